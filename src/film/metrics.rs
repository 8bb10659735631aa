//! Error metrics of an image against a reference: what "accuracy" means in every speed
//! against error figure. All averages are over pixels and the three channels.

use crate::error::{Error, Result};
use crate::math::Rgb;

/// Errors of an image against a reference.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImageErrors {
    /// Mean absolute error.
    pub mae: f64,
    /// Root mean squared error.
    pub rmse: f64,
    /// Mean of (x - ref)^2 / (ref^2 + eps), with eps = 1e-2 so that black reference pixels do
    /// not dominate (the usual relative MSE of rendering papers).
    pub rel_mse: f64,
}

/// Offset in the denominator of the relative MSE.
pub const REL_MSE_EPSILON: f64 = 1e-2;

/// Compares two images of the same size; non-finite pixels in `image` are an error (they
/// must never be produced).
pub fn image_errors(image: &[Rgb], reference: &[Rgb]) -> Result<ImageErrors> {
    if image.len() != reference.len() || image.is_empty() {
        return Err(Error::invalid(format!(
            "image has {} pixels, reference {}: sizes must match and be non-zero",
            image.len(),
            reference.len()
        )));
    }
    let (mut abs, mut sq, mut rel) = (0.0f64, 0.0f64, 0.0f64);
    for (i, (p, r)) in image.iter().zip(reference).enumerate() {
        if !crate::math::is_finite3(*p) || !crate::math::is_finite3(*r) {
            return Err(Error::invalid(format!(
                "pixel {i} is not finite: {p} (reference {r})"
            )));
        }
        for c in 0..3 {
            let d = p[c] as f64 - r[c] as f64;
            abs += d.abs();
            sq += d * d;
            rel += d * d / ((r[c] as f64).powi(2) + REL_MSE_EPSILON);
        }
    }
    let n = (image.len() * 3) as f64;
    Ok(ImageErrors {
        mae: abs / n,
        rmse: (sq / n).sqrt(),
        rel_mse: rel / n,
    })
}

/// The brightest pixel of `image` against the brightest of `reference`, by luminance: a
/// firefly shows as a ratio well above 1 long before it moves the mean errors. None when the
/// reference is black (or either image is empty or not finite).
pub fn largest_pixel_ratio(image: &[Rgb], reference: &[Rgb]) -> Option<f64> {
    let largest = |img: &[Rgb]| {
        img.iter()
            .map(|&p| crate::math::luminance(p) as f64)
            .fold(None, |m: Option<f64>, l| Some(m.map_or(l, |m| m.max(l))))
    };
    let (a, b) = (largest(image)?, largest(reference)?);
    let ratio = a / b;
    (b > 0.0 && ratio.is_finite()).then_some(ratio)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_match_hand_computed_values() {
        let reference = [Rgb::new(1.0, 0.0, 2.0), Rgb::ZERO];
        let image = [Rgb::new(1.5, 0.0, 1.0), Rgb::new(0.0, 0.3, 0.0)];
        let e = image_errors(&image, &reference).unwrap();
        // |d| = 0.5, 0, 1, 0, 0.3, 0 over 6 values.
        assert!((e.mae - 1.8 / 6.0).abs() < 1e-6);
        assert!((e.rmse - ((0.25 + 1.0 + 0.09) / 6.0f64).sqrt()).abs() < 1e-6);
        let rel = 0.25 / 1.01 + 1.0 / 4.01 + 0.09 / 0.01;
        assert!((e.rel_mse - rel / 6.0).abs() < 1e-5);
        assert_eq!(
            image_errors(&reference, &reference).unwrap(),
            ImageErrors::default()
        );
        assert!(image_errors(&image[..1], &reference).is_err());
        assert!(image_errors(&[Rgb::splat(f32::NAN)], &[Rgb::ZERO]).is_err());
    }

    #[test]
    fn largest_pixel_ratio_compares_the_brightest_pixels_by_luminance() {
        let reference = [Rgb::splat(2.0), Rgb::splat(0.5)];
        let image = [Rgb::splat(1.0), Rgb::splat(6.0)];
        assert_eq!(largest_pixel_ratio(&image, &reference), Some(3.0));
        assert_eq!(largest_pixel_ratio(&image, &[Rgb::ZERO; 2]), None);
        assert_eq!(largest_pixel_ratio(&[], &reference), None);
        assert_eq!(
            largest_pixel_ratio(&[Rgb::splat(f32::INFINITY)], &reference),
            None
        );
    }
}
