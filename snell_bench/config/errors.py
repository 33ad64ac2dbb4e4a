"""The error of an unusable config, and the value checks that write its lines.

Every line names the key, the bad value and the fix (``scene.variation=-1: must be an integer >= 0
...; e.g. scene.variation=0``); :class:`ConfigError` carries all lines of a config at once.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

__all__ = ["ConfigError", "Problems", "is_int", "is_number"]


class ConfigError(ValueError):
    """One or more settings are unusable; the message lists each with its fix."""

    def __init__(self, problems: Iterable[str]) -> None:
        self.problems = list(problems)
        if len(self.problems) == 1:
            super().__init__(self.problems[0])
        else:
            super().__init__(
                f"{len(self.problems)} settings are unusable:\n" + "\n".join(f"  - {p}" for p in self.problems)
            )


def is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


class Problems(list):
    """The lines of a :class:`ConfigError`, with the checks of single values.

    Args:
        prefix: the node's key, prepended to the field names the checks are given (``"scene"``).
    """

    def __init__(self, prefix: str = "") -> None:
        super().__init__()
        self.prefix = f"{prefix}." if prefix else ""

    def key(self, name: str) -> str:
        return f"{self.prefix}{name}"

    def int_at_least(self, name: str, v: Any, lo: int, why: str = "", example: int | None = None) -> None:
        """``v`` is an integer >= ``lo``."""
        if not is_int(v) or v < lo:
            key = self.key(name)
            self.append(
                f"{key}={v!r}: must be an integer >= {lo}{why}; e.g. {key}={lo if example is None else example}"
            )

    def finite(self, name: str, v: Any, *, positive=False, lo=None, hi=None, optional=False, fix="") -> None:
        """``v`` is a finite number (``> 0`` with ``positive``, in ``[lo, hi]``; ``None`` allowed
        with ``optional``)."""
        if v is None and optional:
            return
        ok = is_number(v) and math.isfinite(float(v))
        ok = ok and not (positive and float(v) <= 0)
        ok = ok and not (lo is not None and float(v) < lo) and not (hi is not None and float(v) > hi)
        if not ok:
            rng = "a finite number" + (" > 0" if positive else "")
            if positive and hi is not None:
                rng = f"a number in (0, {hi}]"
            elif lo is not None and hi is not None:
                rng = f"a number in [{lo}, {hi}]"
            elif lo is not None:
                rng = f"a number >= {lo}"
            self.append(
                f"{self.key(name)}={v!r}: must be {rng}{' or null' if optional else ''}{'; ' + fix if fix else ''}"
            )

    def raise_if_any(self) -> None:
        if self:
            raise ConfigError(self)
