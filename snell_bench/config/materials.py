"""Materials of the glass object: a name (``object.ior=water``) or a number is its index of refraction."""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["MATERIALS", "resolve_ior", "ior_range_problem", "ior_out_of_range"]

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
