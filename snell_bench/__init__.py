"""snell_bench: physically correct transparent objects in generated images (Snellcaster), reproduced
and measured."""

import os as _os

# OpenMP's default busy-waiting threads fight any other busy process for the cores: on 2 cores a
# small torch op becomes ~3x slower beside one busy process (benchmarks/bench_warps.py prints it),
# and far worse beside a multi-threaded one, the normal case in parallel sweeps. Passive waiting
# costs ~20 % on tiny ops of an idle machine. It only takes effect if snell_bench is imported
# before torch; set OMP_WAIT_POLICY yourself to choose.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
