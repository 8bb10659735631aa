#!/usr/bin/env python3
"""Reference-free errors of one renderer's setting from renders that differ only in the seed:
for every pair (a, b), mean |a - b| / sqrt(2) over pixels and RGB estimates each render's MAE
against the truth (exact for Gaussian pixel errors, approximate for heavy tails) and
mean (a - b)^2 / 2 its variance per value (exact for unbiased renders); printed as the mean
over pairs with their range. For when no reference is at hand, or to check one. With four
images or more it also prints the mean over disjoint pairs (1st with 2nd, 3rd with 4th ...;
independent estimates) with its standard error, the noise of the estimate itself.

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
    if len(images) >= 4:
        dm, dv = [], []
        for a, b in zip(images[0::2], images[1::2]):
            d = a - b
            dm.append(np.abs(d).mean() / np.sqrt(2))
            dv.append((d * d).mean() / 2)
        n = len(dm)
        sm = np.std(dm, ddof=1) / np.sqrt(n) / np.mean(dm)
        sv = np.std(dv, ddof=1) / np.sqrt(n) / np.mean(dv)
        print(f"{n} disjoint pairs: MAE {np.mean(dm):.4e} +- {100 * sm:.1f} %, "
              f"variance {np.mean(dv):.4e} +- {100 * sv:.1f} % (standard errors)")


if __name__ == "__main__":
    main()
