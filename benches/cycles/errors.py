"""MSE, MAE and mean RGB of EXR images against a reference, as `src/film/metrics.rs` computes
them (f64 over all pixels and channels), and the MSE above the reference's own (its header's
`lacuna:reference_rmse_estimate` squared, as `lacuna compare` subtracts it). Reads Lacuna's multi-layer EXR (the root RGB) and
Blender's (its `ViewLayer.Combined` or plain R, G, B channels) with the `OpenEXR` package.

    python errors.py REFERENCE.exr IMAGE.exr [IMAGE.exr ...]
"""
import sys

import numpy as np
import OpenEXR


def rgb(path):
    with OpenEXR.File(path, separate_channels=True) as f:
        ch = f.channels()
        for names in (("R", "G", "B"), ("ViewLayer.Combined.R", "ViewLayer.Combined.G",
                                        "ViewLayer.Combined.B")):
            if all(n in ch for n in names):
                return np.stack([ch[n].pixels.astype(np.float64) for n in names], axis=-1)
        if "RGB" in ch:
            return ch["RGB"].pixels.astype(np.float64)
        raise SystemExit(f"{path}: no RGB channels in {sorted(ch)[:8]}")


def own_mse(path):
    with OpenEXR.File(path) as f:
        rmse = f.header().get("lacuna:reference_rmse_estimate")
    return float(rmse) ** 2 if rmse is not None else 0.0


def main():
    ref = rgb(sys.argv[1])
    floor = own_mse(sys.argv[1])
    print(f"{'image':40} {'MSE':>10} {'above ref':>10} {'MAE':>10}  mean RGB "
          f"(reference {ref.mean(axis=(0, 1))}, its own MSE {floor:.4e})")
    for path in sys.argv[2:]:
        img = rgb(path)
        if img.shape != ref.shape:
            raise SystemExit(f"{path}: shape {img.shape}, reference {ref.shape}")
        if not np.isfinite(img).all():
            raise SystemExit(f"{path}: a pixel is not finite")
        d = img - ref
        mse = np.mean(d * d)
        print(f"{path:40} {mse:10.4e} {mse - floor:10.4e} {np.mean(np.abs(d)):10.4e}  "
              f"{img.mean(axis=(0, 1))}")


if __name__ == "__main__":
    main()
