//! The JSON scene file: loaded (with the side files `tri.obj`, `tri.mtl`, `tex.png` and
//! `env.hdr` beside it), then built, and its camera and settings checked as the CLI does.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(init: lacuna_fuzz::init_panic_policy(), |data: &[u8]| {
    let path = lacuna_fuzz::write("in.json", data);
    let Ok(loaded) = lacuna::scene::load_scene_file(&path) else {
        return;
    };
    let mut settings = lacuna::integrator::IntegratorSettings::default();
    let _ = settings.apply_file(&loaded.settings);
    if let Ok(scene) = loaded.builder.build() {
        let camera = scene
            .camera()
            .copied()
            .unwrap_or_else(|| lacuna::scene::auto_camera(scene.bounds(), 1.0));
        let _ = camera.validate();
    }
});
