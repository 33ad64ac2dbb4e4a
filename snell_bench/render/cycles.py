"""The authors' reference render (``utils/render_gt.py``) with Blender Cycles, run as a subprocess.

:func:`render_cycles` writes the scene's inputs to a temporary folder and runs
``blender/cycles_scene.py`` (shipped with the package) with a Python that has ``bpy`` (its own
environment: ``make setup-cycles`` makes ``.venv-cycles``; ``reference.blender_python`` names
another). Without one it raises :class:`CyclesUnavailable`, whose message names both.

Convention:
    - Frames: the camera frame of :mod:`snell_bench.scene.camera` here; Blender's frame (x right,
      y forward, z up, the camera at the origin) is ``(x, z, -y)`` of it (:func:`to_blender`), the
      frame the authors' MoGe mesh is in once Blender imports it.
    - Images: ``(H, W, 3)`` float32 sRGB in [0, 1]; masks ``(H, W)`` bool.
    - The scene (``lighting="authors"``): the background mesh of
      :func:`~snell_bench.scene.depth_mesh.build_background` (vertices at pixel centres, smooth
      vertex normals, UVs at pixel centres) with the look Blender's glTF importer gives the authors'
      MoGe mesh (Principled BSDF, I⁻ as base colour, metallic 0.5, roughness 1); one shadowless point
      light at the brightest patch, the world colour and the exposure of
      :mod:`snell_bench.render.lighting`; Blender's default view transform (AgX in 4.5); the glass
      a Refraction BSDF for camera rays and a Glass BSDF after (roughness 0.02); 1024 samples with
      adaptive sampling, clamps 6 (direct) and 1.5 (indirect), 8 glossy bounces, no caustics, no
      denoising; Blender's JPEG at quality 95. Then, as ``render_gt`` does with ``--out_mask``: the
      object's pixels outside the mask (read back from its JPEG at 128, holes filled) are blackened
      and the image saved again as a JPEG at quality 95 (by PIL); ``image`` is that file decoded.
    - ``lighting="unlit"``: the Mitsuba reference's scene instead: the background's front side emits
      I⁻ (no light, a black world, nearest-texel lookup), the view transform ``Standard``, exposure 0,
      the render read back linear (``linear.npy``) and encoded to sRGB: a like-for-like check of the
      refraction against :func:`~snell_bench.render.reference.render_reference`.
    - The mask: :func:`~snell_bench.render.authors_mask.authors_mask` with the render's IOR, as their
      evaluation reads it (:func:`~snell_bench.render.authors_mask.as_mask`).
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear
from snell_bench.render.authors_mask import authors_mask, fill_small_holes
from snell_bench.render.geometry import object_arrays
from snell_bench.render.lighting import (
    PointLight,
    brightest_patch,
    exposure_ev,
    fallback_light,
    patch_light,
    patch_probe_pixels,
    world_colour,
)
from snell_bench.render.reference import ReferenceRender
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import build_background, valid_depth_mask
from snell_bench.scene.objects import GlassObject

log = logging.getLogger(__name__)

__all__ = ["SETUP_TARGET", "CyclesUnavailable", "default_blender_python", "find_blender_python", "to_blender"]
__all__ += ["scene_lighting", "render_cycles"]

#: The make target that installs Blender's Python module.
SETUP_TARGET = "make setup-cycles"
#: The script Blender's Python runs.
SCRIPT = Path(__file__).resolve().parent / "blender" / "cycles_scene.py"
#: Camera frame -> Blender's frame (x, z, -y).
_TO_BLENDER = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


class CyclesUnavailable(RuntimeError):
    """No Python with Blender's ``bpy`` to run the Cycles reference with."""


def default_blender_python() -> Path:
    """``.venv-cycles/bin/python`` of the checkout this package lives in."""
    return Path(__file__).resolve().parents[2] / ".venv-cycles" / "bin" / "python"


def find_blender_python(path: str | os.PathLike | None = None) -> Path:
    """The Python that runs the Blender script: ``path``, or :func:`default_blender_python`.

    Raises:
        CyclesUnavailable: it does not exist; the message names ``reference.blender_python`` and
            :data:`SETUP_TARGET`.
    """
    p = Path(path).expanduser() if path else default_blender_python()
    if not (p.is_file() and os.access(p, os.X_OK)):
        key = f"reference.blender_python={path}" if path else f"reference.blender_python=null ({p})"
        raise CyclesUnavailable(
            f"no Python with Blender's bpy for reference.renderer=cycles: {key} is not an executable; "
            f"run `{SETUP_TARGET}` (bpy 4.5 in .venv-cycles) or set reference.blender_python to a Python with bpy"
        )
    return p


def to_blender(points: np.ndarray) -> np.ndarray:
    """``(..., 3)`` camera-frame points or directions in Blender's frame (``(x, z, -y)``)."""
    return np.asarray(points, np.float64) @ _TO_BLENDER.T


def _box(*arrays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pts = np.concatenate([np.asarray(a, np.float64).reshape(-1, 3) for a in arrays])
    return pts.min(axis=0), pts.max(axis=0)


def scene_lighting(image: np.ndarray, camera: Camera, background: tuple, obj: GlassObject) -> dict:
    """The authors' light, world colour and exposure for a scene (camera frame).

    The probe rays of :func:`~snell_bench.render.lighting.patch_probe_pixels` are cast (Open3D)
    into background and object; the first that meets the background first places the light
    (:func:`~snell_bench.render.lighting.patch_light`, the face normal turned to the camera), or
    :func:`~snell_bench.render.lighting.fallback_light` if none does.

    Returns:
        ``{"light": PointLight, "patch": BrightPatch, "fallback": bool, "world_colour", "world_strength",
        "exposure"}``.
    """
    import open3d as o3d

    bv, bf = background
    ov, of = np.asarray(obj.vertices, np.float32), np.asarray(obj.faces, np.uint32)
    rc = o3d.t.geometry.RaycastingScene()
    bg_id = rc.add_triangles(o3d.core.Tensor.from_numpy(bv), o3d.core.Tensor.from_numpy(bf))
    rc.add_triangles(o3d.core.Tensor.from_numpy(ov), o3d.core.Tensor.from_numpy(of))
    patch = brightest_patch(image)
    d = camera.pixel_rays(patch_probe_pixels(patch.x, patch.y, camera.width, camera.height))
    rays = np.concatenate([np.zeros_like(d), d], axis=1).astype(np.float32)
    r = rc.cast_rays(o3d.core.Tensor.from_numpy(rays))
    t, gid, n = r["t_hit"].numpy(), r["geometry_ids"].numpy(), r["primitive_normals"].numpy().astype(np.float64)
    hits = np.flatnonzero(np.isfinite(t) & (gid == bg_id))
    scene_box, bg_box, obj_box = _box(bv, ov), _box(bv), _box(ov)
    if len(hits):
        i = hits[0]
        normal = n[i] if n[i] @ d[i] < 0 else -n[i]
        light = patch_light(t[i] * d[i], normal, np.zeros(3), patch, scene_box, bg_box, obj_box)
    else:
        light = fallback_light(
            image, scene_box, bg_box, up=np.array([0.0, -1.0, 0.0]), forward=np.array([0.0, 0.0, 1.0])
        )
    colour, strength = world_colour(image)
    return {
        "light": light,
        "patch": patch,
        "fallback": not len(hits),
        "world_colour": colour,
        "world_strength": strength,
        "exposure": exposure_ev(image),
    }


def _background_arrays(depth, camera: Camera, edge_threshold: float, obj: GlassObject):
    """The depth mesh's referenced vertices (camera frame, float32), faces (uint32), smooth vertex
    normals facing the camera, and UVs at pixel centres (Blender's v upwards)."""
    import trimesh

    lo, hi = obj.mesh.bounds
    bg = build_background(depth, camera, edge_threshold, extra_points=np.stack([lo, hi]))
    faces = np.asarray(bg.faces, np.int64)
    if not len(faces):
        raise ValueError("the depth map gives no background triangle: nothing to render the object in front of")
    used = np.unique(faces)
    remap = np.full(len(bg.vertices), -1, np.int64)
    remap[used] = np.arange(len(used))
    v, f = np.asarray(bg.vertices, np.float32)[used], remap[faces]
    normals = trimesh.Trimesh(v, f, process=False).vertex_normals
    normals = np.where((np.einsum("ij,ij->i", normals, v) > 0)[:, None], -normals, normals)
    W, H = camera.width, camera.height
    uv = np.stack([(used % W + 0.5) / W, 1.0 - (used // W + 0.5) / H], -1)
    return v, f.astype(np.uint32), normals, uv


def _settings(camera: Camera, spp: int, seed: int, ior: float, lighting: str, lights: dict | None, clip) -> dict:
    K = camera.K
    if abs(K[0, 0] - K[1, 1]) > 1e-6 * K[0, 0] or abs(K[0, 1]) > 1e-9:
        raise ValueError(f"the Cycles reference takes square pixels without skew; K = {K.tolist()}")
    W, H = camera.width, camera.height
    unlit = lighting == "unlit"
    light = None if unlit or lights is None else lights["light"]
    return {
        "width": W,
        "height": H,
        "fx": float(K[0, 0]),
        "shift_x": (W / 2 - (K[0, 2] + 0.5)) / W,
        "shift_y": ((K[1, 2] + 0.5) - H / 2) / W,
        "clip_start": clip[0],
        "clip_end": clip[1],
        "samples": int(spp),
        "adaptive": True,
        "seed": int(seed) % (2**31),
        "clamp_direct": 6.0,
        "clamp_indirect": 1.5,
        "glossy_bounces": 8,
        "ior": float(ior),
        "roughness": 0.0 if unlit else 0.02,
        "lighting": lighting,
        "light": None if light is None else _light_json(light),
        "world_colour": [0.0] * 3 if unlit else [float(c) for c in lights["world_colour"]],
        "world_strength": 0.0 if unlit else float(lights["world_strength"]),
        "exposure": 0.0 if unlit else float(lights["exposure"]),
        "view_transform": "Standard" if unlit else None,
        "pixel_filter": "BOX" if unlit else "BLACKMAN_HARRIS",
        "filter_width": 1.0 if unlit else 1.5,
        "output": "linear" if unlit else "jpeg",
        "jpeg_quality": 95,
        "threads": 0,
    }


def _light_json(light: PointLight) -> dict:
    return {
        "position": [float(c) for c in to_blender(light.position)],
        "energy": float(light.energy),
        "colour": [float(c) for c in light.colour],
        "radius": float(light.radius),
    }


def _run(python: Path, folder: str, timeout_s: float) -> dict:
    cmd = [str(python), str(SCRIPT), "--", folder]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    if done.returncode != 0:
        tail = (done.stdout + done.stderr)[-2000:]
        raise RuntimeError(f"the Cycles render failed (exit status {done.returncode}): {tail}")
    return json.loads(Path(folder, "info.json").read_text())


def _their_post_process(folder: str, mask: np.ndarray, silhouette: np.ndarray) -> np.ndarray:
    """``render_gt``'s last step: object pixels outside the mask file (its JPEG read at 128, holes
    filled) black, saved again as a JPEG at quality 95; returns that file decoded (uint8)."""
    buf = Path(folder, "mask.jpg")
    Image.fromarray(mask.astype(np.uint8) * 255, mode="L").save(buf)
    white = fill_small_holes(np.asarray(Image.open(buf).convert("L")) >= 128, silhouette)
    rgb = np.array(Image.open(Path(folder, "render.jpg")).convert("RGB"))
    rgb[silhouette & ~white] = 0
    Image.fromarray(rgb).save(Path(folder, "reference.jpg"), quality=95)
    return np.asarray(Image.open(Path(folder, "reference.jpg")).convert("RGB"))


def _write_inputs(folder: str, img: np.ndarray, background: tuple, obj: tuple, settings: dict) -> None:
    """``scene.npz`` (Blender's frame), ``texture.png`` (8-bit sRGB) and ``settings.json``."""
    bv, bf, bn, buv = background
    ov, of, on = obj
    np.savez(
        Path(folder, "scene.npz"),
        bg_v=to_blender(bv).astype(np.float32),
        bg_f=bf.astype(np.int32),
        bg_n=to_blender(bn).astype(np.float32),
        bg_uv=buv.astype(np.float32),
        obj_v=to_blender(ov).astype(np.float32),
        obj_f=of.astype(np.int32),
        obj_n=to_blender(on).astype(np.float32),
    )
    Image.fromarray(np.round(img * 255.0).astype(np.uint8)).save(Path(folder, "texture.png"))
    Path(folder, "settings.json").write_text(json.dumps(settings))


def render_cycles(
    i_minus: np.ndarray,
    depth: np.ndarray,
    camera: Camera,
    obj: GlassObject,
    *,
    spp: int = 1024,
    seed: int = 0,
    edge_threshold: float = 0.05,
    ior: float | None = 1.5,
    lighting: str = "authors",
    blender_python: str | os.PathLike | None = None,
    timeout_s: float = 3600.0,
) -> ReferenceRender:
    """Render ``obj`` in the scene of I⁻ as the authors' ``render_gt`` does (see the module's
    conventions), with the authors' mask.

    Args:
        i_minus: ``(H, W, 3)`` sRGB image in [0, 1] of the object-free scene.
        depth: ``(H, W)`` z-depth of I⁻ (NaN, inf or <= 0 where unknown).
        camera: the camera of I⁻ (square pixels, no skew).
        obj: the placed glass object, camera frame.
        spp: Cycles' samples per pixel (the most: adaptive sampling stops earlier where converged).
        seed: Cycles' seed.
        edge_threshold: relative depth jump at which the depth mesh is cut.
        ior: the glass's IOR in render and mask (theirs: 1.5); ``None``: the object's.
        lighting: ``"authors"`` (their lit scene) or ``"unlit"`` (the Mitsuba reference's scene).
        blender_python: a Python with ``bpy``; ``None``: :func:`default_blender_python`.
        timeout_s: the longest the render may take.

    Returns:
        A :class:`~snell_bench.render.reference.ReferenceRender`: ``image`` (sRGB), ``linear`` (its
        decoding), ``mask`` (the authors' mask), ``unobserved`` (1 where
        that mask is not set), ``object_mask`` (the pixels whose first hit is the object).

    Raises:
        CyclesUnavailable: no Python with ``bpy`` (see :func:`find_blender_python`).
        ValueError: an unknown ``lighting``, an object not placed or absorbing, shapes that do not
            match, a camera with non-square pixels.
        RuntimeError: the render failed (the message ends with Blender's output).
    """
    if lighting not in ("authors", "unlit"):
        raise ValueError(f"lighting must be 'authors' or 'unlit', got {lighting!r}")
    if obj.absorbs or obj.media is not None:
        raise ValueError(
            f"the Cycles reference (the authors' scene) has clear glass of one material; object {obj.name!r} "
            f"(absorption {obj.absorption} per metre, {len(obj.media or ())} media) needs reference.renderer=mitsuba "
            "(its interior medium), or a clear object.absorption.color=[1,1,1]"
        )
    python = find_blender_python(blender_python)
    img = _checked_image(i_minus, depth, camera, obj)
    glass_ior = float(obj.ior if ior is None else ior)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    background, obj_arrays, settings = _scene_inputs(
        img, depth, camera, obj, edge_threshold, lighting, glass_ior, spp, seed
    )
    mask, silhouette = authors_mask(camera, background[:2], (obj.vertices, obj.faces), ior=glass_ior)
    timings["geometry"] = time.perf_counter() - t0
    with tempfile.TemporaryDirectory(prefix="snell_cycles_") as folder:
        _write_inputs(folder, img, background, obj_arrays, settings)
        t0 = time.perf_counter()
        info = _run(python, folder, timeout_s)
        timings["image"] = time.perf_counter() - t0
        if lighting == "unlit":
            image = linear_to_srgb(np.clip(np.load(Path(folder, "linear.npy")), 0.0, 1.0)).astype(np.float32)
        else:
            image = _their_post_process(folder, mask, silhouette).astype(np.float32) / 255.0
    log.info(
        "cycles reference (%s, Blender %s, %d spp, %s view, IOR %.3g): %d object pixels, %d in the mask; %s",
        lighting,
        info["blender"],
        spp,
        info["view_transform"],
        glass_ior,
        int(silhouette.sum()),
        int(mask.sum()),
        {k: round(v, 2) for k, v in timings.items()},
    )
    return _reference_render(image, mask, silhouette, info, camera, spp, seed, timings)


def _checked_image(i_minus: np.ndarray, depth: np.ndarray, camera: Camera, obj: GlassObject) -> np.ndarray:
    """I⁻ as float32 clipped to [0, 1], checked against ``depth`` and ``camera`` (same size) and
    ``obj`` (placed); ``ValueError`` otherwise."""
    img = np.clip(np.asarray(i_minus, np.float32), 0.0, 1.0)
    if img.shape != (*camera.shape, 3) or np.asarray(depth).shape != camera.shape:
        raise ValueError(
            f"i_minus {img.shape} and depth {np.asarray(depth).shape} must match the camera {camera.shape}"
        )
    if not obj.placed:
        raise ValueError(f"{obj.name}: the object is in its canonical frame; place it first")
    return img


def _scene_inputs(
    img: np.ndarray,
    depth: np.ndarray,
    camera: Camera,
    obj: GlassObject,
    edge_threshold: float,
    lighting: str,
    ior: float,
    spp: int,
    seed: int,
) -> tuple[tuple, tuple, dict]:
    """What the Blender script reads, in the camera frame: the background ``(v, f, n, uv)``
    (:func:`_background_arrays`), the object ``(v, f, n)``
    (:func:`~snell_bench.render.geometry.object_arrays`) and the settings (:func:`_settings`: the
    light of :func:`scene_lighting` unless ``lighting="unlit"``, the clip planes around the depth
    and the object)."""
    bv, bf, bn, buv = _background_arrays(depth, camera, edge_threshold, obj)
    ov, of, on = object_arrays(obj)
    lights = None if lighting == "unlit" else scene_lighting(img, camera, (bv, bf), obj)
    zmin = float(np.min(np.asarray(depth)[valid_depth_mask(depth)]))
    clip = (1e-3 * min(zmin, float(np.asarray(obj.vertices)[:, 2].min())), 10.0 * float(np.abs(bv).max()) + 10.0)
    return (bv, bf, bn, buv), (ov, of, on), _settings(camera, spp, seed, ior, lighting, lights, clip)


def _reference_render(
    image: np.ndarray, mask: np.ndarray, silhouette: np.ndarray, info: dict, camera: Camera, spp, seed, timings: dict
) -> ReferenceRender:
    """:func:`render_cycles`' result: the decoded ``image``, the authors' ``mask``, the object's
    ``silhouette``, what the Blender script reported (``info``) and the stages' ``timings``."""
    return ReferenceRender(
        image=image,
        linear=srgb_to_linear(image).astype(np.float32),
        unobserved=(~mask).astype(np.float32),
        object_mask=silhouette,
        mask=mask,
        unobserved_threshold=0.5,
        variant=f"cycles {info['blender']} cpu",
        spp=int(spp),
        seed=int(seed),
        timings={**timings, "render": float(info["render_s"])},
        sampler=f"cycles adaptive, {info['view_transform']}",
        unobserved_spp=0,
        window=(0, 0, camera.width, camera.height),
        reflection=False,
        file_format="jpeg",
    )
