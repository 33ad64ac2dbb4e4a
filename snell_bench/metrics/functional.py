"""Masked fidelity metrics as pure functions: histogram-matched grayscale PSNR and MAE under the
paper's evaluation protocol or the authors' released one, and the helpers they share (grayscale,
masked histogram matching, the protocol check). The class forms (batch accumulators, masked LPIPS)
are in :mod:`snell_bench.metrics.fidelity`.

Convention:
    - Images: torch float tensors ``(B, 3, H, W)`` with ``B == 1`` or ``(3, H, W)``, or numpy arrays
      ``(H, W, 3)``; sRGB-encoded values in [0, 1] (data range 1; values are not clamped). ``uint8``
      inputs are read as ``value / 255``. One-channel images (``(B, 1, H, W)``, ``(H, W)``) are taken
      as already gray.
      The functions score ONE image pair (``B == 1``).
    - Masks: bool ``(H, W)``, ``(1, H, W)``, ``(B, 1, H, W)`` or ``(H, W, 1)``; True marks a scored
      pixel (an object pixel whose refracted ray reaches a surface observed in the object-free image).
      Non-bool masks are read as ``mask > 0.5``.
    - Grayscale: ``Y = 0.299 R + 0.587 G + 0.114 B`` on the sRGB-encoded values.
    - Histogram matching: the GENERATED image's masked values are remapped so that their empirical
      distribution matches the REFERENCE's masked values. ``method="cdf"`` (default) is
      :func:`skimage.exposure.match_histograms` applied to the masked values (the cumulative-CDF
      mapping; deterministic under ties: equal values map to equal values). ``method="rank"`` is exact
      histogram specification: the k-th smallest generated value (stable order) receives the k-th
      smallest reference value, so the matched values are a permutation of the reference's. Pixels
      outside the mask are never read by PSNR / MAE.
    - Protocol (config key ``metrics.protocol``, see :data:`PROTOCOLS`):

      * ``"paper"`` (the paper's text): PSNR / MAE on the matched values above.
      * ``"authors"`` (the authors' released evaluation code): the matched values are rescaled
        linearly to the generated image's own range inside the mask (:func:`match_histogram_masked`)
        before PSNR / MAE.

    - PSNR ``= 10 log10(1 / MSE)`` over the masked pixels (``inf`` for identical pixels);
      MAE ``= mean |generated - reference|`` over the masked pixels.
    - Results: a Python ``float`` (never NaN), or :class:`MetricUnavailable` with a ``reason`` (empty
      mask, non-finite pixel values, weights not on this machine). A metric is never replaced by a
      placeholder number. An unknown protocol raises ``ValueError`` naming ``metrics.protocol``.
    - PSNR / MAE compute in float64 numpy on the CPU; no gradients anywhere.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from snell_bench.config.choices import Protocol

__all__ = [
    "EMPTY_MASK_REASON",
    "GRAY_WEIGHTS",
    "MetricUnavailable",
    "NON_FINITE_REASON",
    "PROTOCOLS",
    "PROTOCOL_CONFIG_KEY",
    "check_protocol",
    "masked_mae",
    "masked_psnr",
    "match_histogram_masked",
    "to_gray",
]

#: Luma weights (R, G, B) of the grayscale conversion.
GRAY_WEIGHTS = (0.299, 0.587, 0.114)

#: The reason reported for an empty mask.
EMPTY_MASK_REASON = "empty mask: no object pixel refracts onto an observed surface"

#: The reason reported when the scored pixels hold NaN or infinite values.
NON_FINITE_REASON = "non-finite pixel values (NaN or inf) in the generated or reference image"

#: The evaluation protocols: ``"paper"`` (the paper's text) and ``"authors"`` (the authors' code).
PROTOCOLS = Protocol.values()

#: The config key that selects the protocol.
PROTOCOL_CONFIG_KEY = "metrics.protocol"


class MetricUnavailable(Exception):
    """A metric cannot be computed; ``reason`` says why (and, for missing weights or programs, which
    config key to set). Scoring code reports the metric as missing with this reason."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


def check_protocol(protocol: Any) -> str:
    """The protocol name, checked.

    Convention:
        ``protocol`` must be one of :data:`PROTOCOLS` (a ``str``); anything else raises ``ValueError``
        naming the config key ``metrics.protocol`` and the allowed values.
    """
    if not isinstance(protocol, str) or protocol not in PROTOCOLS:
        allowed = ", ".join(repr(p) for p in PROTOCOLS)
        raise ValueError(f"unknown evaluation protocol {protocol!r}: set {PROTOCOL_CONFIG_KEY} to one of {allowed}")
    return protocol


# --------------------------------------------------------------------------------------------
# Input normalisation
# --------------------------------------------------------------------------------------------


def _image_hwc(x: Any, name: str) -> np.ndarray:
    """One image as float64 numpy ``(H, W, C)`` with C in {1, 3}."""
    if isinstance(x, torch.Tensor):
        t = x.detach().cpu()
        if t.ndim == 4:
            if t.shape[0] != 1:
                raise ValueError(
                    f"{name}: batch of {t.shape[0]} images; the functional metrics score one image "
                    "(use MaskedPSNR / MaskedMAE for batches)"
                )
            t = t[0]
        if t.ndim == 2:
            t = t[None]
        if t.ndim != 3:
            raise ValueError(f"{name}: expected (B, C, H, W), (C, H, W) or (H, W), got {tuple(x.shape)}")
        scale = 255.0 if t.dtype == torch.uint8 else 1.0
        arr = t.permute(1, 2, 0).to(torch.float64).numpy() / scale
    else:
        a = np.asarray(x)
        scale = 255.0 if a.dtype == np.uint8 else 1.0
        arr = a.astype(np.float64) / scale
        if arr.ndim == 4 and arr.shape[0] == 1:
            arr = arr[0]
        if arr.ndim == 2:
            arr = arr[..., None]
        if arr.ndim != 3:
            raise ValueError(f"{name}: expected a numpy (H, W, 3) or (H, W) image, got {a.shape}")
    if arr.shape[-1] not in (1, 3):
        raise ValueError(f"{name}: expected 1 or 3 channels, got shape {arr.shape}")
    return arr


def _mask_hw(mask: Any, hw: tuple[int, int]) -> np.ndarray:
    """A mask as bool numpy ``(H, W)``."""
    m = mask.detach().cpu().numpy() if isinstance(mask, torch.Tensor) else np.asarray(mask)
    while m.ndim > 2 and m.shape[0] == 1:
        m = m[0]
    if m.ndim == 3 and m.shape[-1] == 1:
        m = m[..., 0]
    if m.dtype != np.bool_:
        m = m > 0.5
    if m.shape != tuple(hw):
        raise ValueError(f"mask shape {m.shape} does not match the image size {tuple(hw)}")
    return m


def _gray_hwc(arr: np.ndarray) -> np.ndarray:
    if arr.shape[-1] == 1:
        return arr
    w = np.asarray(GRAY_WEIGHTS, dtype=np.float64)
    return (arr * w).sum(-1, keepdims=True)


def to_gray(image):
    """Grayscale ``0.299 R + 0.587 G + 0.114 B``.

    Convention:
        torch ``(..., 3, H, W)`` -> ``(..., 1, H, W)`` (same float dtype); numpy ``(H, W, 3)`` ->
        ``(H, W)`` (float64). ``uint8`` inputs are read as ``value / 255``. One-channel inputs keep
        their values (numpy ``(H, W, 1)`` -> ``(H, W)``).
    """
    if isinstance(image, torch.Tensor):
        if image.ndim < 3 or image.shape[-3] not in (1, 3):
            raise ValueError(f"expected (..., 3, H, W), got {tuple(image.shape)}")
        if not image.is_floating_point():
            image = image.to(torch.float32) / (255.0 if image.dtype == torch.uint8 else 1.0)
        if image.shape[-3] == 1:
            return image
        w = torch.tensor(GRAY_WEIGHTS, dtype=image.dtype, device=image.device).view(3, 1, 1)
        return (image * w).sum(-3, keepdim=True)
    a = np.asarray(image)
    a = a.astype(np.float64) / (255.0 if a.dtype == np.uint8 else 1.0)
    if a.ndim == 2:
        return a
    if a.ndim != 3 or a.shape[-1] not in (1, 3):
        raise ValueError(f"expected a numpy (H, W, 3) image, got {a.shape}")
    return _gray_hwc(a)[..., 0]


# --------------------------------------------------------------------------------------------
# Histogram matching
# --------------------------------------------------------------------------------------------


def _match_values(src: np.ndarray, tmpl: np.ndarray, method: str) -> np.ndarray:
    """Map the 1-D values ``src`` onto the distribution of the 1-D values ``tmpl`` (float64 out)."""
    if method == "cdf":
        from skimage.exposure import match_histograms

        # float64 in, float64 out: skimage would return float32 for float32 inputs
        return match_histograms(np.asarray(src, np.float64), np.asarray(tmpl, np.float64))
    if method == "rank":
        if src.size != tmpl.size:
            raise ValueError("rank matching needs as many generated as reference values")
        out = np.empty_like(tmpl, dtype=np.float64)
        out[np.argsort(src, kind="stable")] = np.sort(tmpl)
        return out
    raise ValueError(f"unknown histogram matching method {method!r} (use 'cdf' or 'rank')")


def _rescale_to_range(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Rescale the 1-D values linearly from their own range onto ``[lo, hi]`` (float64 out).

    Convention:
        :func:`skimage.exposure.rescale_intensity` with ``in_range="image"`` and
        ``out_range=(lo, hi)``: ``lo + (v - min v) (hi - lo) / (max v - min v)``. Values of zero range
        (all equal) cannot be stretched: they are clipped to ``[lo, hi]`` (skimage's rule), so they
        stay constant and never divide by zero. Values whose range already is ``[lo, hi]`` are
        returned unchanged (the identity map, without rounding).
    """
    from skimage.exposure import rescale_intensity

    values = np.asarray(values, np.float64)
    if values.min() == lo and values.max() == hi:
        return values
    return rescale_intensity(values, in_range="image", out_range=(float(lo), float(hi)))


def _match_protocol(src: np.ndarray, tmpl: np.ndarray, method: str, protocol: str) -> np.ndarray:
    """Histogram matching of the 1-D values ``src`` onto ``tmpl`` as ``protocol`` does it."""
    matched = _match_values(src, tmpl, method)
    if protocol == "authors":
        matched = _rescale_to_range(matched, float(src.min()), float(src.max()))
    return matched


def _squeeze_hw(x: Any, name: str) -> np.ndarray:
    a = x.detach().cpu().to(torch.float64).numpy() if isinstance(x, torch.Tensor) else np.asarray(x, np.float64)
    while a.ndim > 2 and a.shape[0] == 1:
        a = a[0]
    if a.ndim == 3 and a.shape[-1] == 1:
        a = a[..., 0]
    if a.ndim != 2:
        raise ValueError(f"{name}: expected a single-channel image (H, W), got {tuple(np.shape(x))}")
    return a


def match_histogram_masked(gen_gray, ref_gray, mask, *, method: str = "cdf", protocol: str = "paper"):
    """Match the histogram of ``gen_gray`` to that of ``ref_gray`` inside ``mask``.

    With ``g`` the masked values of ``gen_gray`` and ``r`` those of ``ref_gray``:

    - ``protocol="paper"``: ``m = match(g, r)``, the generated values carried onto the reference's
      values (``method="cdf"``: :func:`skimage.exposure.match_histograms`; ``"rank"``: exact
      specification).
    - ``protocol="authors"``: the histogram is matched in shape only: ``m`` as above, then rescaled
      linearly onto the generated values' own range, ``min g + (m - min m) (max g - min g) /
      (max m - min m)`` (:func:`skimage.exposure.rescale_intensity`). When ``m`` is constant
      (``max m == min m``: a constant generated image, or a constant reference) the rescale cannot
      stretch it and leaves a constant: ``m`` clipped to ``[min g, max g]``, i.e. the generated
      constant itself for a constant generated image. No division by zero, no NaN.

    Convention:
        ``gen_gray`` / ``ref_gray``: one-channel images, ``(H, W)`` or with singleton leading dims
        (``(1, 1, H, W)``), numpy or torch. Returns ``gen_gray``'s type and shape (torch: same dtype and
        device; numpy: float64) with the masked pixels remapped and the others unchanged. An empty mask
        returns an unchanged copy. An unknown ``protocol`` raises ``ValueError``.
    """
    check_protocol(protocol)
    g = _squeeze_hw(gen_gray, "gen_gray")
    r = _squeeze_hw(ref_gray, "ref_gray")
    if g.shape != r.shape:
        raise ValueError(f"image sizes differ: {g.shape} vs {r.shape}")
    m = _mask_hw(mask, g.shape)
    out = g.copy()
    if m.any():
        out[m] = _match_protocol(g[m], r[m], method, protocol)
    if isinstance(gen_gray, torch.Tensor):
        return torch.from_numpy(out).to(dtype=gen_gray.dtype, device=gen_gray.device).reshape(gen_gray.shape)
    return out.reshape(np.shape(gen_gray))


# --------------------------------------------------------------------------------------------
# PSNR / MAE
# --------------------------------------------------------------------------------------------


def _prepare_pair(generated, reference, mask, grayscale: bool):
    g = _image_hwc(generated, "generated")
    r = _image_hwc(reference, "reference")
    if g.shape[:2] != r.shape[:2]:
        raise ValueError(f"image sizes differ: {g.shape[:2]} vs {r.shape[:2]}")
    if grayscale:
        g, r = _gray_hwc(g), _gray_hwc(r)
    elif g.shape[-1] != r.shape[-1]:
        raise ValueError(f"channel counts differ: {g.shape[-1]} vs {r.shape[-1]}")
    return g, r, _mask_hw(mask, g.shape[:2])


def _masked_values(
    generated, reference, mask, histogram_match: bool, grayscale: bool, method: str, protocol: str = "paper"
):
    """Masked (generated, reference) values, shape (N, C), after grayscale and matching."""
    check_protocol(protocol)
    g, r, m = _prepare_pair(generated, reference, mask, grayscale)
    if not m.any():
        raise MetricUnavailable(EMPTY_MASK_REASON)
    gv, rv = g[m], r[m]
    if not (np.isfinite(gv).all() and np.isfinite(rv).all()):
        raise MetricUnavailable(NON_FINITE_REASON)
    if histogram_match:
        gv = np.stack([_match_protocol(gv[:, c], rv[:, c], method, protocol) for c in range(gv.shape[1])], axis=1)
    return gv, rv


def masked_psnr(
    generated,
    reference,
    mask,
    *,
    histogram_match: bool = True,
    grayscale: bool = True,
    method: str = "cdf",
    protocol: str = "paper",
) -> float:
    """PSNR ``10 log10(1 / MSE)`` over the masked pixels (data range 1).

    Steps, with ``g`` / ``r`` the masked grayscale (``0.299 R + 0.587 G + 0.114 B``) values of the
    generated and reference images:

    - ``protocol="paper"``: ``g' = match(g, r)`` (the generated histogram carried onto the reference's
      values, see :func:`match_histogram_masked`), ``MSE = mean (g' - r)^2``. Invariant to any
      increasing tone change of the generated image: it measures what no brightness, contrast or
      tone-curve change can fix (the ordering of the intensities).
    - ``protocol="authors"``: ``g' = min g + (m - min m) (max g - min g) / (max m - min m)`` with
      ``m = match(g, r)`` (matched in shape, kept in the generated image's own range; a constant ``m``
      is clipped to ``[min g, max g]``), ``MSE = mean (g' - r)^2``. Forgives the shape of the tone
      curve but not the generated image's range: an affine change ``a r + b`` (``a > 0``) of the
      reference scores like the unmatched pair.

    Convention:
        Defaults: grayscale, histogram-matched, ``paper``. ``grayscale=False`` scores the RGB channels
        (matched, and under ``authors`` rescaled, per channel) and averages the squared error over
        pixels and channels; ``histogram_match=False`` compares the values as they are (both protocols
        then agree). Returns ``inf`` when the (matched) masked pixels are identical. Raises
        :class:`MetricUnavailable` for an empty mask or non-finite masked values, ``ValueError`` for an
        unknown ``protocol`` (naming ``metrics.protocol``).
    """
    gv, rv = _masked_values(generated, reference, mask, histogram_match, grayscale, method, protocol)
    mse = float(np.mean((gv - rv) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


def masked_mae(
    generated,
    reference,
    mask,
    *,
    histogram_match: bool = True,
    grayscale: bool = True,
    method: str = "cdf",
    protocol: str = "paper",
) -> float:
    """Mean absolute error ``mean |g' - r|`` over the masked pixels.

    Convention:
        ``g'`` and ``r`` as in :func:`masked_psnr` (same preprocessing for each ``protocol``, same
        options and errors). Zero for identical (matched) masked pixels.
    """
    gv, rv = _masked_values(generated, reference, mask, histogram_match, grayscale, method, protocol)
    return float(np.mean(np.abs(gv - rv)))
