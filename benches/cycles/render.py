"""Render a Lacuna family scene (`lacuna family SEED --out DIR`: OBJ + MTL + scene file) with
Blender Cycles on the CPU, with or without Open PGL path guiding, for a fixed time, and write a
linear RGB EXR.

    python render.py SCENE.json OUT.exr --time S [--guiding] [--width W --height H]
        [--max-depth D] [--threads T] [--seed N] [--cycles KEY=VALUE ...]

Fair-match settings (the brief's): emission front-facing only (Blender's is two-sided: on
back faces the light's shader leaves its emission out), both clamps 0, a box pixel filter of one pixel, no
denoising, no adaptive sampling, no light threshold. Materials: `Kd` as a Diffuse BSDF, `Ke`
as an Emission of strength 1 (radiance `Ke`, as Lacuna reads it). The OBJ is imported without
an axis change and the camera is placed in the same frame (look-at, vertical fov).
Max bounces D - 1: Lacuna's `--max-depth D` counts surface vertices of the camera path, Cycles
counts bounces after the first hit.

Prints one line: samples reached and render seconds.
"""
import argparse
import json
import math
import os
import re
import sys
import time

import bpy
from mathutils import Matrix, Vector


def parse_mtl(path):
    mats, cur = {}, None
    for line in open(path):
        p = line.split()
        if not p:
            continue
        if p[0] == "newmtl":
            cur = p[1]
            mats[cur] = {"Kd": (0.0, 0.0, 0.0), "Ke": (0.0, 0.0, 0.0)}
        elif p[0] in ("Kd", "Ke") and cur:
            mats[cur][p[0]] = tuple(float(x) for x in p[1:4])
    return mats


def material(name, kd, ke):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nt = m.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (*kd, 1.0)
    if max(ke) > 0:
        emission = nt.nodes.new("ShaderNodeEmission")
        emission.inputs["Color"].default_value = (*ke, 1.0)
        emission.inputs["Strength"].default_value = 1.0
        add = nt.nodes.new("ShaderNodeAddShader")
        nt.links.new(emission.outputs[0], add.inputs[0])
        nt.links.new(diffuse.outputs[0], add.inputs[1])
        # Front faces only: back faces get the diffuse part alone.
        geometry = nt.nodes.new("ShaderNodeNewGeometry")
        mix = nt.nodes.new("ShaderNodeMixShader")
        nt.links.new(geometry.outputs["Backfacing"], mix.inputs["Fac"])
        nt.links.new(add.outputs[0], mix.inputs[1])
        nt.links.new(diffuse.outputs[0], mix.inputs[2])
        nt.links.new(mix.outputs[0], out.inputs["Surface"])
    else:
        nt.links.new(diffuse.outputs[0], out.inputs["Surface"])
    return m


def main():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("out")
    ap.add_argument("--time", type=float, required=True)
    ap.add_argument("--guiding", action="store_true")
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--height", type=int, default=48)
    ap.add_argument("--max-depth", type=int, default=65)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cycles", action="append", default=[], metavar="KEY=VALUE",
                    help="a scene.cycles setting, e.g. guiding_training_samples=0")
    a = ap.parse_args(argv)

    spec = json.load(open(a.scene))
    base = os.path.dirname(os.path.abspath(a.scene))
    obj = os.path.join(base, spec["objects"][0]["obj"])

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    bpy.ops.wm.obj_import(filepath=obj, forward_axis="Y", up_axis="Z")
    mats = parse_mtl(obj[:-4] + ".mtl")
    for o in scene.objects:
        if o.type != "MESH":
            continue
        for slot in o.material_slots:
            name = slot.material.name.split(".")[0]
            kd, ke = mats[name]["Kd"], mats[name]["Ke"]
            slot.material = material(name + "_cycles", kd, ke)

    cam = spec["camera"]
    eye, target, up = (Vector(cam[k]) for k in ("eye", "target", "up"))
    forward = (target - eye).normalized()
    right = forward.cross(up).normalized()
    true_up = right.cross(forward)
    cam_data = bpy.data.cameras.new("camera")
    cam_data.sensor_fit = "VERTICAL"
    cam_data.angle_y = math.radians(cam["fov"])
    cam_obj = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam_obj)
    rot = Matrix((right, true_up, -forward)).transposed()
    cam_obj.matrix_world = Matrix.Translation(eye) @ rot.to_4x4()
    scene.camera = cam_obj

    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene.world = world

    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x, r.resolution_y, r.resolution_percentage = a.width, a.height, 100
    r.threads_mode, r.threads = "FIXED", a.threads
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_depth = "32"
    r.image_settings.exr_codec = "NONE"
    r.film_transparent = False
    scene.view_settings.view_transform = "Standard"
    c = scene.cycles
    c.device = "CPU"
    c.samples = 1 << 24
    c.time_limit = a.time
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.seed = a.seed
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    bounces = max(a.max_depth - 1, 0)
    c.max_bounces = bounces
    c.diffuse_bounces = bounces
    c.glossy_bounces = bounces
    c.transmission_bounces = bounces
    c.transparent_max_bounces = bounces
    c.use_guiding = a.guiding
    if a.guiding:
        c.use_surface_guiding = True
        c.use_volume_guiding = False
    for setting in a.cycles:
        key, value = setting.split("=", 1)
        current = getattr(c, key)
        setattr(c, key, type(current)(value) if not isinstance(current, bool)
                else value.lower() in ("1", "true", "on"))
    r.filepath = a.out
    # The samples reached appear only in the render's status lines ("Sample N/M").
    reached = [0]

    def stats(status):
        m = re.search(r"Sample (\d+)/", status)
        if m:
            reached[0] = max(reached[0], int(m.group(1)))

    bpy.app.handlers.render_stats.append(stats)
    start = time.time()
    bpy.ops.render.render(write_still=True)
    seconds = time.time() - start
    print(f"cycles: guiding={a.guiding} {reached[0]} spp in {seconds:.2f} s -> {a.out}")


if __name__ == "__main__":
    main()
