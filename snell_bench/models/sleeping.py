"""The sleeping generator: the analytic generator whose every model call also waits, a CPU stand-in
for a generator whose calls run on a GPU.

On a GPU node the generator's calls keep the GPU busy and leave the CPU free; on a CPU the analytic
generator's calls take the CPU itself. Sleeping a fixed time in each call (``time.sleep`` gives
the core back) makes sampling take GPU-like wall time that other processes can use, so that
overlapping CPU work with sampling (:mod:`snell_bench.experiment.prefetch`) can be measured on a
CPU (``benchmarks/bench_overlap.py``).

Convention:
    - Outputs: exactly those of the wrapped generator (the same tensors, the same random draws);
      only the wall time differs.
    - Model calls: :meth:`SleepingGenerator.velocity`, :meth:`SleepingGenerator.encode` and
      :meth:`SleepingGenerator.decode` each sleep ``sleep_s`` seconds after the wrapped call; every
      other attribute is the wrapped generator's.
"""

from __future__ import annotations

import math
import time
from typing import Any

import torch

from snell_bench.models.analytic import AnalyticGenerator
from snell_bench.models.base import Condition

__all__ = ["SleepingGenerator"]


class SleepingGenerator:
    """``generator`` with ``sleep_s`` seconds of sleep added to each model call (see the module docs).

    Args:
        generator: the generator wrapped (any :class:`~snell_bench.models.base.Generator`).
        sleep_s: seconds each call of ``velocity``, ``encode`` and ``decode`` sleeps, >= 0.

    Raises:
        ValueError: a negative or non-finite ``sleep_s``.
    """

    name = "sleeping"

    def __init__(self, generator: Any, *, sleep_s: float) -> None:
        if not (math.isfinite(sleep_s) and sleep_s >= 0):
            raise ValueError(f"model.generator.sleep_s must be finite and >= 0 (seconds per model call), got {sleep_s}")
        self.generator = generator
        self.sleep_s = float(sleep_s)
        self.calls = 0  #: model calls made (each slept ``sleep_s``)

    @classmethod
    def from_scene(cls, i_minus, object_mask, panorama=None, *, sleep_s: float, **kwargs: Any) -> SleepingGenerator:
        """:meth:`AnalyticGenerator.from_scene <snell_bench.models.analytic.AnalyticGenerator.from_scene>`
        with ``kwargs``, wrapped."""
        return cls(AnalyticGenerator.from_scene(i_minus, object_mask, panorama, **kwargs), sleep_s=sleep_s)

    def _slept(self, out: torch.Tensor) -> torch.Tensor:
        self.calls += 1
        time.sleep(self.sleep_s)
        return out

    def velocity(self, z: torch.Tensor, sigma, cond: Condition) -> torch.Tensor:
        """The wrapped generator's velocity, then ``sleep_s``."""
        return self._slept(self.generator.velocity(z, sigma, cond))

    def encode(self, images: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """The wrapped generator's encoding, then ``sleep_s``."""
        return self._slept(self.generator.encode(images, generator))

    def decode(self, latents: torch.Tensor) -> torch.Tensor:
        """The wrapped generator's decoding, then ``sleep_s``."""
        return self._slept(self.generator.decode(latents))

    def __getattr__(self, name: str) -> Any:  # geometry, device, dtype, condition, sigmas, ...
        if name == "generator":  # not set yet (unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.generator, name)
