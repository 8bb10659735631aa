#!/usr/bin/env python3
"""Reference-free errors of one renderer's setting from renders that differ only in the seed:
for every pair (a, b), mean |a - b| / sqrt(2) over pixels and RGB estimates each render's MAE
against the truth (exact for Gaussian pixel errors, approximate for heavy tails) and
mean (a - b)^2 / 2 its variance per value (exact for unbiased renders); printed as the mean
over pairs with their range. For when no reference is at hand, or to check one.

    python3 pairs.py IMAGE_SEED1.exr IMAGE_SEED2.exr [IMAGE_SEED3.exr ...]
"""
import itertools
import sys

import numpy as np
import mitsuba as mi

from mae import rgb


def main():
    mi.set_variant("scalar_rgb")
    if len(sys.argv) < 3:
        raise SystemExit("usage: pairs.py IMAGE.exr IMAGE.exr [IMAGE.exr ...]")
    images = [rgb(p).astype(np.float64) for p in sys.argv[1:]]
    mae, var = [], []
    for a, b in itertools.combinations(images, 2):
        if a.shape != b.shape:
            raise SystemExit("images differ in size")
        d = a - b
        mae.append(np.abs(d).mean() / np.sqrt(2))
        var.append((d * d).mean() / 2)
    print(f"{len(images)} images, {len(mae)} pairs: MAE {np.mean(mae):.4e} "
          f"[{min(mae):.4e}, {max(mae):.4e}], variance {np.mean(var):.4e} "
          f"[{min(var):.4e}, {max(var):.4e}], RMSE {np.sqrt(np.mean(var)):.4e}")


if __name__ == "__main__":
    main()
