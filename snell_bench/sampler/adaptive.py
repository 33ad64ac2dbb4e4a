"""Model only what a scene requires: per-scene decisions of the sampler, taken from the warps.

Convention: ``decide`` is pure; it returns the settings the sampler actually runs with, the
decisions with the numbers behind them (logged per run and stored with every result), and the
object pixels that keep a reflection (``None``: all of them).

- Reflection: a pixel's reflection changes its linear colour by ``R (c_refl - c_refr)``, at most
  ``R``; pixels with ``R < sampler.reflection_min_fresnel`` keep the refraction colour alone, and the
  reflection warp is restricted to the others (skipped where none is left).
- Panorama branch: it only contributes where rays reach surfaces I⁻ does not show. When at least
  ``sampler.skip_panorama_above`` of the object's pixels send their refracted ray (and their mirror
  ray, where a reflection is kept) to surfaces I⁻ observes, the branch is skipped: half the model
  calls and the panorama's warps and blends; the reflection then comes from I⁻ itself. With
  ``sampler.pano_to_main: frame`` the branch also reaches the pixels around the object, where I⁻
  itself is blended in; skipping it leaves them phi(x0, I⁻), which the savings report measures with
  the rest (``decisions["panorama"]["pano_to_main"]`` records which it was).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from snell_bench.config.sampler import SamplerSettings
from snell_bench.optics.warps import WarpSet

__all__ = ["decide"]


def decide(warps: WarpSet, settings: SamplerSettings) -> tuple[SamplerSettings, dict, np.ndarray | None]:
    """The settings to run with, the decisions (JSON-ready) and the reflection mask ``(H, W)``."""
    s = settings
    decisions: dict = {"roi": bool(s.roi)}
    if s.sync != "snellcaster":
        return s, decisions, None
    m = warps.object_mask
    n = int(m.sum())
    keep = None
    if s.reflection:
        thr = float(s.reflection_min_fresnel)
        if thr > 0:
            f = warps.fresnel[m]
            keep = m & (warps.fresnel >= thr)
            k = int(keep.sum())
            decisions["reflection"] = {
                "kept": k > 0,
                "pixels_kept": k,
                "share_kept": k / n if n else 0.0,
                "min_fresnel": thr,
                "max_fresnel": float(f.max()) if n else 0.0,
            }
            if k == 0:
                s = dataclasses.replace(s, reflection=False)
                keep = None
        else:
            decisions["reflection"] = {"kept": True, "pixels_kept": n, "share_kept": 1.0, "min_fresnel": 0.0}
    if s.uses_panorama and s.skip_panorama_above is not None:
        thr = float(s.skip_panorama_above)
        observed = warps.refraction_valid.copy()
        if s.reflection:
            needs_refl = m if keep is None else keep
            observed &= warps.reflection_valid | ~needs_refl
        share = float(observed[m].mean()) if n else 1.0
        skip = share >= thr
        decisions["panorama"] = {
            "used": not skip,
            "observed_share": share,
            "skip_above": thr,
            "pano_to_main": s.pano_to_main,
        }
        if skip:
            s = dataclasses.replace(s, panorama=False)
    else:
        decisions["panorama"] = {"used": s.uses_panorama}
    return s, decisions, keep
