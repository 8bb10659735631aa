//! The OBJ/MTL loader: the input is an OBJ file, optionally followed by `\0MTL\0` and an MTL
//! file saved as `in.mtl` (the OBJ names it with `mtllib in.mtl`). Loaded, then built.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(init: lacuna_fuzz::init_panic_policy(), |data: &[u8]| {
    const SPLIT: &[u8] = b"\0MTL\0";
    let (obj, mtl) = match data.windows(SPLIT.len()).position(|w| w == SPLIT) {
        Some(i) => (&data[..i], &data[i + SPLIT.len()..]),
        None => (data, &[][..]),
    };
    lacuna_fuzz::write("in.mtl", mtl);
    let path = lacuna_fuzz::write("in.obj", obj);
    let mut builder = lacuna::scene::SceneBuilder::new();
    if lacuna::scene::load_obj(&path, &mut builder, None).is_ok() {
        let _ = builder.build();
    }
});
