"""Rendering a scene of shapes with Mitsuba's path tracer: :func:`render_linear`, the render loop of
the reference renderer (:mod:`snell_bench.render.reference`), over a window of the image and split
between render threads around the plugins written in Python.

Importing this module does not import Mitsuba: :func:`render_linear` takes the ``mitsuba`` module,
set to a variant by :func:`~snell_bench.render.variants.set_variant`.

Convention:
    - Scene: the shapes given, seen by the sensor of :func:`~snell_bench.render.pieces.sensor`
      (frames, pixels and samplers: see :mod:`snell_bench.render.pieces`), rendered by Mitsuba's
      ``path`` integrator without Russian roulette; images are linear RGB, float32, not clipped.
    - Randomness: the sampler is seeded with ``seed``; the same inputs, sampler, ``spp``, ``seed``,
      render window and variant give the same images (``llvm_*`` variants with several Dr.Jit
      threads: up to float rounding, where a pixel's samples are summed by two threads in either
      order; on one thread, ``drjit.set_thread_count(1)``, bit for bit).
    - Windows: a render may cover only a window ``(x0, y0, x1, y1)`` of the image (end exclusive), a
      crop window of the same film (``crop_offset`` / ``crop_size``): its pixels see exactly the rays
      they see in the whole image, but draw other random numbers (the sampler's stream follows the
      window's pixel order), so a window matches the whole image exactly only where a pixel's value
      does not depend on which samples it draws.
    - Threads: Python plugins hold the interpreter lock; on CPU variants the pixels whose rays can
      reach one are rendered on one thread (see :func:`render_linear`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from snell_bench.render.pieces import sensor, square_pixels
from snell_bench.scene.camera import Camera

__all__ = ["render_linear"]


def render_linear(
    mi,
    shapes: dict,
    camera: Camera,
    spp: int,
    seed,
    max_depth: int,
    clip: tuple,
    python_rect=None,
    *,
    window=None,
    sampler="independent",
    media: bool = False,
):
    """Render ``shapes`` with Mitsuba's path tracer, once per seed, from one loaded scene.

    Python plugins hold the interpreter lock, so with several render threads they mostly wait for
    each other: on CPU variants the part of the window inside ``python_rect`` is rendered on one
    thread and the rest of the window, tile by tile, on all threads; with the Python sensor of a
    non-square-pixel camera (:func:`~snell_bench.render.pieces.pinhole_sensor`) every ray starts in
    Python, and the whole window is rendered on one thread.

    Args:
        mi: the ``mitsuba`` module, set to a variant.
        shapes: the scene's shapes by name.
        camera: the camera.
        spp: samples per pixel (a count ``sampler`` accepts, see
            :func:`~snell_bench.render.pieces.sample_count`), or one per seed.
        seed: seed of the sampler, or a sequence of seeds: one render each, of the same scene.
        max_depth: longest light path (surface interactions, the emitter hit included); no Russian
            roulette.
        clip: ``(near_clip, far_clip)``.
        python_rect: ``(x0, y0, x1, y1)``, end exclusive: the only pixels whose rays can reach a
            BSDF written in Python (the object's footprint); ``None``: no such BSDF.
        window: ``(x0, y0, x1, y1)``, end exclusive: render only these pixels (a crop window of
            the film, see the module's conventions); ``None``: the whole image.
        sampler: the sampler, as in :func:`~snell_bench.render.pieces.check_sampler`.
        media: a shape holds a medium (an absorbing glass): Mitsuba's ``volpathmis`` integrator, which
            attenuates paths inside media (``path`` ignores them) with spectral MIS for an extinction
            that differs between channels (at the same samples its self-noise is 2-3 dB better than
            ``volpath``'s on a tinted sphere).

    Returns:
        The linear float32 image of the window, ``(y1 - y0, x1 - x0, 3)`` (``(H, W, 3)`` without a
        window); a list of them, one per seed, when ``seed`` is a sequence.
    """
    many = isinstance(seed, (list, tuple))
    seeds, counts, (wx0, wy0, wx1, wy1) = _runs(camera, spp, seed, window)
    H, W = camera.shape
    full = (wx0, wy0, wx1, wy1) == (0, 0, W, H)
    scene_dict = {
        "type": "scene",
        # no Russian roulette: paths end at emitters (black BSDFs) or after max_depth interactions
        "integrator": {
            "type": "volpathmis" if media else "path",
            "max_depth": int(max_depth),
            "rr_depth": int(max_depth) + 1,
        },
        "sensor": sensor(mi, camera, counts[0], *clip, rect=None if full else (wx0, wy0, wx1, wy1), sampler=sampler),
    }
    scene_dict.update(shapes)
    loaded = _Loaded(mi, mi.load_dict(scene_dict), camera, clip, sampler, (wx0, wy0, wx1, wy1))
    python_sensor = not square_pixels(camera)
    images = [_render_window(loaded, python_rect, python_sensor, s, n) for s, n in zip(seeds, counts)]
    return images if many else images[0]


def _runs(camera: Camera, spp, seed, window) -> tuple[list[int], list[int], tuple[int, int, int, int]]:
    """The seeds, the sample count of each and the render window ``(x0, y0, x1, y1)`` of
    :func:`render_linear`'s ``spp``, ``seed`` and ``window``, checked (``ValueError`` for as many
    counts as seeds, or a window empty or not inside the image)."""
    H, W = camera.shape
    seeds = [int(s) for s in seed] if isinstance(seed, (list, tuple)) else [int(seed)]
    counts = [int(n) for n in spp] if isinstance(spp, (list, tuple)) else [int(spp)] * len(seeds)
    if len(counts) != len(seeds):
        raise ValueError(f"{len(counts)} sample counts for {len(seeds)} seeds")
    wx0, wy0, wx1, wy1 = (0, 0, W, H) if window is None else tuple(map(int, window))
    if not (0 <= wx0 < wx1 <= W and 0 <= wy0 < wy1 <= H):
        raise ValueError(f"window {window} is empty or not inside the {W}x{H} image")
    return seeds, counts, (wx0, wy0, wx1, wy1)


@dataclass(frozen=True)
class _Loaded:
    """A loaded scene and what its renders share: the ``mitsuba`` module, the scene (its sensor
    covering ``window``), the camera, the ``(near, far)`` clip, the sampler, the render window
    ``(x0, y0, x1, y1)``."""

    mi: Any
    scene: Any
    camera: Camera
    clip: tuple
    sampler: Any
    window: tuple

    def render(self, rect, s, n) -> np.ndarray:
        """The linear float32 image ``(y1 - y0, x1 - x0, 3)`` of ``rect`` (end exclusive), ``n``
        samples per pixel with seed ``s``: by the scene's sensor for the whole window, else by a
        sensor cropped to ``rect``."""
        mi = self.mi
        if rect == self.window:
            sen = self.scene.sensors()[0]
        else:
            sen = mi.load_dict(sensor(mi, self.camera, n, *self.clip, rect=rect, sampler=self.sampler))
        return np.array(mi.render(self.scene, sensor=sen, spp=n, seed=s), dtype=np.float32)[..., :3]

    def one_thread(self, rect, s, n) -> np.ndarray:
        """:meth:`render` with Dr.Jit on one thread (its thread count restored after)."""
        import drjit as dr

        threads = dr.thread_count()
        dr.set_thread_count(1)
        try:
            return self.render(rect, s, n)
        finally:
            dr.set_thread_count(threads)


def _render_window(loaded: _Loaded, python_rect, python_sensor: bool, s, n) -> np.ndarray:
    """The window of ``loaded``, ``n`` samples per pixel with seed ``s``, split between threads as
    :func:`render_linear` says: on CPU (``scalar_*``) variants the pixels of ``python_rect``
    (clipped to the window) on one thread and the rest tile by tile, or all on one thread with a
    Python sensor (``python_sensor``)."""
    wx0, wy0, wx1, wy1 = loaded.window
    if not loaded.mi.variant().startswith("scalar") or (python_rect is None and not python_sensor):
        return loaded.render((wx0, wy0, wx1, wy1), s, n)
    if python_sensor:
        return loaded.one_thread((wx0, wy0, wx1, wy1), s, n)
    # the Python BSDF's pixels (clipped to the window) on one thread, the rest tile by tile
    x0, y0, x1, y1 = python_rect
    x0, x1 = min(max(x0, wx0), wx1), min(max(x1, wx0), wx1)
    y0, y1 = min(max(y0, wy0), wy1), min(max(y1, wy0), wy1)
    out = np.zeros((wy1 - wy0, wx1 - wx0, 3), np.float32)
    tiles = ((wx0, wy0, wx1, y0), (wx0, y1, wx1, wy1), (wx0, y0, x0, y1), (x1, y0, wx1, y1))
    for rx0, ry0, rx1, ry1 in tiles:
        if rx1 > rx0 and ry1 > ry0:
            out[ry0 - wy0 : ry1 - wy0, rx0 - wx0 : rx1 - wx0] = loaded.render((rx0, ry0, rx1, ry1), s, n)
    if x1 > x0 and y1 > y0:
        out[y0 - wy0 : y1 - wy0, x0 - wx0 : x1 - wx0] = loaded.one_thread((x0, y0, x1, y1), s, n)
    return out
