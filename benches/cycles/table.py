"""The table of a `guiding.sh` run: per scene, each contender's samples per pixel and MSE above
the reference's own (mean over the runs), speedups by MSE at equal time, and per-sample
variance (MSE x spp) of each guided renderer against its own unguided one.

    python table.py OUT
"""
import collections
import glob
import os
import re
import sys


def main():
    out = sys.argv[1]
    mse = collections.defaultdict(list)
    for line in open(os.path.join(out, "errors.txt")):
        m = re.match(r"\S*/(\d+)-(.+)-(\d+)\.exr\s+(\S+)\s+(\S+)", line)
        if m:
            mse[(int(m.group(1)), m.group(2))].append(float(m.group(5)))
    spp = collections.defaultdict(list)
    for path in glob.glob(os.path.join(out, "*.exr.log")):
        m = re.match(r"(\d+)-(.+)-(\d+)\.exr\.log", os.path.basename(path))
        text = open(path).read()
        s = re.search(r"(\d+) spp", text)
        if m and s:
            spp[(int(m.group(1)), m.group(2))].append(int(s.group(1)))
    mean = lambda v: sum(v) / len(v)
    print("| scene | spp: Cycles / guided / `path` / `path_skeleton` / `bdpt` | Cycles guided / "
          "Cycles by MSE | per-sample variance, guided / unguided: Cycles, `path_skeleton` | "
          "`path` / Cycles | `path_skeleton` / `path` | `bdpt` / `path` |")
    print("|---|---|---|---|---|---|---|")
    for seed in sorted({k[0] for k in mse}):
        m = {c: mean(mse[(seed, c)]) for c in
             ("cycles", "cycles-guided", "path", "path_skeleton", "bdpt") if (seed, c) in mse}
        n = {c: mean(spp[(seed, c)]) for c in m if (seed, c) in spp}
        speed = lambda a, b: f"{m[b] / m[a]:.2f}x" if a in m and b in m else "-"
        per = lambda a, b: (f"{m[a] * n[a] / (m[b] * n[b]):.2f}"
                            if a in n and b in n else "-")
        counts = " / ".join(f"{n[c]:.0f}" if c in n else "-" for c in
                            ("cycles", "cycles-guided", "path", "path_skeleton", "bdpt"))
        print(f"| rooms:{seed} | {counts} | {speed('cycles-guided', 'cycles')} | "
              f"{per('cycles-guided', 'cycles')}, {per('path_skeleton', 'path')} | "
              f"{speed('path', 'cycles')} | {speed('path_skeleton', 'path')} | "
              f"{speed('bdpt', 'path')} |")


if __name__ == "__main__":
    main()
