"""snell_bench: physically correct transparent objects in generated images (Snellcaster), reproduced
and measured."""

import os as _os

# OpenMP's default busy-wait makes every parallel torch op pay milliseconds of thread hand-over on
# small, shared CPU machines (2 vCPUs: ~8 ms per op instead of ~0.1 ms, measured by
# benchmarks/bench_warps.py). Passive waiting costs little elsewhere. It only takes effect if
# snell_bench is imported before torch; set OMP_WAIT_POLICY yourself to override.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
