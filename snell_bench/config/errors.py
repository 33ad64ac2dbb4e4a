"""The error of an unusable config, and the value checks that write its lines.

Every line names the key, the bad value and the fix (``scene.variation=-1: must be an integer >= 0
...; e.g. scene.variation=0``); :class:`ConfigError` carries all lines of a config at once.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

__all__ = ["ConfigError", "MAX_SEED", "MAX_SPP", "Problems", "is_int", "is_number"]

#: The largest seed a setting takes: a cell's seed is ``seed + scene.variation``, and
#: ``torch.Generator.manual_seed`` takes at most ``2**64 - 1``, so each stays below ``2**63``.
MAX_SEED = 2**63 - 1
#: The most samples per pixel a setting takes (``reference.spp``, ``grid.converged_spp``, ...): 64 times
#: the converged reference of the paper preset (1058) and of the authors' Cycles render (1024). The
#: renderers set the ceiling: Mitsuba's samplers hold the sample count and a pass's wavefront (pixels x
#: samples) in 32-bit integers, so a pass stays below ``2**32`` samples (at 65,536 samples per pixel a
#: window of 256 x 256 pixels fills one; Mitsuba splits a larger window into passes), and the
#: procedural true render and the relighting truth trace one frame per sample; a typo such as
#: ``spp=1000000000`` would fail inside Dr.Jit or run for days.
MAX_SPP = 2**16


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

    def int_at_least(
        self, name: str, v: Any, lo: int, why: str = "", example: int | None = None, hi: int | None = None
    ) -> None:
        """``v`` is an integer >= ``lo`` (and <= ``hi``)."""
        key = self.key(name)
        fix = f"e.g. {key}={lo if example is None else example}"
        if not is_int(v) or v < lo:
            self.append(f"{key}={v!r}: must be an integer >= {lo}{why}; {fix}")
        elif hi is not None and v > hi:
            self.append(f"{key}={v!r}: must be an integer <= {hi}{why}; {fix}")

    def spp(self, name: str, v: Any, example: int, lo: int = 1, why: str = "") -> None:
        """``v`` is a sample count in ``[lo, MAX_SPP]`` (:data:`MAX_SPP`); ``why``: what else the
        line says, e.g. ``"null: off; "``."""
        why = f" ({why}samples per pixel: a converged reference takes about 1,000)"
        self.int_at_least(name, v, lo, why, example, hi=MAX_SPP)

    def seed(self, name: str, v: Any, why: str = "") -> None:
        """``v`` is an integer in ``[0, MAX_SEED]`` (:data:`MAX_SEED`)."""
        self.int_at_least(name, v, 0, why or " (random generators take a seed in [0, 2**63 - 1])", 0, hi=MAX_SEED)

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

    def append_if(self, line: str | None, prefix: str = "") -> None:
        """Add ``prefix + line`` unless ``line`` is ``None`` (a check that found nothing)."""
        if line is not None:
            self.append(prefix + line)

    def nonempty_or_null(self, name: str, v: Any, what: str) -> None:
        """``v`` is ``None`` or a non-blank string (a folder or an address)."""
        if v is not None and not str(v).strip():
            self.append(f"{self.key(name)}={v!r}: must be {what}, not empty; e.g. {self.key(name)}=null")

    def numbers(self, name: str, v: Any, length: int, *, optional: bool = False, fix: str = "") -> list[float] | None:
        """``v`` is a list of ``length`` finite numbers (``None`` allowed with ``optional``).

        Returns:
            The numbers as floats, or ``None`` (``v`` is ``None``, or a line was added).
        """
        if v is None and optional:
            return None
        values = list(v) if isinstance(v, Sequence) and not isinstance(v, str) else None
        if values is None or len(values) != length:
            got = f"{len(values)} value{'' if len(values) == 1 else 's'}" if values is not None else "not a list"
            self.append(
                f"{self.key(name)}={v!r}: must be a list of {length} numbers, got {got}{'; ' + fix if fix else ''}"
            )
            return None
        if not all(is_number(x) and math.isfinite(float(x)) for x in values):
            self.append(
                f"{self.key(name)}={values!r}: must hold finite numbers (no NaN, inf or text){'; ' + fix if fix else ''}"
            )
            return None
        return [float(x) for x in values]

    def raise_if_any(self) -> None:
        if self:
            raise ConfigError(self)
