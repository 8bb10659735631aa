//! Vertex-connection resampling options of a render job: SkelBPT (`bdpt_skeleton`) and ICBPT
//! (`bdpt_ic`), paper 002. Setters and getters of one option each; the getters report what
//! the next run uses (the integrator name's options, the scene file's `render.resampling` and
//! the setters, the latest of them winning).

use super::boundary::{self, lacuna_status, CapiError, CapiResult};
use super::buffer::{arg, out_ptr, write_out};
use super::job::{lacuna_render_job, with_settings, JobSettings};
use crate::guide::ResamplingSettings;
use crate::integrator;

/// Fails unless the job's integrator is one of `integrators`.
fn require(s: &JobSettings, what: &str, integrators: &[&str]) -> CapiResult<()> {
    if integrators.contains(&s.integrator_name()) {
        Ok(())
    } else {
        Err(CapiError::operation(format!(
            "{what} applies to {}; this job renders with '{}'",
            integrators.join(" and "),
            s.resolved.integrator
        )))
    }
}

/// Sets option `key` through its typed (validating) setter, and removes the same option from
/// the integrator name so that the latest setting wins.
fn set_option(
    s: &mut JobSettings,
    key: &str,
    set: impl FnOnce(&mut ResamplingSettings) -> crate::error::Result<()>,
) -> CapiResult<()> {
    set(&mut s.resolved.integrator_settings.resampling)?;
    let kept: Vec<&str> = s
        .resolved
        .integrator
        .split(':')
        .enumerate()
        .filter(|&(i, part)| i == 0 || part.split_once('=').map(|(k, _)| k.trim()) != Some(key))
        .map(|(_, part)| part)
        .collect();
    s.resolved.integrator = kept.join(":");
    Ok(())
}

/// The resampling options the job's next run uses.
///
/// # Safety
/// `job` must be NULL or a live job.
unsafe fn current(job: *const lacuna_render_job, what: &str) -> CapiResult<ResamplingSettings> {
    // SAFETY: NULL or a live job, per the caller's contract.
    let j = unsafe { arg(job, "job") }?;
    let s = j.settings();
    require(&s, what, &["bdpt_skeleton", "bdpt_ic"])?;
    let (_, applied) =
        integrator::parse_spec(&s.resolved.integrator, s.resolved.integrator_settings)?;
    Ok(applied.resampling)
}

/// `bdpt_skeleton` and `bdpt_ic`: resample from the first `subset` light subpaths of each
/// iteration (N, 1..=16777216; default 1024, 002 §5). `LACUNA_STATUS_INVALID_ARGUMENT` for 0
/// or more, `LACUNA_STATUS_INVALID_OPERATION` for jobs of other integrators.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_resampling_subset(
    job: *mut lacuna_render_job,
    subset: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_resampling_subset", job, |s| {
            require(s, "the resampling subset", &["bdpt_skeleton", "bdpt_ic"])?;
            set_option(s, "subset", |r| r.set_subset(subset))
        })
    }
}

/// `bdpt_skeleton`: node acceptance alpha_accept (finite, >= 0; default 1, 002 §4.4): a node
/// gets distributions in an iteration only when more than alpha_accept times the mean number
/// of camera vertices per node mapped to it so far. `LACUNA_STATUS_INVALID_ARGUMENT` for a
/// negative or non-finite value, `LACUNA_STATUS_INVALID_OPERATION` for jobs of other
/// integrators.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_resampling_accept(
    job: *mut lacuna_render_job,
    accept: f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_resampling_accept", job, |s| {
            require(s, "node acceptance", &["bdpt_skeleton"])?;
            set_option(s, "accept", |r| r.set_accept(accept))
        })
    }
}

/// `bdpt_skeleton` and `bdpt_ic`: also render one image per resampling distribution and one
/// for the uniform fallback (002 Figure 10), as the film layers `resampled_visibility`,
/// `resampled_distance`, `resampled_uniform` and `resampled_fallback` (default false).
/// `LACUNA_STATUS_INVALID_OPERATION` for jobs of other integrators.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_resampling_images(
    job: *mut lacuna_render_job,
    enabled: bool,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_resampling_images", job, |s| {
            require(s, "resampling images", &["bdpt_skeleton", "bdpt_ic"])?;
            set_option(s, "images", |r| {
                r.images = enabled;
                Ok(())
            })
        })
    }
}

/// `bdpt_ic`: importance records come from the eye subpaths of this fraction of the pixels
/// per iteration (d in (0, 1]; default 0.001, 002 §5). `LACUNA_STATUS_INVALID_ARGUMENT`
/// outside (0, 1], `LACUNA_STATUS_INVALID_OPERATION` for jobs of other integrators.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_record_density(
    job: *mut lacuna_render_job,
    density: f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_record_density", job, |s| {
            require(s, "the record density", &["bdpt_ic"])?;
            set_option(s, "density", |r| r.set_density(density))
        })
    }
}

/// `bdpt_skeleton` and `bdpt_ic`: writes the resampling subset N the next run uses to
/// `*out_subset`. `LACUNA_STATUS_INVALID_OPERATION` for jobs of other integrators.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_get_resampling_subset(
    job: *const lacuna_render_job,
    out_subset: *mut u32,
) -> lacuna_status {
    boundary::status("lacuna_render_job_get_resampling_subset", |call| {
        // SAFETY: NULL or a live job.
        call.context(&unsafe { arg(job, "job") }?.scene.ctx);
        let out = out_ptr(out_subset, "out_subset")?;
        // SAFETY: forwarded contract.
        let r = unsafe { current(job, "the resampling subset") }?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, r.subset) };
        Ok(())
    })
}

/// `bdpt_skeleton` and `bdpt_ic`: writes the node acceptance alpha_accept the next run uses
/// to `*out_accept` (`bdpt_ic` has no nodes and ignores it). `LACUNA_STATUS_INVALID_OPERATION`
/// for jobs of other integrators.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_get_resampling_accept(
    job: *const lacuna_render_job,
    out_accept: *mut f32,
) -> lacuna_status {
    boundary::status("lacuna_render_job_get_resampling_accept", |call| {
        // SAFETY: NULL or a live job.
        call.context(&unsafe { arg(job, "job") }?.scene.ctx);
        let out = out_ptr(out_accept, "out_accept")?;
        // SAFETY: forwarded contract.
        let r = unsafe { current(job, "node acceptance") }?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, r.accept) };
        Ok(())
    })
}

/// `bdpt_skeleton` and `bdpt_ic`: writes whether the next run renders the per-distribution
/// images to `*out_enabled`. `LACUNA_STATUS_INVALID_OPERATION` for jobs of other integrators.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_get_resampling_images(
    job: *const lacuna_render_job,
    out_enabled: *mut bool,
) -> lacuna_status {
    boundary::status("lacuna_render_job_get_resampling_images", |call| {
        // SAFETY: NULL or a live job.
        call.context(&unsafe { arg(job, "job") }?.scene.ctx);
        let out = out_ptr(out_enabled, "out_enabled")?;
        // SAFETY: forwarded contract.
        let r = unsafe { current(job, "resampling images") }?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, r.images) };
        Ok(())
    })
}

/// `bdpt_skeleton` and `bdpt_ic`: writes the importance-record density d the next run uses to
/// `*out_density` (`bdpt_skeleton` has no records and ignores it).
/// `LACUNA_STATUS_INVALID_OPERATION` for jobs of other integrators.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_get_record_density(
    job: *const lacuna_render_job,
    out_density: *mut f32,
) -> lacuna_status {
    boundary::status("lacuna_render_job_get_record_density", |call| {
        // SAFETY: NULL or a live job.
        call.context(&unsafe { arg(job, "job") }?.scene.ctx);
        let out = out_ptr(out_density, "out_density")?;
        // SAFETY: forwarded contract.
        let r = unsafe { current(job, "the record density") }?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, r.density) };
        Ok(())
    })
}
