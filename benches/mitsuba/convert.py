#!/usr/bin/env python3
"""Converts a Lacuna scene file of the Cornell-box kind into a Mitsuba 3 scene (XML + OBJs).

Supported (and checked): one OBJ with Lambertian materials (MTL `Kd`) and emissive ones
(`Ke`, one-sided area lights as in Lacuna), a perspective camera (eye, target, up, vertical
fov), width, height and max_depth. Anything else (specular `Ks`, textures, transforms, other
lights) is rejected rather than silently dropped.

Mitsuba's `max_depth` counts path vertices, Lacuna's counts bounces: Lacuna's D is
Mitsuba's D + 1. The pixel filter is a box, as Lacuna's pixel samples are uniform over the
pixel. Mitsuba's own Russian roulette (`rr_depth` 5) is left at its default.

    python3 convert.py scenes/cornell-box/cornell-box.json OUTDIR
writes OUTDIR/scene.xml and one OBJ per material (fan-triangulated like tobj), and prints
the scene's summary. The XML takes `spp`, `seed` and `sampler` as `$` parameters.
"""
import json
import os
import sys


def parse_mtl(path):
    mats, cur = {}, None
    with open(path) as f:
        for line in f:
            tok = line.split("#", 1)[0].split()
            if not tok:
                continue
            if tok[0] == "newmtl":
                cur = mats.setdefault(tok[1], {"Kd": [0.0] * 3, "Ke": [0.0] * 3, "Ks": [0.0] * 3})
            elif cur is not None and tok[0] in ("Kd", "Ke", "Ks"):
                cur[tok[0]] = [float(x) for x in tok[1:4]]
            elif cur is not None and tok[0].startswith("map_"):
                raise SystemExit(f"{path}: textures ({tok[0]}) are not supported by this converter")
    return mats


def parse_obj(path):
    """Vertices and, per material, the fan-triangulated faces (0-based vertex indices)."""
    verts, faces, mtllib, cur = [], {}, None, "default"
    with open(path) as f:
        for n, line in enumerate(f, 1):
            tok = line.split("#", 1)[0].split()
            if not tok:
                continue
            if tok[0] == "v":
                verts.append([float(x) for x in tok[1:4]])
            elif tok[0] == "mtllib":
                mtllib = tok[1]
            elif tok[0] == "usemtl":
                cur = tok[1]
            elif tok[0] == "f":
                idx = []
                for t in tok[1:]:
                    i = int(t.split("/")[0])
                    idx.append(i - 1 if i > 0 else len(verts) + i)
                if len(idx) < 3 or min(idx) < 0 or max(idx) >= len(verts):
                    raise SystemExit(f"{path}:{n}: bad face")
                for k in range(1, len(idx) - 1):
                    faces.setdefault(cur, []).append((idx[0], idx[k], idx[k + 1]))
    return verts, faces, mtllib


def vec(v):
    return ", ".join(repr(float(x)) for x in v)


def convert(scene_path, out_dir):
    base = os.path.dirname(os.path.abspath(scene_path))
    with open(scene_path) as f:
        scene = json.load(f)
    allowed = {"comment", "objects", "camera", "render"}
    if set(scene) - allowed:
        raise SystemExit(f"{scene_path}: unsupported fields {sorted(set(scene) - allowed)}")
    objects = scene["objects"]
    if len(objects) != 1 or set(objects[0]) != {"obj"}:
        raise SystemExit(f"{scene_path}: exactly one object without transform or overrides")
    obj_path = os.path.join(base, objects[0]["obj"])
    verts, faces, mtllib = parse_obj(obj_path)
    mats = parse_mtl(os.path.join(os.path.dirname(obj_path), mtllib))
    cam, render = scene["camera"], scene["render"]
    if set(cam) - {"eye", "target", "up", "fov"}:
        raise SystemExit(f"{scene_path}: only a pinhole look-at camera is supported")
    if render.get("integrator", "path") != "path":
        raise SystemExit(f"{scene_path}: only the path integrator has a Mitsuba counterpart")
    width, height = render.get("width", 512), render.get("height", 512)
    max_depth = render.get("max_depth", 8)

    os.makedirs(out_dir, exist_ok=True)
    shapes = []
    for name, tris in faces.items():
        m = mats[name]
        if any(m["Ks"]):
            raise SystemExit(f"{mtllib}: material {name} has Ks: only Lambertian is supported")
        used = sorted({i for t in tris for i in t})
        local = {g: i for i, g in enumerate(used)}
        mesh = os.path.join(out_dir, f"{name}.obj")
        with open(mesh, "w") as f:
            for g in used:
                f.write("v {} {} {}\n".format(*verts[g]))
            for t in tris:
                f.write("f {} {} {}\n".format(*(local[i] + 1 for i in t)))
        emitter = ""
        if any(m["Ke"]):
            emitter = f'\n        <emitter type="area"><rgb name="radiance" value="{vec(m["Ke"])}"/></emitter>'
        shapes.append(
            f'    <shape type="obj">\n        <string name="filename" value="{name}.obj"/>\n'
            f'        <bsdf type="diffuse"><rgb name="reflectance" value="{vec(m["Kd"])}"/></bsdf>'
            f"{emitter}\n    </shape>"
        )
    xml = f"""<scene version="3.0.0">
    <!-- Converted from {os.path.relpath(scene_path)} by benches/mitsuba/convert.py -->
    <default name="spp" value="64"/>
    <default name="seed" value="0"/>
    <default name="sampler" value="independent"/>
    <integrator type="path">
        <!-- Lacuna's max_depth {max_depth} (bounces) = Mitsuba's {max_depth + 1} (vertices) -->
        <integer name="max_depth" value="{max_depth + 1}"/>
    </integrator>
    <sensor type="perspective">
        <string name="fov_axis" value="y"/>
        <float name="fov" value="{float(cam['fov'])}"/>
        <transform name="to_world">
            <lookat origin="{vec(cam['eye'])}" target="{vec(cam['target'])}" up="{vec(cam['up'])}"/>
        </transform>
        <sampler type="$sampler">
            <integer name="sample_count" value="$spp"/>
            <integer name="seed" value="$seed"/>
        </sampler>
        <film type="hdrfilm">
            <integer name="width" value="{width}"/>
            <integer name="height" value="{height}"/>
            <string name="pixel_format" value="rgb"/>
            <rfilter type="box"/>
        </film>
    </sensor>
{chr(10).join(shapes)}
</scene>
"""
    with open(os.path.join(out_dir, "scene.xml"), "w") as f:
        f.write(xml)
    n = sum(len(t) for t in faces.values())
    print(f"{out_dir}/scene.xml: {n} triangles in {len(faces)} materials, {width}x{height}, "
          f"Lacuna max_depth {max_depth} -> Mitsuba max_depth {max_depth + 1}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit("usage: convert.py SCENE.json OUTDIR")
    convert(sys.argv[1], sys.argv[2])
