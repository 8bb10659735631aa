"""Writes the sample IES LM-63 files of this folder (synthetic luminaires made for Lacuna).

Run: python3 generate.py   (no dependencies)
"""
import math


def write(name, keywords, gammas, cs, f):
    lines = ["IES:LM-63-2019"] + [f"[{k}] {v}" for k, v in keywords] + ["TILT=NONE"]
    # lamps, lumens per lamp (-1: absolute photometry), multiplier, counts, type C, metres,
    # width, length, height; ballast factor, ballast-lamp factor, watts.
    lines.append(f"1 -1 1.0 {len(gammas)} {len(cs)} 1 2 0.2 0.2 0.05")
    lines.append("1.0 1.0 25")

    def rows(values):
        return [" ".join(values[i:i + 10]) for i in range(0, len(values), 10)]

    lines += rows([f"{g:g}" for g in gammas])
    lines += rows([f"{c:g}" for c in cs])
    for c in cs:
        lines += rows([f"{max(0.0, f(g, c)):.1f}" for g in gammas])
    with open(name, "w", newline="") as out:
        out.write("\r\n".join(lines) + "\r\n")


def downlight(g, c):
    """A recessed downlight, slightly wider along C0 (quadrant symmetric)."""
    gr, cr = math.radians(g), math.radians(c)
    width = math.radians(28 + 8 * math.cos(cr) ** 2)
    return 1200 * math.exp(-(gr / width) ** 2) + (60 * math.cos(gr) if g < 90 else 0)


def wallwasher(g, c):
    """An asymmetric wall washer throwing towards C0 (bilateral about C0-C180)."""
    gr, cr = math.radians(g), math.radians(c)
    lobe = math.exp(-((gr - math.radians(35)) / math.radians(22)) ** 2)
    lobe *= 0.25 + 0.75 * max(0.0, math.cos(cr)) ** 2
    return 900 * lobe + (15 * math.cos(gr) if g < 90 else 0)


write("downlight.ies",
      [("TEST", "Lacuna sample"), ("MANUFAC", "Lacuna (synthetic)"), ("LUMCAT", "LAC-DL-1"),
       ("LUMINAIRE", "recessed downlight, quadrant symmetric")],
      [i * 2.5 for i in range(37)], [i * 15.0 for i in range(7)], downlight)
write("wallwasher.ies",
      [("TEST", "Lacuna sample"), ("MANUFAC", "Lacuna (synthetic)"), ("LUMCAT", "LAC-WW-1"),
       ("LUMINAIRE", "asymmetric wall washer, bilateral symmetry")],
      [i * 5.0 for i in range(37)], [i * 10.0 for i in range(19)], wallwasher)
