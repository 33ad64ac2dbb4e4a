"""Masked fidelity metrics as pure functions: histogram-matched grayscale PSNR and MAE under the
paper's evaluation protocol or the authors' released one, and the helpers they share (grayscale,
masked histogram matching, the protocol check). The class forms (batch accumulators, masked LPIPS)
are in :mod:`snell_bench.metrics.fidelity`. The authors' evaluation is in
:mod:`snell_bench.metrics.authors`, the protocols, :class:`MetricUnavailable` and its reasons in
:mod:`snell_bench.metrics.common`; this module re-exports both, the names users import.

Convention:
    - Images: torch float tensors ``(B, 3, H, W)`` with ``B == 1`` or ``(3, H, W)``, or numpy arrays
      ``(H, W, 3)``; sRGB-encoded values in [0, 1] (data range 1; values are not clamped). ``uint8``
      inputs are read as ``value / 255``. One-channel images (``(B, 1, H, W)``, ``(H, W)``) are taken
      as already gray (``authors``: as a gray PNG opened as RGB, the value repeated in 3 channels).
      The functions score ONE image pair (``B == 1``).
    - Masks: bool ``(H, W)``, ``(1, H, W)``, ``(B, 1, H, W)`` or ``(H, W, 1)``; True marks a scored
      pixel (an object pixel whose refracted ray reaches a surface observed in the object-free image).
      Non-bool masks are read as ``mask > 0.5`` (``authors``: as an 8-bit image, ``>= 0.5``).
    - Grayscale: ``Y = 0.299 R + 0.587 G + 0.114 B`` on the sRGB-encoded values.
    - Histogram matching: the GENERATED image's masked values are remapped so that their empirical
      distribution matches the REFERENCE's masked values. ``method="cdf"`` (default) is
      :func:`skimage.exposure.match_histograms` applied to the masked values (the cumulative-CDF
      mapping; deterministic under ties: equal values map to equal values). ``method="rank"`` is exact
      histogram specification: the k-th smallest generated value (stable order) receives the k-th
      smallest reference value, so the matched values are a permutation of the reference's. Pixels
      outside the mask are never read by PSNR / MAE.
    - Protocol (config key ``metrics.protocol``, see :data:`PROTOCOLS`):

      * ``"paper"`` (the paper's text): PSNR / MAE on the matched values above, in float64.
      * ``"authors"`` (the authors' released evaluation, ``eval/masked_metrics.py``): computed by
        :func:`authors_metrics`, which reproduces that file on the 8-bit images snell_bench writes:
        both images quantised to 8 bits as :func:`snell_bench.utils.io.save_png` writes them and read
        back as ``value / 255`` in float32, the mask read as an 8-bit image thresholded at ``>= 0.5``,
        float32 grayscale, the authors' 256-bin histogram matching
        (:func:`authors_histogram_matching`), float32 PSNR / MAE. ``method`` does not apply.

    - PSNR ``= 10 log10(1 / MSE)`` over the masked pixels (``inf`` for identical pixels; ``authors``:
      ``inf`` where ``MSE <= 1e-8``, ``torch.isclose``'s default tolerance); MAE ``= mean |generated - reference|`` over the masked pixels.
    - Results: a Python ``float`` (never NaN), or :class:`MetricUnavailable` with a ``reason`` (empty
      mask, non-finite pixel values, weights not on this machine). A metric is never replaced by a
      placeholder number. An unknown protocol raises ``ValueError`` naming ``metrics.protocol``.
    - ``paper`` PSNR / MAE compute in float64 numpy on the CPU; ``authors`` in float32 torch on the
      CPU (the authors' default device is CUDA, whose float32 reductions may differ in the last bits).
      No gradients anywhere.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from snell_bench.metrics.authors import (
    AUTHORS_BINS,
    AUTHORS_EPS,
    AUTHORS_MASK_THRESHOLD,
    AuthorsScores,
    _check_authors_method,
    authors_gray,
    authors_histogram_matching,
    authors_inputs,
    authors_metrics,
    quantize_8bit,
)
from snell_bench.metrics.common import (
    EMPTY_MASK_REASON,
    GRAY_WEIGHTS,
    NON_FINITE_REASON,
    PROTOCOL_CONFIG_KEY,
    PROTOCOLS,
    MetricUnavailable,
    check_protocol,
)

__all__ = [
    "AUTHORS_BINS",
    "AUTHORS_EPS",
    "AUTHORS_MASK_THRESHOLD",
    "AuthorsScores",
    "EMPTY_MASK_REASON",
    "GRAY_WEIGHTS",
    "MetricUnavailable",
    "NON_FINITE_REASON",
    "PROTOCOLS",
    "PROTOCOL_CONFIG_KEY",
    "authors_gray",
    "authors_histogram_matching",
    "authors_inputs",
    "authors_metrics",
    "check_protocol",
    "masked_mae",
    "masked_psnr",
    "match_histogram_masked",
    "quantize_8bit",
    "to_gray",
]


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
      specification); the other pixels unchanged.
    - ``protocol="authors"``: :func:`authors_histogram_matching` of the float32 values ``g`` onto
      ``r`` (256 bins, the matched levels rescaled to the generated values' own range), written back
      into the image, then the WHOLE image clamped to [0, 1] (outside the mask too), as the authors'
      evaluation does. ``method`` must be ``"cdf"`` (the default; the authors have one method).

    Convention:
        ``gen_gray`` / ``ref_gray``: one-channel images, ``(H, W)`` or with singleton leading dims
        (``(1, 1, H, W)``), numpy or torch. Returns ``gen_gray``'s type and shape (torch: same dtype and
        device; numpy: float64) with the masked pixels remapped. An empty mask returns an unchanged
        copy (``authors``: clamped). An unknown ``protocol`` raises ``ValueError``.
    """
    check_protocol(protocol)
    g = _squeeze_hw(gen_gray, "gen_gray")
    r = _squeeze_hw(ref_gray, "ref_gray")
    if g.shape != r.shape:
        raise ValueError(f"image sizes differ: {g.shape} vs {r.shape}")
    m = _mask_hw(mask, g.shape)
    if protocol == "authors":
        _check_authors_method(method)
        g32 = torch.from_numpy(g.astype(np.float32))
        valid = torch.from_numpy(m)
        if m.any():
            g32[valid] = authors_histogram_matching(g32[valid], torch.from_numpy(r.astype(np.float32))[valid])
        out = torch.clamp(g32, 0.0, 1.0).to(torch.float64).numpy()
    else:
        out = g.copy()
        if m.any():
            out[m] = _match_values(g[m], r[m], method)
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


def _masked_values(generated, reference, mask, histogram_match: bool, grayscale: bool, method: str):
    """Masked (generated, reference) values of the ``paper`` protocol, shape (N, C), float64, after
    grayscale and matching."""
    g, r, m = _prepare_pair(generated, reference, mask, grayscale)
    if not m.any():
        raise MetricUnavailable(EMPTY_MASK_REASON)
    gv, rv = g[m], r[m]
    if not (np.isfinite(gv).all() and np.isfinite(rv).all()):
        raise MetricUnavailable(NON_FINITE_REASON)
    if histogram_match:
        gv = np.stack([_match_values(gv[:, c], rv[:, c], method) for c in range(gv.shape[1])], axis=1)
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
    - ``protocol="authors"``: :func:`authors_metrics` (the authors' evaluation on the 8-bit images:
      256-bin matching whose levels are placed in the generated image's own masked range, float32;
      ``inf`` where ``MSE <= 1e-8``). It forgives the shape of the tone curve, not the generated
      image's range.

    Convention:
        Defaults: grayscale, histogram-matched, ``paper``. ``grayscale=False`` scores the RGB channels
        and averages the squared error over pixels and channels (``paper``: matched per channel;
        ``authors``: only unmatched, their RGB PSNR); ``histogram_match=False`` compares the values as
        they are. ``paper`` returns ``inf`` when the (matched) masked pixels are identical. Raises
        :class:`MetricUnavailable` for an empty mask or non-finite masked values, ``ValueError`` for an
        unknown ``protocol`` (naming ``metrics.protocol``) or an option the authors' evaluation lacks.
    """
    if check_protocol(protocol) == "authors":
        _check_authors_method(method)
        return authors_metrics(generated, reference, mask, grayscale=grayscale, histogram_match=histogram_match).psnr
    gv, rv = _masked_values(generated, reference, mask, histogram_match, grayscale, method)
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
        options and errors; ``authors``: :func:`authors_metrics`). Zero for identical (matched)
        masked pixels.
    """
    if check_protocol(protocol) == "authors":
        _check_authors_method(method)
        return authors_metrics(generated, reference, mask, grayscale=grayscale, histogram_match=histogram_match).mae
    gv, rv = _masked_values(generated, reference, mask, histogram_match, grayscale, method)
    return float(np.mean(np.abs(gv - rv)))
