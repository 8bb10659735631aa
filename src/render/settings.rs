//! The one place render settings are resolved, for the command line and the C API alike:
//! the library's defaults, then what the scene file says, then the caller's overrides. The
//! special cases both callers share live here too: a time budget renders until it runs out
//! unless a sample count is given, the integrator falls back to `path`, the camera to an
//! automatic framing of the scene, and the EXR metadata of a render.

use std::time::Duration;

use super::RenderSettings;
use crate::error::{Error, Result};
use crate::film::ExrMetadata;
use crate::integrator::IntegratorSettings;
use crate::math::SamplerKind;
use crate::scene::{auto_camera, Camera, RenderSettingsFile, Scene};

/// The integrator a render uses when neither the scene file nor the caller names one.
pub const DEFAULT_INTEGRATOR: &str = "path";

/// What a caller (command-line flags, a host) sets over the scene file; `None` keeps the
/// file's value, or the default when the file has none.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SettingsOverrides {
    /// Integrator specification, `NAME[:KEY=VALUE]...`.
    pub integrator: Option<String>,
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// Samples per pixel. Replaces the scene file's time budget as well as its sample count.
    pub spp: Option<u32>,
    /// Time budget in seconds (> 0, finite). Without `spp` here, the render runs until the
    /// budget is spent, whatever sample count the scene file gives.
    pub time: Option<f64>,
    pub seed: Option<u64>,
    pub sampler: Option<SamplerKind>,
    /// Worker threads (`None`: all cores, or the caller's own default).
    pub threads: Option<usize>,
    /// Maximum bounces.
    pub max_depth: Option<u32>,
}

/// Settings ready for a render.
#[derive(Clone, Debug, PartialEq)]
pub struct ResolvedSettings {
    /// Integrator specification (`NAME[:KEY=VALUE]...`), for [`crate::integrator::create`].
    pub integrator: String,
    pub render: RenderSettings,
    pub integrator_settings: IntegratorSettings,
    /// True when the sample count came from the scene file or the overrides rather than from
    /// the default or a time budget (a host that adds or removes a time budget later keeps it).
    pub spp_given: bool,
}

/// Resolves the settings of a render: [`RenderSettings::default`] and
/// [`IntegratorSettings::default`], then `file`, then `overrides`. `integrator_overrides`
/// is the last layer for the integrators' own typed options (skeleton guide, MIS heuristic,
/// environment sampling ...), applied after the file's options so that the caller's win.
///
/// Errors in the scene file's options name the file and the option
/// ([`IntegratorSettings::apply_file`]); an override out of range is an invalid argument.
pub fn resolve(
    file: &RenderSettingsFile,
    overrides: &SettingsOverrides,
    integrator_overrides: impl FnOnce(&mut IntegratorSettings) -> Result<()>,
) -> Result<ResolvedSettings> {
    let mut render = RenderSettings::default();
    render.width = overrides.width.or(file.width).unwrap_or(render.width);
    render.height = overrides.height.or(file.height).unwrap_or(render.height);
    render.seed = overrides.seed.or(file.seed).unwrap_or(render.seed);
    render.sampler = match (overrides.sampler, &file.sampler) {
        (Some(kind), _) => kind,
        (None, Some(name)) => SamplerKind::parse(name)?,
        (None, None) => render.sampler,
    };
    render.threads = overrides.threads;

    // Samples and time: a layer's sample count or time budget replaces the earlier layers'
    // (the command line's `--spp` replaces the file's `time`); a time budget with no sample
    // count in its own layer or a later one renders until the budget is spent.
    let (spp, time) = if overrides.spp.is_some() || overrides.time.is_some() {
        (overrides.spp, overrides.time)
    } else {
        (file.spp, file.time)
    };
    render.spp = spp.unwrap_or(render.spp);
    if let Some(t) = time {
        if !(t > 0.0 && t.is_finite()) {
            return Err(Error::invalid(format!(
                "time budget {t} must be a positive number of seconds"
            )));
        }
        render.time_limit = Some(Duration::from_secs_f64(t));
        render.spp = spp.unwrap_or(u32::MAX);
    }

    let mut integrator_settings = IntegratorSettings::default();
    integrator_settings.apply_file(file)?;
    if let Some(d) = overrides.max_depth {
        crate::limits::check_max_depth("max_depth", d)?;
        integrator_settings.max_depth = d;
    }
    integrator_overrides(&mut integrator_settings)?;

    let integrator = overrides
        .integrator
        .clone()
        .or_else(|| file.integrator.clone())
        .unwrap_or_else(|| DEFAULT_INTEGRATOR.to_string());
    Ok(ResolvedSettings {
        integrator,
        render,
        integrator_settings,
        spp_given: spp.is_some(),
    })
}

/// The camera of a render: the caller's, else the scene's, else one framing the scene's
/// bounds at the image's aspect ratio.
pub fn resolve_camera(scene: &Scene, explicit: Option<Camera>, width: u32, height: u32) -> Camera {
    explicit
        .or_else(|| scene.camera().copied())
        .unwrap_or_else(|| auto_camera(scene.bounds(), width as f32 / height.max(1) as f32))
}

impl ResolvedSettings {
    /// The integrator's name without its options.
    pub fn integrator_name(&self) -> &str {
        self.integrator.split(':').next().unwrap_or_default().trim()
    }

    /// Why the integrator's images are biased ([`crate::integrator::Integrator::bias`]), or
    /// None when they are not (or the specification is invalid).
    pub fn bias(&self) -> Option<String> {
        crate::integrator::create(&self.integrator, self.integrator_settings)
            .ok()
            .and_then(|i| i.bias())
    }

    /// The EXR metadata of a finished render of scene `label`: what reproduces it (sample
    /// count, seed, sampler, integrator, max depth, scene), its time, and `biased` ("no", or
    /// why it is). Callers append their own figures (precomputation time, a reference's error
    /// estimate).
    pub fn metadata(&self, label: &str, spp: u32, seconds: f64) -> ExrMetadata {
        ExrMetadata::default()
            .with("spp", spp)
            .with("seed", self.render.seed)
            .with("sampler", self.render.sampler.name())
            .with("integrator", &self.integrator)
            .with("max_depth", self.integrator_settings.max_depth)
            .with("scene", label)
            .with("seconds", format!("{seconds:.3}"))
            .with("biased", self.bias().unwrap_or_else(|| "no".to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::guide::SkeletonStrength;

    fn file() -> RenderSettingsFile {
        RenderSettingsFile {
            width: Some(320),
            height: Some(200),
            spp: Some(64),
            max_depth: Some(5),
            integrator: Some("bdpt".into()),
            seed: Some(3),
            sampler: Some("independent".into()),
            ..Default::default()
        }
    }

    fn no_integrator_overrides(_: &mut IntegratorSettings) -> Result<()> {
        Ok(())
    }

    #[test]
    fn defaults_when_nothing_is_given() {
        let r = resolve(
            &RenderSettingsFile::default(),
            &SettingsOverrides::default(),
            no_integrator_overrides,
        )
        .unwrap();
        assert_eq!(r.integrator, "path");
        assert_eq!(r.render, RenderSettings::default());
        assert_eq!(r.integrator_settings, IntegratorSettings::default());
        assert!(!r.spp_given);
    }

    #[test]
    fn the_file_overrides_defaults_and_overrides_the_file() {
        let r = resolve(
            &file(),
            &SettingsOverrides::default(),
            no_integrator_overrides,
        )
        .unwrap();
        assert_eq!(r.integrator, "bdpt");
        assert_eq!((r.render.width, r.render.height), (320, 200));
        assert_eq!((r.render.spp, r.render.seed), (64, 3));
        assert_eq!(r.render.sampler, SamplerKind::Independent);
        assert_eq!(r.integrator_settings.max_depth, 5);
        assert!(r.spp_given);

        let overrides = SettingsOverrides {
            integrator: Some("path:rr_depth=3".into()),
            width: Some(64),
            spp: Some(8),
            seed: Some(9),
            sampler: Some(SamplerKind::Sobol),
            threads: Some(2),
            max_depth: Some(2),
            ..Default::default()
        };
        let r = resolve(&file(), &overrides, no_integrator_overrides).unwrap();
        assert_eq!(r.integrator, "path:rr_depth=3");
        assert_eq!(r.integrator_name(), "path");
        assert_eq!((r.render.width, r.render.height), (64, 200));
        assert_eq!((r.render.spp, r.render.seed), (8, 9));
        assert_eq!(r.render.sampler, SamplerKind::Sobol);
        assert_eq!(r.render.threads, Some(2));
        assert_eq!(r.integrator_settings.max_depth, 2);
    }

    #[test]
    fn typed_integrator_overrides_come_after_the_file() {
        let mut f = file();
        f.skeleton = Some(
            [("c_skel".to_string(), serde_json::json!(0.25))]
                .into_iter()
                .collect(),
        );
        let r = resolve(&f, &SettingsOverrides::default(), |s| {
            assert_eq!(
                s.skeleton.c_skel, 0.25,
                "the file's option is applied first"
            );
            s.skeleton.set_c_skel(Some(0.75))
        })
        .unwrap();
        assert_eq!(r.integrator_settings.skeleton.c_skel, 0.75);
        assert!(!r.integrator_settings.skeleton.learned_c_skel);
        // A failing override fails the resolution.
        let err = resolve(&f, &SettingsOverrides::default(), |s| {
            s.skeleton.set_strength(Some(SkeletonStrength::Fixed(-1.0)))
        });
        assert!(err.is_err());
    }

    #[test]
    fn a_time_budget_renders_until_it_is_spent_unless_its_layer_gives_a_sample_count() {
        // The file's budget alone: the maximum sample count.
        let f = RenderSettingsFile {
            time: Some(1.5),
            ..Default::default()
        };
        let r = resolve(&f, &SettingsOverrides::default(), no_integrator_overrides).unwrap();
        assert_eq!(r.render.time_limit, Some(Duration::from_secs_f64(1.5)));
        assert_eq!(r.render.spp, u32::MAX);
        assert!(!r.spp_given);
        // The file's budget and sample count: whichever comes first.
        let f = RenderSettingsFile { spp: Some(64), ..f };
        let r = resolve(&f, &SettingsOverrides::default(), no_integrator_overrides).unwrap();
        assert_eq!((r.render.spp, r.render.time_limit.is_some()), (64, true));
        assert!(r.spp_given);
        // A caller's budget replaces the file's sample count.
        let o = SettingsOverrides {
            time: Some(2.0),
            ..Default::default()
        };
        let r = resolve(&f, &o, no_integrator_overrides).unwrap();
        assert_eq!(r.render.spp, u32::MAX);
        assert_eq!(r.render.time_limit, Some(Duration::from_secs(2)));
        assert!(!r.spp_given);
        // A caller's sample count replaces the file's budget.
        let o = SettingsOverrides {
            spp: Some(4),
            ..Default::default()
        };
        let r = resolve(&f, &o, no_integrator_overrides).unwrap();
        assert_eq!((r.render.spp, r.render.time_limit), (4, None));
        // A bad budget is refused.
        for t in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let o = SettingsOverrides {
                time: Some(t),
                ..Default::default()
            };
            assert!(resolve(&f, &o, no_integrator_overrides).is_err(), "{t}");
        }
    }

    #[test]
    fn out_of_range_depths_are_refused() {
        let o = SettingsOverrides {
            max_depth: Some(crate::limits::MAX_DEPTH + 1),
            ..Default::default()
        };
        assert!(resolve(&file(), &o, no_integrator_overrides).is_err());
        let f = RenderSettingsFile {
            max_depth: Some(crate::limits::MAX_DEPTH + 1),
            ..Default::default()
        };
        let e = resolve(&f, &SettingsOverrides::default(), no_integrator_overrides).unwrap_err();
        assert!(e.to_string().contains("render.max_depth"), "{e}");
    }

    #[test]
    fn the_camera_falls_back_to_the_scene_then_to_automatic_framing() {
        let scene = crate::scene::two_rooms_builder().unwrap().build().unwrap();
        let framed = resolve_camera(&scene, None, 200, 100);
        let expected = scene
            .camera()
            .copied()
            .unwrap_or_else(|| auto_camera(scene.bounds(), 2.0));
        assert_eq!(framed, expected);
        let mut builder = crate::scene::two_rooms_builder().unwrap();
        let own = Camera::look_at(
            glam::Vec3::new(0.0, 1.0, 4.0),
            glam::Vec3::ZERO,
            glam::Vec3::Y,
            50.0,
        )
        .unwrap();
        builder.set_camera(own).unwrap();
        let with_camera = builder.build().unwrap();
        assert_eq!(resolve_camera(&with_camera, None, 10, 10), own);
        let explicit =
            Camera::look_at(glam::Vec3::ONE, glam::Vec3::ZERO, glam::Vec3::Y, 30.0).unwrap();
        assert_eq!(
            resolve_camera(&with_camera, Some(explicit), 10, 10),
            explicit
        );
    }

    /// The scene file keeps the integrators' options raw; applying them validates them, and an
    /// error names the file and the option as a load-time error would.
    #[test]
    fn bad_integrator_options_of_a_scene_file_name_the_file_and_the_option() {
        let dir = std::env::temp_dir().join(format!("lacuna-settings-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cases = [
            (r#"{"skeleton": {"c_skel": 1.5}}"#, "render.skeleton.c_skel"),
            (
                r#"{"skeleton": {"strength": "loud"}}"#,
                "render.skeleton.strength",
            ),
            (r#"{"skeleton": {"colour": 1}}"#, "render.skeleton.colour"),
            (
                r#"{"resampling": {"subset": 0}}"#,
                "render.resampling.subset",
            ),
            (
                r#"{"resampling": {"density": 2}}"#,
                "render.resampling.density",
            ),
        ];
        for (i, (render, location)) in cases.into_iter().enumerate() {
            let path = dir.join(format!("bad{i}.json"));
            std::fs::write(&path, format!(r#"{{"render": {render}}}"#)).unwrap();
            let loaded = crate::scene::load_scene_file(&path).expect("options are kept raw");
            let err = resolve(
                &loaded.settings,
                &SettingsOverrides::default(),
                no_integrator_overrides,
            )
            .unwrap_err();
            match &err {
                Error::Parse {
                    path: p,
                    location: l,
                    ..
                } => assert_eq!((p, l.as_str()), (&path, location), "{err}"),
                other => panic!("{render}: expected a parse error, got {other}"),
            }
            // Without a file (a built-in scene's settings) the option is still named.
            let mut settings = loaded.settings.clone();
            settings.source = None;
            let err = resolve(
                &settings,
                &SettingsOverrides::default(),
                no_integrator_overrides,
            )
            .unwrap_err();
            assert!(err.to_string().contains(location), "{err}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn metadata_names_what_reproduces_the_render() {
        let r = resolve(
            &file(),
            &SettingsOverrides::default(),
            no_integrator_overrides,
        )
        .unwrap();
        let m = r.metadata("scene.json", 64, 1.23456);
        for (key, value) in [
            ("spp", "64"),
            ("seed", "3"),
            ("sampler", "independent"),
            ("integrator", "bdpt"),
            ("max_depth", "5"),
            ("scene", "scene.json"),
            ("seconds", "1.235"),
            ("biased", "no"),
        ] {
            assert_eq!(m.get(key), Some(value), "{key}");
        }
    }

    #[test]
    fn metadata_says_when_the_image_is_biased() {
        let with = |spec: &str| {
            let overrides = SettingsOverrides {
                integrator: Some(spec.into()),
                ..Default::default()
            };
            let r = resolve(&file(), &overrides, no_integrator_overrides).unwrap();
            r.metadata("scene.json", 1, 0.0)
                .get("biased")
                .unwrap()
                .to_string()
        };
        assert_eq!(with("vpl:compensate=true"), "no");
        assert!(with("vpl:clamp=0.1").starts_with("biased: "));
        assert!(with("vpl").starts_with("biased: "));
        assert_eq!(with("path"), "no");
    }
}
