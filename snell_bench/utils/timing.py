"""Wall-clock timing of named stages.

Examples:
    >>> t = Timer()
    >>> with t("warps"):
    ...     pass
    >>> list(t.seconds)
    ['warps']
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["Timer"]


class Timer:
    """Records the wall time of each named stage in :attr:`seconds` (a stage timed twice adds up)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - t0

    def rounded(self, digits: int = 3) -> dict[str, float]:
        """:attr:`seconds` rounded to ``digits`` decimals."""
        return {k: round(v, digits) for k, v in self.seconds.items()}
