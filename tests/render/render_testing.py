"""Shared set-up of the render tests: the Mitsuba variant they use, a procedural room with a glass
sphere (seen with square or non-square pixels), and image comparisons. Imports no Mitsuba."""

from __future__ import annotations

import os
from contextlib import contextmanager
from types import SimpleNamespace

import numpy as np
import scipy.ndimage as nd

from snell_bench.imaging.remap import remap
from snell_bench.optics import compute_warps
from snell_bench.render.variants import VARIANT_ENV
from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import place_object
from snell_bench.scene.procedural import ProceduralScene
from snell_bench.scene.procedural.color import srgb_encode
from snell_bench.utils.tensors import bchw_to_hwc, hwc_to_bchw

H, W = 128, 224


@contextmanager
def forced_cpu_variant():
    """Render with ``scalar_rgb`` unless a variant is forced (the probe has its own test)."""
    old = os.environ.get(VARIANT_ENV)
    if not old:
        os.environ[VARIANT_ENV] = "scalar_rgb"
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(VARIANT_ENV, None)
        else:
            os.environ[VARIANT_ENV] = old


def make_room() -> SimpleNamespace:
    """A glass sphere on the table of a procedural room; I⁻ supersampled 2 x 2."""
    scene = ProceduralScene("room", 0)
    r = scene.render(W, H, supersample=2)
    obj = place_object(GlassObject.sphere(subdivisions=4), r.depth, r.camera)
    ws = compute_warps(r.depth, r.camera, obj, pano_height=16)
    return SimpleNamespace(scene=scene, image=r.image, depth=r.depth, camera=r.camera, obj=obj, ws=ws)


def non_square(camera: Camera) -> Camera:
    """``camera`` with non-square pixels and an off-centre principal point: ``fy = 1.12 fx``,
    ``(cx, cy) = (0.46 W, 0.55 H)``."""
    K = camera.K.copy()
    K[1, 1] = 1.12 * K[0, 0]
    K[0, 2], K[1, 2] = 0.46 * camera.width, 0.55 * camera.height
    return Camera(K=K, width=camera.width, height=camera.height)


def make_non_square_room(room: SimpleNamespace) -> SimpleNamespace:
    """The room of :func:`make_room` (the same scene and object) seen with :func:`non_square` of its
    camera: I⁻ supersampled 2 x 2 as ``ProceduralScene.render`` does, z-depth through pixel centres."""
    scene, cam = room.scene, non_square(room.camera)
    d = cam.pixel_rays()
    t = scene.radiance(np.zeros(3), d.reshape(-1, 3))[1]
    depth = (t.astype(np.float64) * d[..., 2].reshape(-1)).reshape(cam.shape).astype(np.float32)
    acc = np.zeros((H * W, 3), np.float64)
    for oy in (-0.25, 0.25):
        for ox in (-0.25, 0.25):
            acc += scene.radiance(np.zeros(3), cam.pixel_rays(cam.pixel_grid() + [ox, oy]).reshape(-1, 3))[0]
    image = srgb_encode((acc / 4.0).reshape(H, W, 3))
    ws = compute_warps(depth, cam, room.obj, pano_height=16)
    return SimpleNamespace(scene=scene, image=image, depth=depth, camera=cam, obj=room.obj, ws=ws)


def warp(image: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """(H, W, 3) image through a backward warp (bilinear, 0 where invalid)."""
    out, _ = remap(hwc_to_bchw(image), coords)
    return bchw_to_hwc(out)


def psnr(a: np.ndarray, b: np.ndarray, m: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / np.mean((a[m] - b[m]) ** 2)))


def far_from_object(object_mask: np.ndarray, px: int = 2) -> np.ndarray:
    """Pixels whose footprints cannot touch the object (its mask grown by ``px``)."""
    return ~nd.binary_dilation(object_mask, iterations=px)


def metric_pixels(ref, ws) -> np.ndarray:
    """The metric mask where our warp is valid, eroded by one pixel: pixels on the mask's rim mix
    the light of neighbouring regions (silhouette, borders of unobserved regions) in their footprint,
    which a warp through the pixel centre cannot show."""
    return nd.binary_erosion(ref.mask & ws.refraction_valid & ws.object_mask, iterations=1)
