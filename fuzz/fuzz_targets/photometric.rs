//! The photometric loaders: the first byte picks the format (even: IES LM-63, odd: EULUMDAT),
//! the rest is the file. A profile that loads is queried and sampled.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(init: lacuna_fuzz::init_panic_policy(), |data: &[u8]| {
    let Some((&format, text)) = data.split_first() else {
        return;
    };
    let profile = if format % 2 == 0 {
        lacuna::light::PhotometricProfile::from_ies_bytes(text)
    } else {
        lacuna::light::PhotometricProfile::from_ldt_bytes(text)
    };
    if let Ok(p) = profile {
        let d = lacuna::math::Vec3::new(0.3, -0.2, 0.9).normalize();
        assert!(p.intensity(d).is_finite() && p.direction_pdf(d).is_finite());
        if let Some((w, pdf)) = p.sample_direction(lacuna::math::Vec2::new(0.37, 0.71)) {
            assert!(w.is_finite() && pdf.is_finite() && pdf > 0.0);
        }
    }
});
