#!/usr/bin/env python3
"""Reads a `lacuna compare` curves.csv and answers two questions for one contender's run:
its MAE after SECONDS, and the time its MAE curve took to reach TARGET_MAE (both by
interpolation in log-log between the recorded passes; "not reached" past the last pass).

    python3 crossing.py CURVES.csv SECONDS TARGET_MAE [INTEGRATOR] [RUN]
"""
import csv
import math
import sys


def interp(points, x, xi, yi):
    """Log-log interpolation of column yi at value x of column xi (points sorted by xi)."""
    for a, b in zip(points, points[1:]):
        if (a[xi] - x) * (b[xi] - x) <= 0 and a[xi] != b[xi]:
            f = (math.log(x) - math.log(a[xi])) / (math.log(b[xi]) - math.log(a[xi]))
            return math.exp(math.log(a[yi]) + f * (math.log(b[yi]) - math.log(a[yi])))
    return None


def main():
    if len(sys.argv) < 4:
        raise SystemExit("usage: crossing.py CURVES.csv SECONDS TARGET_MAE [INTEGRATOR] [RUN]")
    seconds, target = float(sys.argv[2]), float(sys.argv[3])
    name = sys.argv[4] if len(sys.argv) > 4 else None
    run = sys.argv[5] if len(sys.argv) > 5 else "0"
    with open(sys.argv[1]) as f:
        rows = [r for r in csv.DictReader(f)
                if (name is None or r["integrator"] == name) and r["run"] == run]
    if not rows:
        raise SystemExit(f"{sys.argv[1]}: no rows for integrator {name}, run {run}")
    pts = sorted((float(r["seconds"]), float(r["mae"]), int(r["spp"])) for r in rows)
    pts = [p for p in pts if p[0] > 0]
    at = interp(pts, seconds, 0, 1)
    # The MAE falls with noise on top: take the first crossing of the target.
    reach = None
    for a, b in zip(pts, pts[1:]):
        if a[1] > target >= b[1]:
            f = (math.log(target) - math.log(a[1])) / (math.log(b[1]) - math.log(a[1]))
            reach = math.exp(math.log(a[0]) + f * (math.log(b[0]) - math.log(a[0])))
            break
    if pts[0][1] <= target:
        reach = pts[0][0]
    print(f"MAE after {seconds:g} s: {at:.4e}" if at else f"MAE after {seconds:g} s: outside the curve")
    print(f"time to MAE {target:.4e}: {reach:.2f} s" if reach else
          f"time to MAE {target:.4e}: not reached in {pts[-1][0]:.2f} s (MAE {pts[-1][1]:.4e})")


if __name__ == "__main__":
    main()
