"""Materials of the glass object: a name (``object.ior=water``) or a number is its index of
refraction; a colour reached at a thickness (``object.absorption``) is its absorption (Beer–Lambert).

Convention: absorption coefficients σ are per metre of the placed object (scene units), one per
linear RGB channel; a path of length ``L`` inside the medium transmits ``exp(-σ L)`` of its light.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = [
    "MATERIALS",
    "CLEAR",
    "resolve_ior",
    "ior_range_problem",
    "ior_out_of_range",
    "absorption_coefficients",
    "absorption_problem",
    "check_sigma",
    "Medium",
]

#: No absorption: σ = 0 in every channel.
CLEAR: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Medium:
    """The material inside one closed shell of an object made of several (a glass of water).

    Attributes:
        ior: index of refraction (a material name or a number, :func:`resolve_ior`).
        absorption: σ per metre (linear R, G, B; :func:`absorption_coefficients`).
        priority: where shells overlap, the medium of highest priority fills the overlap; a ray
            that crosses the surface of a shell of lower priority than the medium it is in meets no
            interface there. Ties: the shell listed later wins.
    """

    ior: float = 1.5
    absorption: tuple = CLEAR
    priority: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "ior", resolve_ior(self.ior))
        object.__setattr__(self, "absorption", check_sigma(self.absorption))
        if isinstance(self.priority, bool) or not isinstance(self.priority, int):
            raise ValueError(f"a medium's priority must be an integer, got {self.priority!r}")


#: Refractive indices (sodium D line, ~589 nm) of common transparent materials.
MATERIALS: dict[str, float] = {
    "air": 1.0,
    "ice": 1.31,
    "water": 1.333,
    "acrylic": 1.49,
    "glass": 1.5,
    "crown_glass": 1.52,
    "quartz": 1.544,
    "flint_glass": 1.62,
    "sapphire": 1.77,
    "cubic_zirconia": 2.15,
    "diamond": 2.42,
}


def resolve_ior(material: str | float | int) -> float:
    """Index of refraction from a material name in :data:`MATERIALS` or a number.

    Raises ``ValueError`` for an unknown name or a value that is not finite and > 0.
    An IOR of 1 is allowed (the object is invisible: identity warp); below 1 means the object is
    optically thinner than its surroundings (e.g. an air bubble: pass the ratio).
    """
    if isinstance(material, str):
        key = material.strip().lower().replace(" ", "_").replace("-", "_")
        if key in MATERIALS:
            return MATERIALS[key]
        try:
            material = float(key)
        except ValueError:
            raise ValueError(
                f"unknown material {material!r}; use one of {sorted(MATERIALS)} or a number (the IOR)"
            ) from None
    if isinstance(material, bool):
        raise ValueError(f"ior must be a number or a material name, got {material!r}")
    try:
        ior = float(material)
    except (TypeError, ValueError):
        raise ValueError(f"ior must be a number or a material name, got {material!r}") from None
    if not math.isfinite(ior) or ior <= 0.0:
        raise ValueError(f"ior must be finite and > 0, got {material!r} (glass is 1.5, water 1.333)")
    return ior


def ior_range_problem(ior_range) -> str | None:
    """Why ``object.ior_range`` is unusable (two finite numbers ``0 < low <= high``), or ``None``.

    Examples:
        >>> ior_range_problem([1, 3]) is None
        True
        >>> ior_range_problem([3, 1])
        'object.ior_range=[3, 1]: must be [low, high], two finite numbers with 0 < low <= high; e.g. object.ior_range=[1,3]'
    """
    values = list(ior_range) if isinstance(ior_range, Sequence) and not isinstance(ior_range, str) else None
    ok = (
        values is not None
        and len(values) == 2
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)
        and 0 < values[0] <= values[1]
    )
    if ok:
        return None
    shown = values if values is not None else ior_range
    return (
        f"object.ior_range={shown!r}: must be [low, high], two finite numbers with 0 < low <= high; "
        "e.g. object.ior_range=[1,3]"
    )


def ior_out_of_range(ior: float, ior_range) -> str | None:
    """Why the IOR ``ior`` lies outside ``object.ior_range`` (a valid range), or ``None``.

    The line starts with the comparison (``below object.ior_range=[1.0, 3.0] ...``) and ends with
    the override that accepts it; the caller prefixes the key and the value.

    Examples:
        >>> ior_out_of_range(1.5, [1, 3]) is None
        True
        >>> ior_out_of_range(0.75, [1, 3]).split(";")[0]
        'below object.ior_range=[1.0, 3.0] (a solid or liquid has an IOR >= 1)'
    """
    low, high = (float(v) for v in ior_range)
    shown = f"object.ior_range=[{low}, {high}]"
    if ior < low:
        new_low = f"{ior:.6g}" if ior > 0 else "0.5"
        why = " (a solid or liquid has an IOR >= 1)" if low >= 1.0 else ""
        return (
            f"below {shown}{why}; for an object optically thinner than its surroundings (an air bubble) lower it "
            f"explicitly: object.ior_range=[{new_low},{high:g}]"
        )
    if ior > high:
        why = " (no transparent solid or liquid exceeds about 3 in visible light; diamond is 2.42)" if high <= 3 else ""
        return f"above {shown}{why}; for a larger IOR raise it explicitly: object.ior_range=[{low:g},{ior:.6g}]"
    return None


def absorption_problem(color, distance) -> str | None:
    """Why ``object.absorption`` (``color``, ``distance``) is unusable, or ``None``.

    ``color`` is the linear RGB transmittance reached after ``distance`` metres of the medium: three
    finite numbers in ``(0, 1]`` (1: that channel is not absorbed; 0 would absorb everything at any
    thickness); ``distance`` a finite number > 0.

    Examples:
        >>> absorption_problem([0.5, 0.8, 1.0], 0.05) is None
        True
        >>> absorption_problem([0.0, 0.8, 1.0], 0.05)
        'object.absorption.color=[0.0, 0.8, 1.0]: three linear RGB transmittances in (0, 1], e.g. [0.5,0.8,0.95]'
    """
    values = list(color) if isinstance(color, Sequence) and not isinstance(color, str) else None
    ok = values is not None and len(values) == 3 and all(_number(v) and 0.0 < float(v) <= 1.0 for v in values)
    if not ok:
        shown = values if values is not None else color
        return f"object.absorption.color={shown!r}: three linear RGB transmittances in (0, 1], e.g. [0.5,0.8,0.95]"
    if not (_number(distance) and float(distance) > 0.0):
        return (
            f"object.absorption.distance={distance!r}: the thickness (metres) at which the colour is reached, a "
            "finite number > 0, e.g. 0.05"
        )
    return None


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def absorption_coefficients(color, distance) -> tuple[float, float, float]:
    """σ per metre (per linear RGB channel) of a medium that transmits ``color`` after ``distance``
    metres: ``σ = -ln(C) / d`` (Beer–Lambert).

    Raises:
        ValueError: as :func:`absorption_problem` says.

    Examples:
        >>> [round(s, 4) for s in absorption_coefficients([0.5, 1.0, 0.25], 0.1)]
        [6.9315, 0.0, 13.8629]
    """
    problem = absorption_problem(color, distance)
    if problem is not None:
        raise ValueError(problem)
    return tuple(-math.log(float(c)) / float(distance) + 0.0 for c in color)


def check_sigma(sigma) -> tuple[float, float, float]:
    """``sigma`` as three finite absorption coefficients >= 0 (per metre), else ``ValueError``."""
    try:
        values = [float(v) for v in sigma] if not isinstance(sigma, str) else None
    except (TypeError, ValueError):
        values = None
    if values is None or len(values) != 3 or not all(math.isfinite(v) and v >= 0.0 for v in values):
        raise ValueError(
            f"absorption must be three finite coefficients >= 0 per metre (linear R, G, B), got {sigma!r}; "
            "set object.absorption.color and .distance instead"
        )
    return tuple(v + 0.0 for v in values)
