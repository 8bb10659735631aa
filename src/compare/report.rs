//! Writes a comparison for people: `curves.csv`, `convergence.svg`, `summary.md`, each
//! contender's final image (EXR and PNG) and a false-colour error image (PNG).

use std::fmt::Write as _;
use std::path::Path;

use super::{Comparison, Schedule, Spread};
use crate::error::{Error, Result};
use crate::film::{write_png_rgb, ExrMetadata};
use crate::math::Rgb;

/// Line colours of the plot (colour-blind-safe palette of Wong 2011).
const PALETTE: [&str; 8] = [
    "#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442", "#000000",
];

fn write(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

/// File-name-safe form of a label.
fn slug(label: &str) -> String {
    label
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Writes every output of `cmp` into `dir` (created if needed). `reference` is the reference
/// image the errors were measured against.
pub fn write_report(
    dir: &Path,
    cmp: &Comparison,
    reference: &[Rgb],
    width: u32,
    height: u32,
    scene: &str,
) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    write(&dir.join("curves.csv"), &curves_csv(cmp))?;
    write(&dir.join("convergence.svg"), &convergence_svg(cmp, scene))?;
    write(&dir.join("summary.md"), &summary_md(cmp, scene))?;
    // Error images share one scale: the baseline's 99th percentile of absolute error.
    let baseline_errors = abs_errors(&cmp.films[0].radiance(), reference);
    let scale = percentile(&baseline_errors, 0.99).max(1e-12);
    for (c, film) in cmp.films.iter().enumerate() {
        let name = slug(&cmp.labels[c]);
        let meta = ExrMetadata::default()
            .with("integrator", &cmp.labels[c])
            .with("spp", film.min_samples())
            .with("seconds", cmp.seconds_per_run);
        film.write_exr(&dir.join(format!("{name}.exr")), &meta)?;
        film.write_png(&dir.join(format!("{name}.png")), 0.0)?;
        let errors = abs_errors(&film.radiance(), reference);
        write_png_rgb(
            &dir.join(format!("{name}_error.png")),
            width,
            height,
            &error_image(&errors, scale),
            0.0,
        )?;
    }
    Ok(())
}

fn abs_errors(image: &[Rgb], reference: &[Rgb]) -> Vec<f32> {
    image
        .iter()
        .zip(reference)
        .map(|(p, r)| (*p - *r).abs().element_sum() / 3.0)
        .collect()
}

fn percentile(values: &[f32], q: f64) -> f32 {
    let mut v: Vec<f32> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f32::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// False colours for per-pixel errors: 0 is black, `scale` and above is white, through a
/// perceptually ordered dark-blue, magenta, orange ramp (linear RGB, ready for sRGB encoding).
pub fn error_image(errors: &[f32], scale: f32) -> Vec<Rgb> {
    const STOPS: [[f32; 3]; 5] = [
        [0.0, 0.0, 0.0],
        [0.05, 0.02, 0.35],
        [0.55, 0.05, 0.4],
        [1.0, 0.45, 0.05],
        [1.0, 1.0, 0.85],
    ];
    errors
        .iter()
        .map(|&e| {
            let t = if e.is_finite() {
                (e / scale).clamp(0.0, 1.0)
            } else {
                1.0
            } * (STOPS.len() - 1) as f32;
            let i = (t as usize).min(STOPS.len() - 2);
            let f = t - i as f32;
            Rgb::from(STOPS[i]) * (1.0 - f) + Rgb::from(STOPS[i + 1]) * f
        })
        .collect()
}

fn curves_csv(cmp: &Comparison) -> String {
    let mut s = String::from("integrator,run,seconds,spp,mae,rmse,rel_mse\n");
    for p in &cmp.points {
        let _ = writeln!(
            s,
            "{},{},{:.6},{},{:.8e},{:.8e},{:.8e}",
            cmp.labels[p.contender],
            p.run,
            p.seconds,
            p.spp,
            p.errors.mae,
            p.errors.rmse,
            p.errors.rel_mse
        );
    }
    s
}

fn fmt_spread(s: &Spread, digits: usize) -> String {
    if s.min == s.max {
        format!("{:.*e}", digits, s.median)
    } else {
        format!(
            "{:.*e} [{:.*e}, {:.*e}]",
            digits, s.median, digits, s.min, digits, s.max
        )
    }
}

fn summary_md(cmp: &Comparison, scene: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Equal-time comparison: {scene}\n");
    let _ = writeln!(
        s,
        "{} s per run, {} run(s) per integrator, {}, errors against the reference as median [min, max] over runs. \
         Each run's per-scene precomputation is spent from its budget and counted in every time below. \
         The first integrator is the baseline.\n",
        cmp.seconds_per_run,
        cmp.runs,
        match cmp.schedule {
            Schedule::Sequential => "the integrators one after the other",
            Schedule::Concurrent =>
                "the integrators of a run at the same time (each with its own threads, sharing the machine)",
        }
    );
    if let Some(n) = cmp.reference_noise {
        let _ = writeln!(
            s,
            "Reference's own estimated error (from two half-sample renders): MAE {:.3e}, RMSE {:.3e}, relMSE {:.3e}. \
             Errors near these values are limited by the reference, not by the integrator: \
             the column \"MSE above the reference's\" compares MSE above the reference's own (RMSE² - {:.3e}), whose ratio is the speedup \
             at equal time without that floor.\n",
            n.mae, n.rmse, n.rel_mse, n.rmse * n.rmse
        );
    }
    let _ = writeln!(s, "| integrator | MAE | RMSE | relMSE | spp reached | precomputation (s) | time to baseline's MAE (s) | speedup | log-log slope | MSE above the reference's (speedup) | largest pixel / reference's |");
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
    for (c, sm) in cmp.summaries.iter().enumerate() {
        let time = sm
            .time_to_baseline_error
            .map_or("not reached".to_string(), |t| {
                if t.min == t.max {
                    format!("{:.2}", t.median)
                } else {
                    format!("{:.2} [{:.2}, {:.2}]", t.median, t.min, t.max)
                }
            });
        let speedup = if c == 0 {
            "1 (baseline)".to_string()
        } else if sm.indistinguishable {
            "≈ 1 (within run-to-run spread)".to_string()
        } else {
            match sm.speedup {
                Some(sp) if cmp.runs > 1 => {
                    format!("{:.2}x [{:.2}, {:.2}]", sp.median, sp.min, sp.max)
                }
                Some(sp) => format!("{:.2}x (1 run: spread unknown)", sp.median),
                None => format!(
                    "slower: ≈ {:.2}x [{:.2}, {:.2}] from (MAE ratio)², never reached the baseline's error",
                    sm.efficiency.median, sm.efficiency.min, sm.efficiency.max
                ),
            }
        };
        let slope = match sm.slope {
            Some(v) if sm.plateaued() => format!("{v:.2} (plateau: bias or reference noise)"),
            Some(v) => format!("{v:.2}"),
            None => "-".to_string(),
        };
        let pre = &sm.precompute_seconds;
        let precompute = if pre.min == pre.max {
            format!("{:.3}", pre.median)
        } else {
            format!("{:.3} [{:.3}, {:.3}]", pre.median, pre.min, pre.max)
        };
        let above = match (sm.mse_above_reference, sm.mse_speedup) {
            (None, _) => "- (reference noise unknown)".to_string(),
            (Some(e), Some(sp)) => format!(
                "{} ({:.2}x [{:.2}, {:.2}])",
                fmt_spread(&e, 3),
                sp.median,
                sp.min,
                sp.max
            ),
            (Some(e), None) => format!("{} (within the reference's noise)", fmt_spread(&e, 3)),
        };
        let lp = &sm.largest_pixel;
        let largest = if lp.min == lp.max {
            format!("{:.3}", lp.median)
        } else {
            format!("{:.3} [{:.3}, {:.3}]", lp.median, lp.min, lp.max)
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.0} | {} | {} | {} | {} | {} | {} |",
            sm.label,
            fmt_spread(&sm.mae, 3),
            fmt_spread(&sm.rmse, 3),
            fmt_spread(&sm.rel_mse, 3),
            sm.spp.median,
            precompute,
            time,
            speedup,
            slope,
            above,
            largest
        );
    }
    for (label, bias) in cmp.labels.iter().zip(&cmp.biases) {
        if let Some(bias) = bias {
            let _ = writeln!(s, "\n{label} is {bias}");
        }
    }
    let _ = writeln!(s, "\nFiles: `curves.csv` (every pass of every run), `convergence.svg` (MAE against time, log-log, the median run of each integrator), `<integrator>.exr/.png` (last run), `<integrator>_error.png` (absolute error, black = 0, white = the baseline's 99th percentile).");
    s
}

/// Log-log plot of MAE against time, one line per integrator (its median run), each labelled
/// at its end.
fn convergence_svg(cmp: &Comparison, scene: &str) -> String {
    let (w, h) = (860.0, 520.0);
    let (left, right, top, bottom) = (80.0, 170.0, 50.0, 60.0);
    // The median run of each contender by final MAE.
    let curves: Vec<Vec<(f64, f64)>> = (0..cmp.labels.len())
        .map(|c| {
            let mut runs: Vec<_> = cmp.results.iter().filter(|r| r.contender == c).collect();
            runs.sort_by(|a, b| a.errors.mae.total_cmp(&b.errors.mae));
            let run = runs.get(runs.len() / 2).map_or(0, |r| r.run);
            cmp.points
                .iter()
                .filter(|p| {
                    p.contender == c && p.run == run && p.seconds > 0.0 && p.errors.mae > 0.0
                })
                .map(|p| (p.seconds, p.errors.mae))
                .collect()
        })
        .collect();
    // Spread over runs: at each time of the median run's curve, the least and the greatest MAE
    // of all runs there (each run interpolated in log-log space; pass times differ by run).
    let bands: Vec<Vec<(f64, f64, f64)>> = (0..cmp.labels.len())
        .map(|c| {
            let runs: Vec<Vec<(f64, f64)>> = (0..cmp.runs)
                .map(|run| {
                    cmp.points
                        .iter()
                        .filter(|p| {
                            p.contender == c
                                && p.run == run
                                && p.seconds > 0.0
                                && p.errors.mae > 0.0
                        })
                        .map(|p| (p.seconds, p.errors.mae))
                        .collect()
                })
                .collect();
            curves[c]
                .iter()
                .filter_map(|&(t, _)| {
                    let at: Vec<f64> = runs.iter().filter_map(|r| log_interpolate(r, t)).collect();
                    (at.len() == runs.len()).then(|| {
                        let lo = at.iter().copied().fold(f64::MAX, f64::min);
                        let hi = at.iter().copied().fold(f64::MIN, f64::max);
                        (t, lo, hi)
                    })
                })
                .collect()
        })
        .collect();
    let all: Vec<&(f64, f64)> = curves.iter().flatten().collect();
    let (mut tx0, mut tx1, mut ey0, mut ey1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &&(t, e) in &all {
        tx0 = tx0.min(t.log10());
        tx1 = tx1.max(t.log10());
        ey0 = ey0.min(e.log10());
        ey1 = ey1.max(e.log10());
    }
    if all.is_empty() {
        (tx0, tx1, ey0, ey1) = (0.0, 1.0, 0.0, 1.0);
    }
    // Keep the reference's own error (drawn below) inside the plot.
    if let Some(noise) = cmp
        .reference_noise
        .filter(|n| n.mae > 0.0 && n.mae.is_finite())
    {
        ey0 = ey0.min(noise.mae.log10());
        ey1 = ey1.max(noise.mae.log10());
    }
    let (tx0, tx1) = (tx0.floor(), tx1.ceil().max(tx0.floor() + 1.0));
    let (ey0, ey1) = (ey0.floor(), ey1.ceil().max(ey0.floor() + 1.0));
    let px = |t: f64| left + (t.log10() - tx0) / (tx1 - tx0) * (w - left - right);
    let py = |e: f64| top + (ey1 - e.log10()) / (ey1 - ey0) * (h - top - bottom);
    let mut s = String::new();
    let _ = writeln!(s, r#"<?xml version="1.0" encoding="UTF-8"?>"#);
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="13">"#
    );
    let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
    let _ = writeln!(
        s,
        r#"<text x="{}" y="28" font-size="16" text-anchor="middle">MAE against time: {}</text>"#,
        w / 2.0,
        xml_escape(scene)
    );
    // Decade grid and labels.
    for d in tx0 as i32..=tx1 as i32 {
        let x = px(10f64.powi(d));
        let _ = writeln!(
            s,
            r##"<line x1="{x:.1}" y1="{top}" x2="{x:.1}" y2="{}" stroke="#ddd"/>"##,
            h - bottom
        );
        let _ = writeln!(
            s,
            r#"<text x="{x:.1}" y="{}" text-anchor="middle">{}</text>"#,
            h - bottom + 20.0,
            decade(d)
        );
    }
    for d in ey0 as i32..=ey1 as i32 {
        let y = py(10f64.powi(d));
        let _ = writeln!(
            s,
            r##"<line x1="{left}" y1="{y:.1}" x2="{}" y2="{y:.1}" stroke="#ddd"/>"##,
            w - right
        );
        let _ = writeln!(
            s,
            r#"<text x="{}" y="{:.1}" text-anchor="end">{}</text>"#,
            left - 8.0,
            y + 4.0,
            decade(d)
        );
    }
    let _ = writeln!(
        s,
        r#"<rect x="{left}" y="{top}" width="{}" height="{}" fill="none" stroke="black"/>"#,
        w - left - right,
        h - top - bottom
    );
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">time (s)</text>"#,
        left + (w - left - right) / 2.0,
        h - 15.0
    );
    let _ = writeln!(
        s,
        r#"<text x="20" y="{}" text-anchor="middle" transform="rotate(-90 20 {})">MAE</text>"#,
        top + (h - top - bottom) / 2.0,
        top + (h - top - bottom) / 2.0
    );
    // The reference's own error: curves that reach it are limited by the reference.
    if let Some(noise) = cmp
        .reference_noise
        .filter(|n| n.mae > 0.0 && n.mae.is_finite())
    {
        let y = py(noise.mae);
        let _ = writeln!(
            s,
            r##"<line x1="{left}" y1="{y:.1}" x2="{}" y2="{y:.1}" stroke="#888" stroke-dasharray="6 4"/>"##,
            w - right
        );
        let _ = writeln!(
            s,
            r##"<text x="{}" y="{:.1}" fill="#666" font-size="11" text-anchor="end">reference's own error</text>"##,
            w - right - 4.0,
            y - 4.0
        );
    }
    // Spread over runs (min..max of MAE at each pass index), under the median curves.
    for (c, band) in bands.iter().enumerate() {
        if band.len() < 2 || cmp.runs < 2 {
            continue;
        }
        let colour = PALETTE[c % PALETTE.len()];
        let mut d = String::new();
        for (i, &(t, lo, _)) in band.iter().enumerate() {
            let _ = write!(
                d,
                "{}{:.1},{:.1} ",
                if i == 0 { "M" } else { "L" },
                px(t),
                py(lo)
            );
        }
        for &(t, _, hi) in band.iter().rev() {
            let _ = write!(d, "L{:.1},{:.1} ", px(t), py(hi));
        }
        let _ = writeln!(
            s,
            r#"<polygon points="{}" fill="{colour}" fill-opacity="0.15" stroke="none"/>"#,
            d.trim_end().replace(['M', 'L'], "")
        );
    }
    let mut end_labels: Vec<(f64, f64, usize)> = Vec::new();
    for (c, curve) in curves.iter().enumerate() {
        let colour = PALETTE[c % PALETTE.len()];
        let mut d = String::new();
        for (i, &(t, e)) in curve.iter().enumerate() {
            let _ = write!(
                d,
                "{}{:.1},{:.1} ",
                if i == 0 { "M" } else { "L" },
                px(t),
                py(e)
            );
        }
        let _ = writeln!(
            s,
            r#"<path d="{}" fill="none" stroke="{colour}" stroke-width="2"><title>{}</title></path>"#,
            d.trim_end(),
            xml_escape(&cmp.labels[c])
        );
        if let Some(&(t, e)) = curve.last() {
            end_labels.push((px(t), py(e) + 4.0, c));
        }
    }
    // Each curve is named at its end; labels that would overlap are pushed apart vertically
    // (and joined to their curve's end by a thin leader) so none hides another.
    end_labels.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut placed: Vec<f64> = Vec::with_capacity(end_labels.len());
    for (i, l) in end_labels.iter().enumerate() {
        let y = if i == 0 {
            l.1
        } else {
            l.1.max(placed[i - 1] + 15.0)
        };
        placed.push(y);
    }
    let x_label = end_labels.iter().map(|l| l.0).fold(f64::MIN, f64::max) + 8.0;
    for (&(x, y_curve, c), &y) in end_labels.iter().zip(&placed) {
        let colour = PALETTE[c % PALETTE.len()];
        let _ = writeln!(
            s,
            r#"<line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{colour}" stroke-width="0.75"/>"#,
            x + 2.0,
            y_curve - 4.0,
            x_label - 2.0,
            y - 4.0
        );
        let _ = writeln!(
            s,
            r#"<text x="{x_label:.1}" y="{y:.1}" fill="{colour}">{}</text>"#,
            xml_escape(&cmp.labels[c])
        );
    }
    let _ = writeln!(s, "</svg>");
    s
}

/// A curve's value at time `t`, interpolated linearly in log-log space; `None` outside it.
fn log_interpolate(curve: &[(f64, f64)], t: f64) -> Option<f64> {
    let i = curve.iter().position(|&(ti, _)| ti >= t)?;
    let (t1, e1) = curve[i];
    if t1 == t || i == 0 {
        return (t1 == t).then_some(e1);
    }
    let (t0, e0) = curve[i - 1];
    let a = (t.ln() - t0.ln()) / (t1.ln() - t0.ln());
    Some((e0.ln() + a * (e1.ln() - e0.ln())).exp())
}

fn decade(d: i32) -> String {
    if (-2..=3).contains(&d) {
        format!("{}", 10f64.powi(d))
    } else {
        format!("1e{d}")
    }
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn error_image_maps_zero_to_black_and_scale_to_white() {
        let img = error_image(&[0.0, 1.0, 5.0, f32::NAN], 1.0);
        assert_eq!(img[0], Rgb::ZERO);
        assert_eq!(img[1], Rgb::new(1.0, 1.0, 0.85));
        assert_eq!(img[2], img[1]);
        assert_eq!(img[3], img[1]);
        assert_eq!(slug("a/b c"), "a_b_c");
        assert_eq!(xml_escape("<&>"), "&lt;&amp;&gt;");
    }
}
