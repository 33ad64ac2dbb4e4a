"""States of a cell in which no score could mean anything, detected where the pipeline computes
them: the object's warps void over every object pixel, an empty metric mask, a reference without one
finite pixel. Each check returns the reason in one line, or ``None``; :class:`~snell_bench.pipeline.Degenerate`
carries it to the record (``status: degenerate``)."""

from __future__ import annotations

import numpy as np

__all__ = ["reference_problem", "warps_problem"]


def warps_problem(warps, max_bounces: int | None = None) -> str | None:
    """Why the warps cannot carry a result: the object covers pixels but none of their refracted
    rays leaves it for the background (every one trapped or lost), or ``None``."""
    m = np.asarray(warps.object_mask, bool)
    n = int(m.sum())
    if n == 0 or bool(np.asarray(warps.refraction_valid, bool)[m].any()):
        return None
    bounces = f" within warps.max_bounces={max_bounces}" if max_bounces is not None else ""
    return (
        f"no refracted ray leaves the object{bounces}: refraction is valid in 0 of its {n:,} pixels, so "
        "the image has nothing to show through the glass; raise warps.max_bounces (8 traces a sphere)"
    )


def reference_problem(reference) -> str | None:
    """Why a rendered reference cannot score anything: no finite pixel, or an empty metric mask, or
    ``None`` (``None`` for no reference too: that is recorded as a missing metric, not a state)."""
    if reference is None:
        return None
    if not np.isfinite(np.asarray(reference.image)).any():
        return "the reference render has no finite pixel (NaN or infinite everywhere): nothing to score against"
    mask = getattr(reference, "mask", None)
    if mask is not None and not np.asarray(mask, bool).any():
        return (
            "the metric mask is empty: no object pixel refracts onto an observed surface, so no masked metric "
            "has a pixel to score"
        )
    return None
