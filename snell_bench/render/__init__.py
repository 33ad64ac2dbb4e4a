"""Reference renders: an independent physically based renderer (Mitsuba 3) and the true render of
procedural scenes.

- :mod:`~snell_bench.render.backend`: Mitsuba (import, variant, plugins, scene pieces).
- :mod:`~snell_bench.render.geometry`: the background built from a depth map, the object's arrays.
- :mod:`~snell_bench.render.reference`: :func:`render_reference`, the Mitsuba reference render.
- :mod:`~snell_bench.render.true_render`: :func:`render_true`, the true render of a procedural
  scene (no Mitsuba).

Importing this package does not import Mitsuba; :func:`render_reference` does (install the
``render`` extra: ``pip install snell_bench[render]``).
"""

from snell_bench.render.backend import mitsuba_variant
from snell_bench.render.reference import ReferenceRender, render_reference
from snell_bench.render.true_render import render_true

__all__ = ["ReferenceRender", "mitsuba_variant", "render_reference", "render_true"]
