"""Scores of a relit image against the true relit image: the shadow and caustic the object casts.

Convention:
    - Images: ``(H, W, 3)`` float sRGB in [0, 1]; ``unrelit`` is the image the relighter got, the
      truth's own ``before`` the same scene without the object's light (I⁻ with the object's own
      pixels); ``receivers``: ``(H, W)`` bool, the pixels scored (lit surfaces, not the object).
    - Ratio images, in linear RGB: ``relit / unrelit`` and ``truth / before`` (0 where the
      denominator is below 1e-4), the multiplicative change of each pixel's light.
    - Region: the receivers whose truth differs from ``before`` by more than ``threshold`` (2/255
      in sRGB, in any channel): where the object changes the light.
    - ``psnr_region``: PSNR (peak 1, RGB) of the relit image against the truth in the region;
      ``psnr_ratio``: PSNR (peak 1) of the ratio images there, each clipped to [0, 2].
    - ``shadow_iou``: intersection over union of the shadow footprints, the receivers whose
      ratio's mean over RGB is below ``1 - shadow`` (10 % darker).
    - Caustic: the light added, ``max(0, relit - unrelit)`` summed over RGB in linear RGB, over the
      receivers where either ratio's mean exceeds ``1 + caustic`` (10 % brighter: the truth's noise
      stays out); ``caustic_energy_error`` its total's relative error against the truth's
      (``None`` where the truth has none), ``caustic_centroid_px`` the distance in pixels between the
      two light-weighted centroids (``None`` where either has none).
"""

from __future__ import annotations

import math

import numpy as np

from snell_bench.imaging.color import srgb_to_linear

__all__ = ["RELIGHT_METRICS", "relight_region", "relight_scores"]

#: The scores :func:`relight_scores` returns, with their direction (``+1``: higher is better).
RELIGHT_METRICS = {
    "psnr_region": +1,
    "psnr_ratio": +1,
    "shadow_iou": +1,
    "caustic_energy_error": -1,
    "caustic_centroid_px": -1,
}


def _lin(image) -> np.ndarray:
    return srgb_to_linear(np.asarray(image, np.float32)).astype(np.float64)


def _ratio(after, before) -> np.ndarray:
    a, b = _lin(after), _lin(before)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(b > 1e-4, a / b, 0.0)


def relight_region(truth, before, receivers, threshold: float = 2 / 255) -> np.ndarray:
    """``(H, W)`` bool: the receivers whose truth differs from ``before`` by more than ``threshold``."""
    diff = np.abs(np.asarray(truth, np.float64) - np.asarray(before, np.float64)).max(-1)
    return np.asarray(receivers, bool) & (diff > threshold)


def _psnr(a, b, m) -> float:
    mse = float(((np.asarray(a, np.float64) - np.asarray(b, np.float64))[m] ** 2).mean())
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


def _added(after, before, m) -> np.ndarray:
    return np.where(m, np.clip(_lin(after) - _lin(before), 0.0, None).sum(-1), 0.0)


def _centroid(w: np.ndarray) -> np.ndarray | None:
    total = float(w.sum())
    if total <= 0:
        return None
    v, u = np.mgrid[0 : w.shape[0], 0 : w.shape[1]]
    return np.array([(w * u).sum(), (w * v).sum()]) / total


def relight_scores(relit, unrelit, truth, before, receivers, *, shadow: float = 0.1, caustic: float = 0.1) -> dict:
    """The scores of ``relit`` (module convention).

    Returns:
        ``{name: float | None}`` for every name of :data:`RELIGHT_METRICS`, and ``region_px``.

    Raises:
        ValueError: the images differ in shape, or the region is empty (the object changes nothing).
    """
    shapes = {np.shape(x) for x in (relit, unrelit, truth, before)}
    if len(shapes) != 1 or np.shape(receivers) != np.shape(truth)[:2]:
        raise ValueError(f"relight_scores needs images of one shape and a mask of their size, got {shapes}")
    region = relight_region(truth, before, receivers)
    if not region.any():
        raise ValueError("the truth does not differ from the scene without the object's light: nothing to score")
    r_m = np.clip(_ratio(relit, unrelit), 0.0, 2.0)
    r_t = np.clip(_ratio(truth, before), 0.0, 2.0)
    rec = np.asarray(receivers, bool)
    dark_m, dark_t = rec & (r_m.mean(-1) < 1 - shadow), rec & (r_t.mean(-1) < 1 - shadow)
    union = int((dark_m | dark_t).sum())
    bright = rec & ((r_m.mean(-1) > 1 + caustic) | (r_t.mean(-1) > 1 + caustic))
    add_m, add_t = _added(relit, unrelit, bright), _added(truth, before, bright)
    e_t = float(add_t.sum())
    c_m, c_t = _centroid(add_m), _centroid(add_t)
    return {
        "psnr_region": _psnr(relit, truth, region),
        "psnr_ratio": _psnr(r_m, r_t, region),
        "shadow_iou": float((dark_m & dark_t).sum() / union) if union else None,
        "caustic_energy_error": abs(float(add_m.sum()) - e_t) / e_t if e_t > 0 else None,
        "caustic_centroid_px": float(np.linalg.norm(c_m - c_t)) if c_m is not None and c_t is not None else None,
        "region_px": int(region.sum()),
    }
