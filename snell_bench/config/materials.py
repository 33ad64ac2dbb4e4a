"""Materials of the glass object: a name (``object.ior=water``) or a number is its index of refraction."""

from __future__ import annotations

import math

__all__ = ["MATERIALS", "resolve_ior"]

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
