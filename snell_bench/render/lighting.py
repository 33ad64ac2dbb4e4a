"""The lighting rules of the authors' reference render (``utils/render_gt.py``), as pure functions.

Their Blender scene lights the textured depth mesh with one shadowless point light placed in front
of the image's brightest patch, a world colour taken from the image's border, and a view exposure
chosen from the image's mean brightness. Each rule is a function of arrays here, so it can be
checked on hand-made images; :mod:`snell_bench.render.cycles` hands the results to Blender.

Convention:
    - Images: ``(H, W, 3)`` sRGB values in [0, 1] (the authors' code works on the 8-bit JPEG
      divided by 255, without decoding to linear RGB); rows top to bottom.
    - Luminance: the Rec. 709 weights ``0.2126 R + 0.7152 G + 0.0722 B`` on those sRGB values
      (:data:`REC709`), as their code computes it.
    - Pixels: integer ``(x, y)`` indices of :mod:`snell_bench.scene.camera` (x right, y down,
      integer values at pixel centres).
    - 3-D points and directions: any right-handed frame (the camera frame of
      :mod:`snell_bench.scene.camera` in this package); the rules only use distances, cross
      products and axis-aligned boxes, which a rotation by quarter turns (their Blender frame is the
      camera frame turned so that z points up) leaves as they are. A box is ``(lo, hi)``, two
      ``(3,)`` corners.
    - Light power: Blender's point-light power in watts; colours: linear RGB triples that Blender
      takes as they are.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "REC709",
    "BrightPatch",
    "PointLight",
    "luminance",
    "brightest_patch",
    "patch_probe_pixels",
    "patch_light",
    "fallback_light",
    "world_colour",
    "exposure_ev",
]

#: Luminance weights (R, G, B) of the authors' lighting rules (Rec. 709, on sRGB values).
REC709 = np.array([0.2126, 0.7152, 0.0722], np.float64)
#: Share of pixels above the threshold of a bright cluster: the 99.7th percentile of luminance.
_BRIGHT_PERCENTILE = 99.7
#: A cluster needs this many pixels at or above the threshold, or the brightest pixel is taken.
_MIN_CLUSTER = 8
#: Offsets (image fractions: right, up) tried in turn when the brightest pixel's ray misses the mesh.
_PROBE_OFFSETS = ((0.0, 0.0), (0.015, 0.0), (-0.015, 0.0), (0.0, 0.015), (0.0, -0.015))
_PROBE_OFFSETS += ((0.03, 0.0), (-0.03, 0.0), (0.0, 0.03), (0.0, -0.03))


@dataclass(frozen=True)
class BrightPatch:
    """The image's brightest patch.

    Attributes:
        x, y: the patch's centre pixel.
        tone: ``(3,)`` mean sRGB colour of the patch.
        luminance: mean Rec. 709 luminance of the patch (at least 1e-4).
    """

    x: int
    y: int
    tone: np.ndarray
    luminance: float


@dataclass(frozen=True)
class PointLight:
    """A shadowless point light.

    Attributes:
        position: ``(3,)`` where it is.
        energy: Blender's power in watts.
        colour: ``(3,)`` its colour.
        radius: its radius (Blender's ``shadow_soft_size``).
    """

    position: np.ndarray
    energy: float
    colour: np.ndarray
    radius: float


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of ``(..., 3)`` values (float64, shape ``(...)``)."""
    return np.asarray(rgb, np.float64) @ REC709


def _check_image(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image, np.float64)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise ValueError(f"image must be an (H, W, 3) RGB array, got shape {img.shape}")
    return img


def brightest_patch(image: np.ndarray) -> BrightPatch:
    """The brightest patch of ``image``, found as ``render_gt`` finds it.

    The pixels at or above the 99.7th percentile of luminance form the bright cluster; its centre is
    their luminance-weighted mean position, rounded to a pixel (with fewer than 8 such pixels, the
    brightest pixel, the first in row-major order on ties). The patch is the square of half-width
    ``max(2, int(0.03 min(H, W)))`` around it, clipped to the image.

    Args:
        image: ``(H, W, 3)`` sRGB in [0, 1].

    Returns:
        The :class:`BrightPatch`.
    """
    img = _check_image(image)
    h, w, _ = img.shape
    lum = luminance(img)
    bright = lum >= np.percentile(lum, _BRIGHT_PERCENTILE)
    if np.count_nonzero(bright) < _MIN_CLUSTER:
        y, x = np.unravel_index(int(np.argmax(lum)), lum.shape)
    else:
        ys, xs = np.nonzero(bright)
        weights = lum[ys, xs] + 1e-6
        x = int(np.clip(np.round(np.average(xs, weights=weights)), 0, w - 1))
        y = int(np.clip(np.round(np.average(ys, weights=weights)), 0, h - 1))
    r = max(2, int(min(h, w) * 0.03))
    patch = img[max(0, y - r) : min(h, y + r + 1), max(0, x - r) : min(w, x + r + 1)].reshape(-1, 3)
    return BrightPatch(int(x), int(y), patch.mean(axis=0), max(float(luminance(patch).mean()), 1e-4))


def patch_probe_pixels(x: int, y: int, width: int, height: int) -> np.ndarray:
    """The pixels whose rays ``render_gt`` casts, in turn, to find the surface under a patch.

    The patch's centre first, then offsets of 1.5 % and 3 % of the image's width (right, left) and
    height (up, down); image positions are clamped to ``[0.001, 0.999]`` of the image.

    Returns:
        ``(9, 2)`` float64 pixel coordinates ``(x, y)`` (not rounded).
    """
    u0, v0 = (x + 0.5) / width, 1.0 - (y + 0.5) / height  # image fractions, v upwards
    out = []
    for du, dv in _PROBE_OFFSETS:
        u = min(max(u0 + du, 0.001), 0.999)
        v = min(max(v0 + dv, 0.001), 0.999)
        out.append((u * width - 0.5, (1.0 - v) * height - 0.5))
    return np.asarray(out, np.float64)


def _inside(p: np.ndarray, box) -> bool:
    lo, hi = box
    return bool(np.all(p >= np.asarray(lo)) and np.all(p <= np.asarray(hi)))


def _max_dim(box, floor: float) -> float:
    lo, hi = (np.asarray(b, np.float64) for b in box)
    return max(float(np.max(hi - lo)), floor)


def _clamp(v: float, lo: float, hi: float) -> float:
    return max(lo, min(hi, v))


def _distance_scale(position: np.ndarray, object_box) -> float:
    """``render_gt``'s power scale for a light near the object: ``(d / d_ref)²`` in [0.06, 1], with
    ``d`` the distance to the object box's centre and ``d_ref = max(0.75 size, 0.08)``."""
    lo, hi = (np.asarray(b, np.float64) for b in object_box)
    d = float(np.linalg.norm(position - 0.5 * (lo + hi)))
    ref = max(0.75 * _max_dim(object_box, 1e-4), 0.08)
    return _clamp((d / ref) ** 2, 0.06, 1.0)


def patch_light(
    hit: np.ndarray,
    normal: np.ndarray,
    camera_position: np.ndarray,
    patch: BrightPatch,
    scene_box,
    background_box,
    object_box,
) -> PointLight:
    """The point light ``render_gt`` puts in front of the brightest patch.

    With ``s`` the size (longest side) of the box around background and object and
    ``o = max(0.05, 0.12 s)``: the light starts at ``hit + 0.9 o n + 0.5 o t`` (``t``: the unit
    vector ``n x (hit - camera)``, or the x axis where that vanishes) and moves ``0.6 o`` along
    ``n`` while it is inside the background's box, at most 8 times. Its power is
    ``clamp(250 + 3200 L, 120, 4200)`` W (``L``: the patch's luminance) times the distance scale
    (``(d / d_ref)²`` in [0.06, 1] from the object box's centre, ``d_ref = max(0.75 size_object, 0.08)``),
    clamped to [20, 4200]; its colour the patch's tone a quarter of the way to white; its radius
    ``max(0.02, 0.08 s)``.

    Args:
        hit: ``(3,)`` where the patch's ray meets the background.
        normal: ``(3,)`` the background's face normal there (the side the camera sees).
        camera_position: ``(3,)`` the camera's centre.
        patch: the :class:`BrightPatch`.
        scene_box, background_box, object_box: boxes ``(lo, hi)`` around everything, the background
            and the object.

    Returns:
        The :class:`PointLight`.
    """
    hit, n = np.asarray(hit, np.float64), np.asarray(normal, np.float64)
    n = n / np.linalg.norm(n)
    to_hit = hit - np.asarray(camera_position, np.float64)
    side = np.cross(n, to_hit / np.linalg.norm(to_hit))
    side = np.array([1.0, 0.0, 0.0]) if np.linalg.norm(side) < 1e-6 else side / np.linalg.norm(side)
    size = _max_dim(scene_box, 0.001)
    o = max(0.05, 0.12 * size)
    pos = hit + 0.9 * o * n + 0.5 * o * side
    for _ in range(8):
        if not _inside(pos, background_box):
            break
        pos = pos + 0.6 * o * n
    base = _clamp(250.0 + 3200.0 * patch.luminance, 120.0, 4200.0)
    energy = _clamp(base * _distance_scale(pos, object_box), 20.0, 4200.0)
    colour = 0.75 * np.asarray(patch.tone, np.float64) + 0.25
    return PointLight(pos, float(energy), colour, max(0.02, 0.08 * size))


def fallback_light(image: np.ndarray, scene_box, background_box, *, up: np.ndarray, forward: np.ndarray) -> PointLight:
    """The light ``render_gt`` uses when no ray through the bright patch meets the background.

    Between the camera and the scene: at the scene box's centre, moved back along ``forward`` to
    ``1.2`` half-depths before it (not nearer the camera than 0.1, or half the centre's depth) and
    ``0.8 s`` up (``s``: the scene box's longest side); while inside the background's box (at most
    10 times) moved ``0.5 s`` back and ``0.5 s`` up; still inside: ``2 s`` above the centre.
    1200 W times ``clamp(0.5 / L, 0.2, 2)`` (``L``: the image's mean luminance), the image's mean
    colour 45 % of the way to white, radius ``0.1 s``.

    Args:
        image: ``(H, W, 3)`` sRGB in [0, 1].
        scene_box, background_box: boxes ``(lo, hi)`` around everything and the background.
        up, forward: unit axis vectors (``±e_i``) of the frame: up and the camera's viewing
            direction (the camera frame: ``(0, -1, 0)`` and ``(0, 0, 1)``).

    Returns:
        The :class:`PointLight`.
    """
    img = _check_image(image)
    up, forward = np.asarray(up, np.float64), np.asarray(forward, np.float64)
    lo, hi = (np.asarray(b, np.float64) for b in scene_box)
    centre, size = 0.5 * (lo + hi), _max_dim(scene_box, 0.001)
    depth = float(centre @ forward)
    half = 0.5 * float(np.abs((hi - lo) @ forward))
    new_depth = depth - 1.2 * half
    if new_depth < 0.1:
        new_depth = max(0.1, 0.5 * depth)
    pos = centre + (new_depth - depth) * forward + 0.8 * size * up
    for _ in range(10):
        if not _inside(pos, background_box):
            break
        pos = pos + 0.5 * size * (up - forward)
    if _inside(pos, background_box):
        pos = centre + 2.0 * size * up
    mean = img.reshape(-1, 3).mean(axis=0)
    lum = max(float(luminance(mean)), 1e-4)
    energy = _clamp(1200.0 * _clamp(0.5 / lum, 0.2, 2.0), 0.1, 1e6)
    return PointLight(pos, float(energy), 0.55 * mean + 0.45, 0.1 * size)


def world_colour(image: np.ndarray) -> tuple[np.ndarray, float]:
    """The world (background) colour and strength ``render_gt`` takes from the image's border.

    The border is the frame ``max(1, int(0.08 min(H, W)))`` pixels wide; its mean colour a quarter of
    the way to white is the colour, and ``clamp(0.6 L, 0.02, 0.6)`` the strength (``L``: the Rec. 709
    luminance of the border's mean colour, at least 1e-4).

    Args:
        image: ``(H, W, 3)`` sRGB in [0, 1].

    Returns:
        ``(colour (3,) float64, strength)``.
    """
    img = _check_image(image)
    h, w, _ = img.shape
    b = max(1, int(min(w, h) * 0.08))
    inner = np.zeros((h, w), bool)
    inner[b : h - b, b : w - b] = True
    mean = img[~inner].mean(axis=0)
    lum = max(float(luminance(mean)), 1e-4)
    return 0.75 * mean + 0.25, _clamp(0.6 * lum, 0.02, 0.6)


def exposure_ev(image: np.ndarray, target: float = 0.5) -> float:
    """The view exposure ``render_gt`` sets: ``log2(target / L)`` clamped to [-2, +1] EV, with ``L``
    the Rec. 709 luminance of the image's mean colour (at least 1e-4).

    Args:
        image: ``(H, W, 3)`` sRGB in [0, 1].
        target: the luminance aimed at (theirs: 0.5).
    """
    img = _check_image(image)
    lum = max(float(luminance(img.reshape(-1, 3).mean(axis=0))), 1e-4)
    return _clamp(math.log2(target / lum), -2.0, 1.0)
