"""Methods: one module per method kind, found by one registry (:mod:`.registry`).

- :mod:`.base`: :class:`Method`, what every kind implements: which models it needs, how it makes its
  image, what it costs for ``job=plan``, whether a finished cell is still current;
- :mod:`.snellcaster`, :mod:`.t2i`, :mod:`.inpaint`, :mod:`.pipeline` (another diffusers model),
  :mod:`.images` (images made anywhere): the built-in kinds;
- :mod:`.cost`: the bases of ``job=plan``'s estimates and the scaling the kinds share;
- :mod:`.registry`: ``method.kind`` / ``method._target_`` to the class; users' methods plug in by a
  ``_target_`` in a method YAML or by the ``snell_bench.methods`` entry point.

A user's method::

    from snell_bench.methods import Method

    class PhysicsOnly(Method):
        def run(self, cfg, inputs, warps, t):
            ...  # return CellResult(image=...)
"""

from snell_bench.methods.base import Method
from snell_bench.methods.registry import (
    BUILTIN,
    installed_methods,
    method_class,
    method_kinds,
    method_of,
)

__all__ = [
    "BUILTIN",
    "Method",
    "installed_methods",
    "method_class",
    "method_kinds",
    "method_of",
]
