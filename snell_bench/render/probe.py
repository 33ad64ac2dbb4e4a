"""The body of the Mitsuba variant probe: a tiny reference render, run in a subprocess by
:func:`~snell_bench.render.variants.mitsuba_variant` for each candidate variant in turn
(``cuda_ad_rgb``, ``llvm_ad_rgb``), forced by the environment (``$SNELL_BENCH_MITSUBA_VARIANT``).
It runs the reference render's own code (a BSDF written in Python, the texture, the meshes, the
numpy round trips), so a variant that passes it renders references.

Convention:
    - Scene: a ``12 x 8`` image (60° horizontal field of view) of a wall at z-depth 3 textured with
      a ramp of values in ``[0.1, 0.9]``, and the unit-diameter glass sphere of
      :meth:`~snell_bench.scene.objects.GlassObject.sphere` (one subdivision) moved by
      ``(0, -0.5, 2)`` in the camera frame; 2 samples per pixel of the ``independent`` sampler in
      both passes of :func:`~snell_bench.render.reference.render_reference`.
    - Success: the render is finite and not all black, and :data:`~snell_bench.render.variants.PROBE_OK`
      is printed on stdout; anything else raises, or aborts the process.
"""

from __future__ import annotations

import numpy as np

from snell_bench.render.reference import ReferenceSettings, render_reference
from snell_bench.render.variants import PROBE_OK
from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject

__all__ = ["probe_render"]


def probe_render() -> None:
    """A tiny reference render of a sphere before a textured wall, with the variant that
    :func:`~snell_bench.render.variants.mitsuba_variant` gives (see the module's conventions).

    Raises:
        RuntimeError: the render is empty or not finite.
    """
    H, W = 8, 12
    cam = Camera.from_fov(W, H, 60.0)
    depth = np.full((H, W), 3.0)
    img = np.linspace(0.1, 0.9, H * W * 3).reshape(H, W, 3)
    T = np.eye(4)
    T[:3, 3] = (0.0, -0.5, 2.0)
    obj = GlassObject.sphere(subdivisions=1).transformed(T)
    ref = render_reference(img, depth, cam, obj, ReferenceSettings(spp=2, sampler="independent", unobserved_spp=2))
    if not (np.isfinite(ref.image).all() and ref.image.max() > 0):
        raise RuntimeError("the probe render is empty or not finite")
    print(PROBE_OK, flush=True)
