"""Reference renders: an independent physically based renderer (Mitsuba 3) and the true render of
procedural scenes.

- :mod:`~snell_bench.render.variants`: importing Mitsuba and choosing its variant (probed in a
  subprocess running :mod:`~snell_bench.render.probe`).
- :mod:`~snell_bench.render.plugins`: Mitsuba plugins written in Python (the refraction-path BSDF,
  a pinhole sensor of any intrinsics).
- :mod:`~snell_bench.render.pieces`: scene pieces (meshes, sensors, emitters, BSDFs, samplers).
- :mod:`~snell_bench.render.integrator`: :func:`~snell_bench.render.integrator.render_linear`, the
  render loop (windows, seeds, render threads).
- :mod:`~snell_bench.render.geometry`: the background built from a depth map, the object's arrays.
- :mod:`~snell_bench.render.reference`: :func:`render_reference`, the Mitsuba reference render, in
  stages (:mod:`~snell_bench.render.reference_passes`: its scene and passes), with one
  :class:`ReferenceSettings` (:mod:`~snell_bench.render.reference_settings`).
- :mod:`~snell_bench.render.true_render`: :func:`render_true`, the true render of a procedural
  scene (no Mitsuba).

Importing this package does not import Mitsuba; :func:`render_reference` does (install the
``render`` extra: ``pip install snell_bench[render]``).
"""

from snell_bench.render.reference import ReferenceRender, ReferenceSettings, render_reference
from snell_bench.render.true_render import render_true
from snell_bench.render.variants import mitsuba_variant

__all__ = ["ReferenceRender", "ReferenceSettings", "mitsuba_variant", "render_reference", "render_true"]
