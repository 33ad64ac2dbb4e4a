"""Build and render the Cycles reference scene; run by Blender's Python (``bpy``), not imported.

Usage: ``<python with bpy> cycles_scene.py FOLDER``. FOLDER holds what
:mod:`snell_bench.render.cycles` wrote: ``scene.npz`` (meshes in Blender's frame: x right, y forward,
z up, the camera at the origin looking along +y), ``texture.png`` (I⁻, 8-bit sRGB, top row first)
and ``settings.json``. The script writes ``render.jpg`` (the view transform applied, as Blender
saves a render) or, with ``"output": "linear"``, ``linear.npy`` (``(H, W, 3)`` float32 scene-linear
RGB, top row first), and ``info.json`` (Blender's version, the seconds the render took).
"""

import json
import os
import sys
import time

import bpy
import numpy as np


def build_mesh(name, vertices, faces, normals, uv=None):
    """A Blender object from arrays: smooth shaded with the given vertex normals."""
    me = bpy.data.meshes.new(name)
    nv, nf = len(vertices), len(faces)
    me.vertices.add(nv)
    me.vertices.foreach_set("co", np.ascontiguousarray(vertices, np.float32).ravel())
    me.loops.add(3 * nf)
    me.loops.foreach_set("vertex_index", np.ascontiguousarray(faces, np.int32).ravel())
    me.polygons.add(nf)
    me.polygons.foreach_set("loop_start", np.arange(0, 3 * nf, 3, dtype=np.int32))
    me.polygons.foreach_set("use_smooth", np.ones(nf, bool))
    if uv is not None:
        layer = me.uv_layers.new(name="UVMap")
        layer.data.foreach_set("uv", np.ascontiguousarray(uv[faces.ravel()], np.float32).ravel())
    me.update(calc_edges=True)
    me.normals_split_custom_set_from_vertices([tuple(n) for n in np.asarray(normals, np.float64)])
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def background_material(texture_path, unlit):
    """Lit: the glTF look of the authors' MoGe mesh (Principled BSDF, I⁻ as base colour, metallic
    0.5, roughness 1). Unlit: I⁻ emitted from the front side only, as the Mitsuba reference."""
    mat = bpy.data.materials.new("background")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = bpy.data.images.load(texture_path)
    tex.image.colorspace_settings.name = "sRGB"
    tex.interpolation = "Closest" if unlit else "Linear"
    if unlit:
        emit = nodes.new("ShaderNodeEmission")
        emit.inputs["Strength"].default_value = 1.0
        links.new(tex.outputs["Color"], emit.inputs["Color"])
        geo, black, mix = (
            nodes.new("ShaderNodeNewGeometry"),
            nodes.new("ShaderNodeEmission"),
            nodes.new("ShaderNodeMixShader"),
        )
        black.inputs["Strength"].default_value = 0.0
        links.new(geo.outputs["Backfacing"], mix.inputs["Fac"])
        links.new(emit.outputs["Emission"], mix.inputs[1])
        links.new(black.outputs["Emission"], mix.inputs[2])
        links.new(mix.outputs["Shader"], out.inputs["Surface"])
    else:
        bsdf = nodes.new("ShaderNodeBsdfPrincipled")
        bsdf.inputs["Metallic"].default_value = 0.5
        bsdf.inputs["Roughness"].default_value = 1.0
        links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
        links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def glass_material(ior, roughness):
    """Refraction BSDF for camera rays, Glass BSDF for every other ray (Light Path "Is Camera Ray")."""
    mat = bpy.data.materials.new("glass")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out, path, mix = (
        nodes.new("ShaderNodeOutputMaterial"),
        nodes.new("ShaderNodeLightPath"),
        nodes.new("ShaderNodeMixShader"),
    )
    refraction, glass = nodes.new("ShaderNodeBsdfRefraction"), nodes.new("ShaderNodeBsdfGlass")
    for node in (refraction, glass):
        node.inputs["IOR"].default_value = ior
        node.inputs["Roughness"].default_value = roughness
        node.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    links.new(path.outputs["Is Camera Ray"], mix.inputs["Fac"])
    links.new(glass.outputs["BSDF"], mix.inputs[1])
    links.new(refraction.outputs["BSDF"], mix.inputs[2])
    links.new(mix.outputs["Shader"], out.inputs["Surface"])
    return mat


def add_camera(s):
    """A pinhole at the origin looking along +y, z up; focal length and shift in pixels."""
    data = bpy.data.cameras.new("camera")
    cam = bpy.data.objects.new("camera", data)
    bpy.context.scene.collection.objects.link(cam)
    cam.rotation_euler = (np.pi / 2, 0.0, 0.0)
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = 36.0
    data.lens = s["fx"] * 36.0 / s["width"]
    data.shift_x, data.shift_y = s["shift_x"], s["shift_y"]
    data.clip_start, data.clip_end = s["clip_start"], s["clip_end"]
    scene = bpy.context.scene
    scene.camera = cam
    scene.render.resolution_x, scene.render.resolution_y = s["width"], s["height"]
    scene.render.resolution_percentage = 100


def add_light(light):
    """A shadowless point light, hidden from camera, glossy and transmission rays, with no
    specular highlight."""
    data = bpy.data.lights.new("light", "POINT")
    data.energy = light["energy"]
    data.color = light["colour"]
    data.shadow_soft_size = light["radius"]
    data.use_shadow = False
    data.specular_factor = 0.0
    ob = bpy.data.objects.new("light", data)
    ob.location = light["position"]
    ob.visible_camera = ob.visible_glossy = ob.visible_transmission = False
    bpy.context.scene.collection.objects.link(ob)


def set_world(colour, strength):
    world = bpy.context.scene.world or bpy.data.worlds.new("World")
    bpy.context.scene.world = world
    world.use_nodes = True
    bg = world.node_tree.nodes.get("Background") or world.node_tree.nodes.new("ShaderNodeBackground")
    bg.inputs["Color"].default_value = (*colour, 1.0)
    bg.inputs["Strength"].default_value = strength


def set_render(s, folder):
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = s["samples"]
    c.use_adaptive_sampling = s["adaptive"]
    c.seed = s["seed"]
    c.sample_clamp_direct, c.sample_clamp_indirect = s["clamp_direct"], s["clamp_indirect"]
    c.glossy_bounces = s["glossy_bounces"]
    c.caustics_reflective = c.caustics_refractive = False
    c.use_denoising = False
    for layer in scene.view_layers:
        layer.cycles.use_denoising = False
    c.pixel_filter_type = s["pixel_filter"]
    scene.render.filter_size = s["filter_width"]
    if s.get("threads"):
        scene.render.threads_mode, scene.render.threads = "FIXED", s["threads"]
    vs = scene.view_settings
    if s["view_transform"]:
        vs.view_transform = s["view_transform"]
    vs.exposure = s["exposure"]
    fmt = scene.render.image_settings
    if s["output"] == "linear":
        fmt.file_format, fmt.color_depth, fmt.color_mode = "OPEN_EXR", "32", "RGB"
        scene.render.filepath = os.path.join(folder, "linear.exr")
    else:
        fmt.file_format, fmt.quality, fmt.color_mode = "JPEG", s["jpeg_quality"], "RGB"
        scene.render.filepath = os.path.join(folder, "render.jpg")
    return vs.view_transform


def main(folder):
    s = json.load(open(os.path.join(folder, "settings.json")))
    data = np.load(os.path.join(folder, "scene.npz"))
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob, do_unlink=True)
    unlit = s["lighting"] == "unlit"
    bg = build_mesh("background", data["bg_v"], data["bg_f"], data["bg_n"], data["bg_uv"])
    bg.data.materials.append(background_material(os.path.join(folder, "texture.png"), unlit))
    glass = build_mesh("object", data["obj_v"], data["obj_f"], data["obj_n"])
    glass.data.materials.append(glass_material(s["ior"], s["roughness"]))
    add_camera(s)
    if s["light"] is not None:
        add_light(s["light"])
    set_world(s["world_colour"], s["world_strength"])
    view = set_render(s, folder)
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    seconds = time.perf_counter() - t0
    if s["output"] == "linear":
        img = bpy.data.images.load(os.path.join(folder, "linear.exr"))
        px = np.empty(s["width"] * s["height"] * 4, np.float32)
        img.pixels.foreach_get(px)
        rgb = px.reshape(s["height"], s["width"], 4)[::-1, :, :3]  # Blender's rows run bottom to top
        np.save(os.path.join(folder, "linear.npy"), np.ascontiguousarray(rgb))
    info = {"blender": bpy.app.version_string, "render_s": seconds, "view_transform": view}
    json.dump(info, open(os.path.join(folder, "info.json"), "w"))


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--") + 1] if "--" in sys.argv else sys.argv[1])
