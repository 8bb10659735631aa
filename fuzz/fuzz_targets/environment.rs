//! The environment-map loaders: the first byte picks `.exr` or `.hdr`, the rest is the file.
//! Loaded within a 256 MiB budget, then its sampling structures are built.
#![no_main]

use lacuna::light::environment::EnvImage;
use lacuna::light::{EnvSettings, EnvStrategy, EnvironmentMap};
use libfuzzer_sys::fuzz_target;

fuzz_target!(init: lacuna_fuzz::init_panic_policy(), |data: &[u8]| {
    let Some((&kind, file)) = data.split_first() else {
        return;
    };
    let name = if kind & 1 == 0 { "in.exr" } else { "in.hdr" };
    let path = lacuna_fuzz::write(name, file);
    let Ok(image) = EnvImage::load_within(&path, lacuna_fuzz::FUZZ_BUDGET) else {
        return;
    };
    if let Ok(mut map) = EnvironmentMap::new(image, EnvSettings::default()) {
        map.prepare(EnvStrategy::default());
    }
});
