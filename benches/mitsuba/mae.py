#!/usr/bin/env python3
"""Errors of images against a reference, computed as Lacuna's `src/film/metrics.rs` does:
over all pixels and the three channels, differences of the f32 values taken in f64, MAE,
RMSE and relative MSE with epsilon 1e-2; a non-finite pixel is an error. (numpy sums
pairwise, Rust in order; checked on a `lacuna compare` output: all three agree with its
curves.csv to the seven digits printed.) Also prints each
image's mean per channel, to check that converged images of two renderers agree.

    python3 mae.py REFERENCE.exr IMAGE.exr [IMAGE.exr ...]

EXRs are read with Mitsuba's Bitmap; for Lacuna's multi-layer files the root R, G, B layer
is taken (not the albedo, depth or normal AOVs).
"""
import sys

import numpy as np
import mitsuba as mi

REL_MSE_EPSILON = 1e-2


def rgb(path):
    layers = dict(mi.Bitmap(path).split())
    img = np.array(layers["<root>"], dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise SystemExit(f"{path}: no RGB layer (shape {img.shape})")
    return img


def errors(image, reference):
    if image.shape != reference.shape or image.size == 0:
        raise SystemExit(f"image is {image.shape}, reference {reference.shape}: sizes must match")
    if not (np.isfinite(image).all() and np.isfinite(reference).all()):
        raise SystemExit("a pixel is not finite")
    r = reference.astype(np.float64)
    d = image.astype(np.float64) - r
    n = d.size
    return (np.abs(d).sum() / n, np.sqrt((d * d).sum() / n),
            (d * d / (r * r + REL_MSE_EPSILON)).sum() / n)


def main():
    mi.set_variant("scalar_rgb")
    if len(sys.argv) < 3:
        raise SystemExit("usage: mae.py REFERENCE.exr IMAGE.exr [IMAGE.exr ...]")
    ref = rgb(sys.argv[1])
    m = ref.astype(np.float64).mean(axis=(0, 1))
    print(f"{sys.argv[1]}: reference, mean RGB {m[0]:.6f} {m[1]:.6f} {m[2]:.6f}")
    for path in sys.argv[2:]:
        img = rgb(path)
        mae, rmse, rel = errors(img, ref)
        m = img.astype(np.float64).mean(axis=(0, 1))
        print(f"{path}: MAE {mae:.6e} RMSE {rmse:.6e} relMSE {rel:.6e} "
              f"mean RGB {m[0]:.6f} {m[1]:.6f} {m[2]:.6f}")


if __name__ == "__main__":
    main()
