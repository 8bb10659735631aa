//! Speed against error through the C API: reference renders and equal-time comparisons of
//! integrators, written as a report directory (the same as `lacuna reference` / `lacuna
//! compare`).

use std::ffi::c_char;
use std::sync::Mutex;

use super::boundary::{self, lacuna_status, CapiError};
use super::buffer::{arg, out_ptr, path_arg, read_strided, str_arg, write_out};
use super::film::lacuna_film;
use super::job::lacuna_render_job;
use super::job::with_settings;
use super::types::*;
use crate::compare::{compare_scheduled, render_reference, write_report, Contender};
use crate::film::ImageErrors;

/// Renders a reference image with the job's settings (its samples per pixel, at least 2; no
/// time budget) as two independent halves, writes the averaged film to `*out_film` and the
/// estimate of its remaining error to `*out_noise` (may be NULL). The film's EXR header carries
/// the estimate, so `lacuna_render_job_compare` can use it after `lacuna_film_load_exr`.
/// Progress and cancellation work as for `lacuna_render_job_run` (no partial film).
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_run_reference(
    job: *mut lacuna_render_job,
    out_film: *mut *mut lacuna_film,
    out_noise: *mut lacuna_image_errors,
) -> lacuna_status {
    boundary::status("lacuna_render_job_run_reference", |call| {
        // SAFETY: NULL or a live job; only shared references to it are ever made.
        let j = unsafe { arg(job.cast_const(), "job") }?;
        call.context(&j.scene.ctx);
        let out = out_ptr(out_film, "out_film")?;
        let (_guard, mut p) = j.start()?;
        let precompute_seconds = j.prepare(&mut p)?;
        let last = Mutex::new(0.0);
        let progress = j.progress_fn(p.settings.progress, &last);
        let mut settings = p.settings.resolved.render.clone();
        settings.time_limit = None;
        let mut reference = render_reference(
            &j.scene.scene,
            &p.camera,
            p.integrator.as_ref(),
            &settings,
            &progress,
        )?;
        reference.stats.precompute_seconds = precompute_seconds;
        j.set_last_stats(reference.stats);
        let n = reference.noise;
        let meta = j
            .metadata(&p, &reference.stats)
            .with("reference_mae_estimate", format!("{:e}", n.mae))
            .with("reference_rmse_estimate", format!("{:e}", n.rmse))
            .with("reference_rel_mse_estimate", format!("{:e}", n.rel_mse));
        // SAFETY: checked non-NULL, writable per the contract; `out_noise` is checked here.
        unsafe {
            if !out_noise.is_null() {
                write_out(
                    out_noise,
                    lacuna_image_errors {
                        mae: n.mae,
                        rmse: n.rmse,
                        rel_mse: n.rel_mse,
                    },
                );
            }
            write_out(out, j.make_film(reference.film, meta, reference.stats));
        }
        Ok(())
    })
}

/// Runs each of the `integrator_count` integrators named in `integrators` (names, or specs
/// `name:key=value:...` as `lacuna compare --integrators` takes them, `sampler=` included)
/// for the same wall-clock time `seconds_per_run` (> 0), `runs` times (>= 1), with the job's resolution,
/// seed, depth, MIS heuristic, threads and camera, measuring errors against `reference` (a film
/// of the job's resolution) after every pass; then writes the report into directory `out_dir`
/// (created if needed): curves.csv, convergence.svg, summary.md, each integrator's final image
/// (EXR and PNG) and false-colour error images. The first integrator is the baseline.
/// Progress and cancellation work as for `lacuna_render_job_run`. The contenders run one after
/// the other unless `lacuna_render_job_set_compare_schedule` says otherwise.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_compare(
    job: *mut lacuna_render_job,
    integrators: *const *const c_char,
    integrator_count: usize,
    reference: *const lacuna_film,
    seconds_per_run: f64,
    runs: u32,
    out_dir: *const c_char,
) -> lacuna_status {
    boundary::status("lacuna_render_job_compare", |call| {
        // SAFETY: NULL or a live job; only shared references to it are ever made.
        let j = unsafe { arg(job.cast_const(), "job") }?;
        call.context(&j.scene.ctx);
        // SAFETY: NULL or a live film.
        let r = unsafe { arg(reference, "reference") }?;
        // SAFETY: NULL or a NUL-terminated string.
        let dir = unsafe { path_arg(out_dir, "out_dir") }?;
        if integrator_count == 0 {
            return Err(CapiError::invalid("integrator_count 0: name at least one"));
        }
        // SAFETY: `integrator_count` string pointers are readable (caller's contract).
        let names: Vec<*const c_char> =
            unsafe { read_strided(integrators.cast(), 0, integrator_count, "integrators") }?;
        if !(seconds_per_run > 0.0 && seconds_per_run.is_finite()) {
            return Err(CapiError::invalid(format!(
                "seconds_per_run {seconds_per_run} must be positive and finite"
            )));
        }
        if runs == 0 {
            return Err(CapiError::invalid("runs 0: at least 1"));
        }
        let (_guard, p) = j.start()?;
        let (w, h) = (
            p.settings.resolved.render.width,
            p.settings.resolved.render.height,
        );
        if (r.film.width(), r.film.height()) != (w, h) {
            return Err(CapiError::invalid(format!(
                "reference is {}x{} but the job renders {w}x{h}",
                r.film.width(),
                r.film.height()
            )));
        }
        let mut contenders = names
            .iter()
            .enumerate()
            .map(|(i, &n)| {
                // SAFETY: each entry is NULL or a NUL-terminated string.
                let name = unsafe { str_arg(n, &format!("integrators[{i}]")) }?;
                Ok(Contender::from_spec(
                    name,
                    p.settings.resolved.integrator_settings,
                )?)
            })
            .collect::<Result<Vec<_>, CapiError>>()?;
        let get = |k: &str| r.metadata.get(k)?.parse::<f64>().ok();
        let noise = (|| {
            Some(ImageErrors {
                mae: get("reference_mae_estimate")?,
                rmse: get("reference_rmse_estimate")?,
                rel_mse: get("reference_rel_mse_estimate")?,
            })
        })();
        let pixels = r.film.radiance();
        let last = Mutex::new(0.0);
        let progress = j.progress_fn(p.settings.progress, &last);
        let mut settings = p.settings.resolved.render.clone();
        settings.time_limit = None;
        let cmp = compare_scheduled(
            &j.scene.scene,
            &p.camera,
            &mut contenders,
            &pixels,
            noise,
            &settings,
            seconds_per_run,
            runs,
            p.settings.compare_schedule,
            &progress,
        )?;
        write_report(&dir, &cmp, &pixels, w, h, &j.scene.label)?;
        Ok(())
    })
}

/// Sets how `lacuna_render_job_compare` runs its contenders: a `lacuna_compare_schedule`
/// value. `LACUNA_COMPARE_SCHEDULE_SEQUENTIAL` (the default) gives each run all of the job's
/// threads in turn; `LACUNA_COMPARE_SCHEDULE_CONCURRENT` starts the contenders of a run
/// together, each with the job's thread count, so that on a shared machine all meet the same
/// load (absolute figures drop, ratios hold).
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_compare_schedule(
    job: *mut lacuna_render_job,
    schedule: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_compare_schedule", job, |s| {
            s.compare_schedule = lacuna_compare_schedule::from_c(schedule, "schedule")?.into();
            Ok(())
        })
    }
}

/// Writes the job's `lacuna_compare_schedule` to `*out_schedule`.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_get_compare_schedule(
    job: *const lacuna_render_job,
    out_schedule: *mut u32,
) -> lacuna_status {
    boundary::status("lacuna_render_job_get_compare_schedule", |call| {
        // SAFETY: NULL or a live job.
        let j = unsafe { arg(job, "job") }?;
        call.context(&j.scene.ctx);
        let out = out_ptr(out_schedule, "out_schedule")?;
        let schedule = j.settings().compare_schedule;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, lacuna_compare_schedule::from(schedule) as u32) };
        Ok(())
    })
}
