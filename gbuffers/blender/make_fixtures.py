"""Render the real Blender G-buffer fixtures in gbuffers/blender/.

This script is NOT part of clphong or its tests: CI never installs ``bpy``
(Blender as a Python module, from PyPI) and never runs it.  The files it makes
are committed; rerun it only to regenerate them.

    python3.11 -m venv /tmp/bpy50 && /tmp/bpy50/bin/pip install "bpy==5.0.*" openimageio
    python3.11 -m venv /tmp/bpy45 && /tmp/bpy45/bin/pip install "bpy==4.5.*"
    /tmp/bpy50/bin/python gbuffers/blender/make_fixtures.py \\
        --blender45-python /tmp/bpy45/bin/python

(bpy 4.5 and 5.0 both need CPython 3.11.)  Without ``--blender45-python`` the
4.5 file is left as it is.  It writes, next to itself:

  cycles-5.0.exr              Blender 5.0 default multilayer EXR (multi-part)
  cycles-5.0-interleaved.exr  the same render, image_settings.use_exr_interleave = True
  cycles-4.5.exr              the same scene rendered by Blender 4.5 LTS
  spheres.toml                the clphong scene (camera, lights in watts)
  fixtures.json               ground facts and the EXR layouts observed with OpenImageIO

The scene: three Lambert spheres resting on a finite ground plane (Blender
world coordinates, Z up), a perspective camera, three radius-0 point lights in
two light groups, a black world, Cycles CPU with direct light only
(max_bounces = 0), no shadows (no mesh is visible to shadow rays), no clamp, no
denoiser, no adaptive sampling, transparent film, fixed seed.

Internal mode: ``make_fixtures.py --render-only OUT.exr`` builds the scene in
the running bpy and writes one multilayer EXR (used for the 4.5 subprocess).
"""

import argparse
import json
import os
import re
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))

# ---------------------------------------------------------------- the scene
WIDTH, HEIGHT = 80, 60
SAMPLES = 1024
SEED = 7
CAMERA_LOCATION = (0.6, -8.0, 3.2)
CAMERA_TARGET = (0.0, 0.0, 0.6)
CAMERA_LENS_MM = 50.0
CAMERA_SENSOR_MM = 36.0            # sensor_fit AUTO: the wider side (width)

PLANE_HALF_SIZE = 3.0              # ground plane z = 0, x, y in [-3, 3]
OBJECTS = [
    # name, kind, centre, radius, base colour (linear Rec.709)
    {"name": "Ground", "kind": "plane", "center": (0.0, 0.0, 0.0),
     "radius": None, "color": (0.7, 0.7, 0.7)},
    {"name": "SphereRed", "kind": "sphere", "center": (-1.2, 0.4, 1.0),
     "radius": 1.0, "color": (0.8, 0.15, 0.1)},
    {"name": "SphereGreen", "kind": "sphere", "center": (1.1, -0.2, 0.7),
     "radius": 0.7, "color": (0.15, 0.7, 0.2)},
    {"name": "SphereBlue", "kind": "sphere", "center": (0.1, -1.5, 0.45),
     "radius": 0.45, "color": (0.1, 0.25, 0.8)},
]
SPHERE_SEGMENTS, SPHERE_RINGS = 96, 48

LIGHTS = [
    {"name": "KeyWarm", "position": (3.0, -3.0, 5.0), "power": 500.0,
     "color": (1.0, 0.9, 0.8), "group": "key"},
    {"name": "KeyLeft", "position": (-4.0, -1.5, 3.5), "power": 300.0,
     "color": (0.9, 1.0, 0.9), "group": "key"},
    {"name": "FillFront", "position": (0.5, -5.0, 1.5), "power": 150.0,
     "color": (0.6, 0.7, 1.0), "group": "fill"},
]
GROUPS = ["key", "fill"]


def build_scene(bpy):
    """Build the fixture scene in the current Blender session; return it."""
    import bmesh
    from mathutils import Vector

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    view_layer = scene.view_layers[0]
    v5 = bpy.app.version >= (5, 0, 0)

    # World: black, strength 0 -> no environment light.
    world = bpy.data.worlds.new("World")
    if not v5:
        world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    bg.inputs["Strength"].default_value = 0.0
    scene.world = world

    for spec in OBJECTS:
        mesh = bpy.data.meshes.new(spec["name"])
        bm = bmesh.new()
        if spec["kind"] == "plane":
            bmesh.ops.create_grid(bm, x_segments=1, y_segments=1,
                                  size=PLANE_HALF_SIZE)
        else:
            bmesh.ops.create_uvsphere(bm, u_segments=SPHERE_SEGMENTS,
                                      v_segments=SPHERE_RINGS,
                                      radius=spec["radius"])
        bm.to_mesh(mesh)
        bm.free()
        if spec["kind"] == "sphere":
            mesh.shade_smooth()
        obj = bpy.data.objects.new(spec["name"], mesh)
        obj.location = spec["center"]
        obj.visible_shadow = False          # nothing casts shadows
        scene.collection.objects.link(obj)

        mat = bpy.data.materials.new(spec["name"] + "Mat")
        if not v5:
            mat.use_nodes = True
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        for node in list(nodes):
            if node.type != "OUTPUT_MATERIAL":
                nodes.remove(node)
        out = nodes["Material Output"]
        diffuse = nodes.new("ShaderNodeBsdfDiffuse")      # Lambert
        diffuse.inputs["Color"].default_value = (*spec["color"], 1.0)
        diffuse.inputs["Roughness"].default_value = 0.0
        links.new(diffuse.outputs["BSDF"], out.inputs["Surface"])
        mesh.materials.append(mat)

    for name in GROUPS:
        view_layer.lightgroups.add(name=name)
    for spec in LIGHTS:
        light = bpy.data.lights.new(spec["name"], "POINT")
        light.energy = spec["power"]                    # watts
        light.color = spec["color"]
        light.shadow_soft_size = 0.0                    # true point light
        light.use_soft_falloff = False
        light.exposure = 0.0
        obj = bpy.data.objects.new(spec["name"], light)
        obj.location = spec["position"]
        obj.lightgroup = spec["group"]
        scene.collection.objects.link(obj)

    cam_data = bpy.data.cameras.new("Camera")
    cam_data.type = "PERSP"
    cam_data.lens = CAMERA_LENS_MM
    cam_data.sensor_width = CAMERA_SENSOR_MM
    cam_data.sensor_fit = "AUTO"
    cam_data.dof.use_dof = False
    cam = bpy.data.objects.new("Camera", cam_data)
    cam.location = CAMERA_LOCATION
    direction = Vector(CAMERA_TARGET) - Vector(CAMERA_LOCATION)
    cam.rotation_mode = "QUATERNION"
    cam.rotation_quaternion = direction.to_track_quat("-Z", "Y")
    scene.collection.objects.link(cam)
    scene.camera = cam

    render = scene.render
    render.engine = "CYCLES"
    render.resolution_x, render.resolution_y = WIDTH, HEIGHT
    render.resolution_percentage = 100
    render.pixel_aspect_x = render.pixel_aspect_y = 1.0
    render.film_transparent = True
    render.use_compositing = False
    render.use_sequencer = False
    for prop in render.bl_rna.properties:               # no stamp metadata
        if prop.identifier.startswith("use_stamp"):
            setattr(render, prop.identifier, False)

    cy = scene.cycles
    cy.device = "CPU"
    cy.samples = SAMPLES
    cy.use_adaptive_sampling = False
    cy.seed = SEED
    cy.use_animated_seed = False
    cy.max_bounces = 0
    cy.diffuse_bounces = cy.glossy_bounces = 0
    cy.transmission_bounces = cy.volume_bounces = 0
    cy.transparent_max_bounces = 0
    cy.caustics_reflective = cy.caustics_refractive = False
    cy.sample_clamp_direct = cy.sample_clamp_indirect = 0.0
    cy.light_sampling_threshold = 0.0
    cy.use_light_tree = False
    cy.use_denoising = False
    cy.use_preview_denoising = False
    # pixel filter: left at Blender's default (Blackman-Harris, 1.5 px)

    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0

    view_layer.use_pass_combined = True
    view_layer.use_pass_position = True
    view_layer.use_pass_normal = True
    view_layer.use_pass_diffuse_color = True
    view_layer.use_pass_z = False
    view_layer.cycles.use_denoising = False
    return scene


def set_multilayer_exr(bpy, scene, interleave=None):
    im = scene.render.image_settings
    if hasattr(im, "media_type"):                       # Blender 5.0+
        im.media_type = "MULTI_LAYER_IMAGE"
    im.file_format = "OPEN_EXR_MULTILAYER"
    im.color_depth = "32"
    im.exr_codec = "ZIP"
    if interleave is not None:
        im.use_exr_interleave = interleave


def render_to(bpy, outputs):
    """Render once; save the Render Result to each (path, interleave) pair."""
    scene = build_scene(bpy)
    bpy.ops.render.render()
    result = bpy.data.images["Render Result"]
    for path, interleave in outputs:
        set_multilayer_exr(bpy, scene, interleave)
        result.save_render(filepath=path, scene=scene)
        print("wrote", path, os.path.getsize(path), "bytes")
    return scene


# ------------------------------------------------------- inspect and record
def exr_headers(path):
    """The raw OpenEXR headers (pure Python): version flags and, per part,
    the channel list in file order plus the attributes a reader cares about."""
    import struct
    with open(path, "rb") as f:
        data = f.read()
    if data[:4] != b"\x76\x2f\x31\x01":
        raise ValueError(f"{path}: not an OpenEXR file")
    version = struct.unpack("<I", data[4:8])[0]
    flags = {"version": version & 0xFF, "multipart": bool(version & 0x1000),
             "long_names": bool(version & 0x400),
             "tiled": bool(version & 0x200), "deep": bool(version & 0x800)}
    pixel_types = {0: "uint", 1: "half", 2: "float"}
    line_orders = {0: "INCREASING_Y", 1: "DECREASING_Y", 2: "RANDOM_Y"}
    compressions = {0: "NONE", 1: "RLE", 2: "ZIPS", 3: "ZIP", 4: "PIZ"}
    pos, headers = 8, []

    def cstr(at):
        end = data.index(b"\0", at)
        return data[at:end].decode(), end + 1

    while True:
        header = {}
        while data[pos] != 0:
            name, pos = cstr(pos)
            kind, pos = cstr(pos)
            size = struct.unpack("<i", data[pos:pos + 4])[0]
            value = data[pos + 4:pos + 4 + size]
            pos += 4 + size
            if kind == "chlist":
                channels, q = [], 0
                while value[q] != 0:
                    end = value.index(b"\0", q)
                    ptype = struct.unpack("<i", value[end + 1:end + 5])[0]
                    channels.append([value[q:end].decode(), pixel_types[ptype]])
                    q = end + 17
                header[name] = channels
            elif kind == "string":
                header[name] = value.decode(errors="replace")
            elif kind == "box2i":
                header[name] = list(struct.unpack("<4i", value))
            elif kind == "lineOrder":
                header[name] = line_orders[value[0]]
            elif kind == "compression":
                header[name] = compressions.get(value[0], value[0])
            elif kind == "int":
                header[name] = struct.unpack("<i", value)[0]
            elif kind == "float":
                header[name] = struct.unpack("<f", value)[0]
            else:
                header[name] = f"<{kind}, {size} bytes>"
        pos += 1
        headers.append(header)
        if not flags["multipart"] or data[pos] == 0:
            break
    return flags, headers


def exr_layout(path):
    """Parts, channels, pixel types and windows of an EXR, read with OIIO."""
    import OpenImageIO as oiio
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise RuntimeError(oiio.geterror())
    parts = []
    index = 0
    while inp.seek_subimage(index, 0):
        spec = inp.spec()
        formats = [str(f) for f in spec.channelformats] or \
            [str(spec.format)] * spec.nchannels
        parts.append({
            "name": spec.get_string_attribute("name")
                    or spec.get_string_attribute("oiio:subimagename"),
            "channels": list(spec.channelnames),
            "pixel_types": sorted(set(formats)),
            "data_window": [spec.x, spec.y, spec.width, spec.height],
            "display_window": [spec.full_x, spec.full_y,
                               spec.full_width, spec.full_height],
            "compression": spec.get_string_attribute("compression"),
        })
        index += 1
    inp.close()
    flags, headers = exr_headers(path)
    keep = ("name", "type", "view", "channels", "lineOrder", "compression",
            "dataWindow", "displayWindow", "colorInteropID", "chunkCount")
    return {"bytes": os.path.getsize(path), "parts": len(parts),
            "oiio_subimages": parts, "header_flags": flags,
            "headers": [{k: h[k] for k in keep if k in h} |
                        {"other_attributes": sorted(set(h) - set(keep))}
                        for h in headers]}


def toml_vec(v):
    return "[" + ", ".join(repr(float(x)) for x in v) + "]"


def write_toml(path):
    lines = [
        "# clphong scene for the Blender fixtures in this folder",
        "# (cycles-5.0.exr, cycles-5.0-interleaved.exr, cycles-4.5.exr).",
        "# Written by make_fixtures.py; Blender world coordinates, Z up.",
        "# Lights are radius-0 Cycles point lights: power in watts, so the",
        "# direct diffuse radiance is rho/pi * color * power/(4 pi) * cos/d^2.",
        "",
        "[camera]",
        'type = "perspective"',
        f"position = {toml_vec(CAMERA_LOCATION)}",
        "",
        "[material]",
        'model = "phong"',
        "k_a = 0.0",
        "k_d = 1.0",
        "k_s = 0.0",
        "h = 1.0",
    ]
    for light in LIGHTS:
        lines += [
            "",
            "[[light]]  # {}".format(light["name"]),
            'type = "point"',
            "position = {}".format(toml_vec(light["position"])),
            "color = {}".format(toml_vec(light["color"])),
            "power = {!r}".format(float(light["power"])),
            'group = "{}"'.format(light["group"]),
        ]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--blender45-python",
                    help="python of a venv with bpy 4.5 (renders cycles-4.5.exr)")
    ap.add_argument("--render-only", metavar="OUT.exr",
                    help=argparse.SUPPRESS)
    args = ap.parse_args()

    import bpy
    if args.render_only:
        render_to(bpy, [(args.render_only, None)])
        print("BLENDER_VERSION", bpy.app.version_string)
        return

    if bpy.app.version[:2] != (5, 0):
        sys.exit(f"run this with bpy 5.0 (found {bpy.app.version_string})")
    default = os.path.join(HERE, "cycles-5.0.exr")
    interleaved = os.path.join(HERE, "cycles-5.0-interleaved.exr")
    scene = render_to(bpy, [(default, False), (interleaved, True)])
    camera_matrix = [[round(v, 7) for v in row]
                     for row in scene.camera.matrix_world]

    v45_path = os.path.join(HERE, "cycles-4.5.exr")
    json_path = os.path.join(HERE, "fixtures.json")
    blender45 = None
    if args.blender45_python:
        out = subprocess.run([args.blender45_python, os.path.abspath(__file__),
                              "--render-only", v45_path], check=True,
                             capture_output=True, text=True).stdout
        blender45 = next(l.split(" ", 1)[1] for l in out.splitlines()
                     if l.startswith("BLENDER_VERSION "))
    elif os.path.exists(json_path):
        with open(json_path) as f:
            blender45 = json.load(f)["blender"].get("cycles-4.5.exr")

    write_toml(os.path.join(HERE, "spheres.toml"))
    facts = {
        "generator": "gbuffers/blender/make_fixtures.py",
        "blender": {"cycles-5.0.exr": bpy.app.version_string,
                    "cycles-5.0-interleaved.exr": bpy.app.version_string,
                    "cycles-4.5.exr": blender45},
        "render": {
            "engine": "CYCLES", "device": "CPU", "samples": SAMPLES,
            "adaptive_sampling": False, "seed": SEED,
            "resolution": [WIDTH, HEIGHT], "max_bounces": 0,
            "use_light_tree": False, "light_sampling_threshold": 0.0,
            "sample_clamp_direct": 0.0, "denoising": False,
            "film_transparent": True,
            "pixel_filter": "BLACKMAN_HARRIS 1.5 px (default)",
            "shadows": "none: every mesh has visible_shadow = False",
            "world": "black, strength 0",
            "exr": "OPEN_EXR_MULTILAYER, 32-bit float, ZIP",
            "image_settings_5.0": {"media_type": "MULTI_LAYER_IMAGE",
                                   "file_format": "OPEN_EXR_MULTILAYER",
                                   "use_exr_interleave": "False (default)"
                                   " / True for the -interleaved file"},
        },
        "camera": {"location": CAMERA_LOCATION, "target": CAMERA_TARGET,
                   "rotation": "track_to(-Z forward, Y up)",
                   "lens_mm": CAMERA_LENS_MM, "sensor_width_mm": CAMERA_SENSOR_MM,
                   "sensor_fit": "AUTO",
                   "matrix_world": camera_matrix},
        "lights": [dict(l, type="POINT", radius=0.0, use_soft_falloff=False)
                   for l in LIGHTS],
        "light_groups": GROUPS,
        "objects": [dict(o, material="Diffuse BSDF, roughness 0",
                         **({"uv_sphere": [SPHERE_SEGMENTS, SPHERE_RINGS],
                             "shading": "smooth"} if o["kind"] == "sphere"
                            else {"half_size": PLANE_HALF_SIZE}))
                    for o in OBJECTS],
        "files": {},
    }
    for name in ("cycles-5.0.exr", "cycles-5.0-interleaved.exr",
                 "cycles-4.5.exr"):
        path = os.path.join(HERE, name)
        if os.path.exists(path):
            facts["files"][name] = exr_layout(path)
    facts["files"]["cycles-5.0-interleaved.exr"]["option"] = \
        "scene.render.image_settings.use_exr_interleave = True"
    text = json.dumps(facts, indent=1)
    # one line per short list of numbers or [name, type] pair
    text = re.sub(r"\[\s+([^\[\]{}]*?)\s+\]",
                  lambda m: "[" + re.sub(r",\s+", ", ", m.group(1)) + "]",
                  text)
    with open(json_path, "w") as f:
        f.write(text + "\n")
    print("wrote", json_path)


if __name__ == "__main__":
    main()
