"""Writes reflector.obj and reflector.mtl: the faceted paraboloid mirror of reflector_lamp.json.

A paraboloid y = depth - r^2 / (4 f) opening downward (vertex up), focal length f, aperture
radius R at y = 0, as `rings` x `segments` flat facets (a faceted reflector: the facets break
the beam into a pattern the light field has to record). Public domain (CC0).
"""
import math

F, R, RINGS, SEGMENTS = 0.02, 0.1, 10, 24
DEPTH = R * R / (4 * F)

with open("reflector.mtl", "w") as mtl:
    mtl.write("# Polished aluminium reflector (mirror: illum 3, reflectance Ks).\n")
    mtl.write("newmtl reflector\nKd 0 0 0\nKs 0.9 0.9 0.9\nillum 3\n")

with open("reflector.obj", "w") as obj:
    obj.write("# Faceted paraboloid reflector, written by generate.py (CC0).\n")
    obj.write(f"# focal length {F} m, aperture radius {R} m at y = 0, vertex at y = {DEPTH:.4f} m.\n")
    obj.write("mtllib reflector.mtl\nusemtl reflector\n")
    obj.write(f"v 0 {DEPTH:.6f} 0\n")
    for ring in range(1, RINGS + 1):
        r = R * ring / RINGS
        y = DEPTH - r * r / (4 * F)
        for k in range(SEGMENTS):
            a = 2 * math.pi * k / SEGMENTS
            obj.write(f"v {r * math.cos(a):.6f} {y:.6f} {r * math.sin(a):.6f}\n")

    def vertex(ring, k):
        return 1 if ring == 0 else 2 + (ring - 1) * SEGMENTS + k % SEGMENTS

    for k in range(SEGMENTS):
        obj.write(f"f {vertex(0, 0)} {vertex(1, k + 1)} {vertex(1, k)}\n")
    for ring in range(1, RINGS):
        for k in range(SEGMENTS):
            a, b = vertex(ring, k), vertex(ring, k + 1)
            c, d = vertex(ring + 1, k + 1), vertex(ring + 1, k)
            obj.write(f"f {a} {b} {c}\nf {a} {c} {d}\n")
