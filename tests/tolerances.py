"""Tolerances for one computation evaluated along two paths, derived from floating-point rounding.

Two evaluations of the same expression agree bit for bit only when they perform the same operations
in the same order. A model built in memory and the same model read back from disk, a batch and its
items one at a time, the project's sampling loop and diffusers' pipeline, or one run on one thread
and another on two, may sum their matrix products, convolutions and reductions in other orders: MKL
and oneDNN pick their kernels by instruction set (AVX2, AVX-512), thread count and operand
alignment. Such results agree up to rounding only, and the tolerance has to follow from the rounding
of the computation, not from the difference seen on one machine.

The bound: a sum of ``n`` terms, each addition rounded with unit roundoff ``u``, is within
``(n - 1) u sum_i |x_i|`` of the exact sum whatever the order (to first order in ``u``; Higham,
*Accuracy and Stability of Numerical Algorithms*, 2nd ed., section 4.2), so two orders are within
``2 (n - 1) u sum_i |x_i|`` of each other. With ``|a|`` the largest magnitude of the compared
results, :func:`reordering_tolerance` returns ``2 n u |a|``:

- Terms that do not cancel (filters with non-negative weights, means, attention's convex
  combinations) have ``sum_i |x_i| <= |a|``: the bound is the worst case.
- Terms of random sign and typical size ``s`` (a layer with random weights) have
  ``sum_i |x_i| ~ 0.8 n s``, but their rounding errors add like a random walk: two orders differ by
  at most ``lambda sqrt(2 n) u sum_i |x_i| ~ 1.1 lambda n^1.5 u s``, except with probability
  ``2 exp(-lambda^2 / 2)`` per result (Higham and Mary, SIAM J. Sci. Comput. 41(5), 2019). The
  results themselves are of size ``sqrt(n) s``, the largest of thousands about 3.5 times that, so
  ``2 n u |a|`` is this bound with ``lambda`` about 6 (a failure probability of 1e-8 per result).
- A chain of stages, each passing on its input's error with a gain of at most 1 (normalised layers,
  filters whose weights sum to 1, convex combinations), is bounded by the sum of the stages' bounds:
  ``n`` is then the sum of their lengths. For a shallow network ``n`` is its longest reduction: the
  shorter ones add less than the margin of the random-walk estimate.

The tolerance thus scales with the actual magnitude of the results and with a length read off the
computation (written next to each use), never with a difference measured on one machine.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["EPS32", "EPS64", "max_abs", "reordering_tolerance"]

#: Unit roundoff of float32 (half the spacing of float32 numbers in [1, 2)).
EPS32 = 2.0**-24
#: Unit roundoff of float64.
EPS64 = 2.0**-53


def max_abs(*values) -> float:
    """The largest finite magnitude over tensors, arrays or numbers (0 for none)."""
    out = 0.0
    for v in values:
        a = v.detach().double().cpu().numpy() if isinstance(v, torch.Tensor) else np.asarray(v, np.float64)
        a = np.abs(a[np.isfinite(a)])
        if a.size:
            out = max(out, float(a.max()))
    return out


def reordering_tolerance(length: int, *values, eps: float = EPS32) -> float:
    """How far two summation orders of one computation may move its results: ``2 n eps |a|``.

    Args:
        length: ``n``, the longest reduction on the computation's path (the length of a dot product,
            the size of a convolution window times its input channels, the number of tokens an
            attention sums over), or the sum of the lengths of a chain of stages.
        values: the compared results (tensors, arrays or numbers); ``|a|`` is their largest
            magnitude.
        eps: the unit roundoff of the format the reductions run in (:data:`EPS32`, :data:`EPS64`).

    Returns:
        The absolute tolerance (see the module docstring for the derivation).

    Examples:
        >>> reordering_tolerance(144, torch.tensor([0.5, -1.0])) == 2 * 144 * 2.0**-24
        True
    """
    return 2.0 * int(length) * float(eps) * max_abs(*values)
