"""Reference renders: an independent physically based renderer (Mitsuba 3) and the true render of
procedural scenes.

Importing this package does not import Mitsuba; :func:`render_reference` does (install the
``render`` extra: ``pip install snell_bench[render]``).
"""

from snell_bench.render.mitsuba_ref import ReferenceRender, mitsuba_variant, render_reference, render_true

__all__ = ["ReferenceRender", "mitsuba_variant", "render_reference", "render_true"]
