//! Bias against variance of a renderer's images (issue 36's one-second question): given a
//! reference and K >= 2 images of independent seeds, prints each image's MAE and MSE against
//! the reference, the variance of one image (half the mean squared difference of pairs of
//! images: independent noise of equal variance), and the squared bias left (the images' mean
//! MSE less that variance; it still holds the reference's own noise, printed from its header
//! where `lacuna reference` wrote it).
//!
//! `cargo run --release --example error_split -- REF.exr A.exr B.exr [C.exr ...]`

use std::path::Path;

use lacuna::image_file::read_exr_rgb;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        eprintln!("usage: error_split REF.exr A.exr B.exr [C.exr ...]");
        std::process::exit(2);
    }
    let reference = read_exr_rgb(Path::new(&args[0])).unwrap();
    let images: Vec<_> = args[1..]
        .iter()
        .map(|a| read_exr_rgb(Path::new(a)).unwrap().pixels)
        .collect();
    let mse = |a: &[lacuna::math::Rgb], b: &[lacuna::math::Rgb]| {
        let (mut abs, mut sq) = (0.0f64, 0.0f64);
        for (p, r) in a.iter().zip(b) {
            for c in 0..3 {
                let d = f64::from(p[c]) - f64::from(r[c]);
                abs += d.abs();
                sq += d * d;
            }
        }
        let n = (a.len() * 3) as f64;
        (abs / n, sq / n)
    };
    let mut total = 0.0;
    for (name, image) in args[1..].iter().zip(&images) {
        let (mae, sq) = mse(image, &reference.pixels);
        total += sq;
        println!("{name}: MAE {mae:.4} MSE {sq:.4}");
    }
    let k = images.len();
    let (mut pairs, mut half) = (0, 0.0);
    for i in 0..k {
        for j in i + 1..k {
            half += 0.5 * mse(&images[i], &images[j]).1;
            pairs += 1;
        }
    }
    let variance = half / f64::from(pairs);
    let mean = total / k as f64;
    let noise = reference
        .metadata
        .entries
        .iter()
        .filter(|(key, _)| key.contains("rmse") || key.contains("noise") || key.contains("mse"))
        .map(|(key, v)| format!("{key}={v}"))
        .collect::<Vec<_>>()
        .join(" ");
    println!(
        "mean MSE {mean:.4} = variance {variance:.4} + bias^2 (with the reference's noise) {:.4}; reference: {noise}",
        mean - variance
    );
}
