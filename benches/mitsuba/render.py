#!/usr/bin/env python3
"""Renders a converted scene (convert.py) with Mitsuba 3 and times it without its kernel
compilation.

    python3 render.py SCENE.xml OUT.exr (--spp N | --time SECONDS) [--threads 2] [--seed 0]
                      [--pass-spp 64] [--sampler independent] [--variant llvm_ad_rgb]

The image is the mean of passes of `--pass-spp` samples per pixel with distinct seeds (one
wavefront per pass keeps the memory bounded). Before the clock starts, one pass with a seed
no timed pass uses is rendered and discarded: it compiles (or loads from Dr.Jit's cache) the
kernel the timed passes reuse. `--time` renders passes while the next one is expected to end
nearer the budget than stopping now, and at least one (so the time lands within half a pass
of it; compare at the seconds printed); `--spp` renders ceil(N / pass-spp) passes. The summary line
gives spp, seconds and samples per second; the EXR holds RGB only.
"""
import argparse
import time

import numpy as np
import drjit as dr
import mitsuba as mi


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("out")
    budget = ap.add_mutually_exclusive_group(required=True)
    budget.add_argument("--spp", type=int)
    budget.add_argument("--time", type=float)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pass-spp", type=int, default=16)
    ap.add_argument("--sampler", default="independent")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    args = ap.parse_args()

    mi.set_variant(args.variant)
    if args.variant.startswith("llvm"):
        dr.set_thread_count(args.threads)
    scene = mi.load_file(args.scene, spp=args.pass_spp, sampler=args.sampler)

    def render_pass(seed):
        img = mi.render(scene, seed=seed)
        dr.eval(img)
        dr.sync_thread()
        return img

    t0 = time.perf_counter()
    render_pass(0x7FFF0000 + args.seed)
    warmup = time.perf_counter() - t0

    passes = -(-args.spp // args.pass_spp) if args.spp else None
    acc, k, pass_times = None, 0, []
    start = time.perf_counter()
    while True:
        if passes is not None and k == passes:
            break
        if passes is None:
            elapsed = time.perf_counter() - start
            mean_pass = sum(pass_times) / k if k else warmup
            if k > 0 and elapsed + mean_pass / 2 > args.time:
                break
        t = time.perf_counter()
        img = np.array(render_pass(args.seed * 1_000_003 + k), dtype=np.float64)
        pass_times.append(time.perf_counter() - t)
        acc = img if acc is None else acc + img
        k += 1
    seconds = time.perf_counter() - start

    mean = (acc / k).astype(np.float32)
    mi.Bitmap(mean, mi.Bitmap.PixelFormat.RGB).write(args.out)
    h, w = mean.shape[:2]
    spp = k * args.pass_spp
    print(
        f"{args.scene}: {w}x{h}, {spp} spp ({k} passes of {args.pass_spp}, {args.sampler}) of "
        f"{args.variant} path in {seconds:.2f} s: {w * h * spp / seconds / 1e6:.2f} M samples/s, "
        f"{args.threads} threads (warm-up pass {warmup:.2f} s, not counted; passes "
        f"{min(pass_times):.3f}-{max(pass_times):.3f} s) -> {args.out}"
    )


if __name__ == "__main__":
    main()
