"""Masked fidelity metrics as pure functions: histogram-matched grayscale PSNR and MAE under the
paper's evaluation protocol or the authors' released one, and the helpers they share (grayscale,
masked histogram matching, the protocol check). The class forms (batch accumulators, masked LPIPS)
are in :mod:`snell_bench.metrics.fidelity`.

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
from typing import Any, NamedTuple

import numpy as np
import torch

from snell_bench.config.choices import Protocol

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
# The authors' evaluation (eval/masked_metrics.py), reproduced in float32 torch
# --------------------------------------------------------------------------------------------

#: Number of histogram bins of the authors' matching.
AUTHORS_BINS = 256

#: The mask threshold of the authors' evaluation (on the 8-bit mask read as ``value / 255``).
AUTHORS_MASK_THRESHOLD = 0.5

#: The constant the authors add to every normaliser (min/max range, histogram sum).
AUTHORS_EPS = 1e-8


class AuthorsScores(NamedTuple):
    """PSNR (dB, may be ``inf``) and MAE of :func:`authors_metrics`, as Python floats."""

    psnr: float
    mae: float


def _check_authors_method(method: str) -> None:
    if method != "cdf":
        raise ValueError(
            f"histogram matching method {method!r} does not apply to metrics.protocol='authors' "
            "(the authors' evaluation has one matching): use method='cdf' or protocol='paper'"
        )


def quantize_8bit(image: Any) -> np.ndarray:
    """An image as the 8-bit values :func:`snell_bench.utils.io.save_png` writes.

    Convention:
        Float input (numpy or torch; torch ``(1, C, H, W)`` / ``(C, H, W)`` is moved to ``(H, W, C)``):
        ``clip(rint(255 x), 0, 255)`` in float64 (``rint``: round half to even), as ``uint8``; ``uint8``
        input is returned as it is. Numpy layout ``(H, W, C)`` / ``(H, W)`` kept. Non-finite values
        raise :class:`MetricUnavailable` (no PNG can hold them).
    """
    if isinstance(image, torch.Tensor):
        t = image.detach().cpu()
        if t.ndim == 4:
            if t.shape[0] != 1:
                raise ValueError(f"expected one image, got a batch of {t.shape[0]}")
            t = t[0]
        a = t.permute(1, 2, 0).numpy() if t.ndim == 3 else t.numpy()
    else:
        a = np.asarray(image)
    if a.dtype == np.uint8:
        return a
    a = np.asarray(a, np.float64)
    if not np.isfinite(a).all():
        raise MetricUnavailable(NON_FINITE_REASON)
    return np.clip(np.rint(a * 255.0), 0, 255).astype(np.uint8)


def _authors_image(x: Any, name: str) -> torch.Tensor:
    """One image as the authors read its PNG: ``(1, 3, H, W)`` float32, ``uint8 / 255``."""
    q = quantize_8bit(x)
    if q.ndim == 3 and q.shape[-1] == 1:
        q = q[..., 0]
    if q.ndim == 2:  # a gray PNG opened with convert("RGB")
        q = np.repeat(q[..., None], 3, axis=-1)
    if q.ndim != 3 or q.shape[-1] != 3:
        raise ValueError(f"{name}: expected an (H, W, 3) or (H, W) image, got shape {q.shape}")
    arr = np.asarray(q, dtype=np.float32) / 255.0
    return torch.from_numpy(arr).permute(2, 0, 1).unsqueeze(0)


def _authors_mask(mask: Any, hw: tuple[int, int]) -> torch.Tensor:
    """The scored pixels as the authors read the mask PNG: bool ``(1, 1, H, W)``.

    A bool mask is saved as 0 / 255 and read back unchanged; any other mask is quantised like
    :func:`quantize_8bit`, read as ``value / 255`` in float32 and thresholded at ``>= 0.5``.
    """
    m = mask.detach().cpu().numpy() if isinstance(mask, torch.Tensor) else np.asarray(mask)
    while m.ndim > 2 and m.shape[0] == 1:
        m = m[0]
    if m.ndim == 3 and m.shape[-1] == 1:
        m = m[..., 0]
    if m.shape != tuple(hw):
        raise ValueError(f"mask shape {m.shape} does not match the image size {tuple(hw)}")
    if m.dtype != np.bool_:
        m = (np.asarray(quantize_8bit(m), dtype=np.float32) / 255.0) >= AUTHORS_MASK_THRESHOLD
    return torch.from_numpy(np.ascontiguousarray(m))[None, None]


def authors_gray(rgb: torch.Tensor) -> torch.Tensor:
    """Grayscale of the authors' evaluation: ``(1, 3, H, W)`` -> ``(1, 1, H, W)``, in ``rgb``'s dtype.

    Convention:
        The weights ``(0.299, 0.587, 0.114)`` rounded to ``rgb``'s dtype, products summed over the
        channel dimension by ``torch.sum`` (float32 for the authors' protocol).
    """
    w = torch.tensor(GRAY_WEIGHTS, dtype=rgb.dtype, device=rgb.device).view(1, 3, 1, 1)
    return (rgb * w).sum(dim=1, keepdim=True)


def authors_histogram_matching(source: torch.Tensor, template: torch.Tensor) -> torch.Tensor:
    """The authors' histogram matching of the 1-D values ``source`` onto ``template``.

    With ``n = 256`` bins, for ``v`` in {source, template} (all arithmetic as written, float32
    tensors, the min / max taken as Python floats):

    1. ``lo, hi = v.min(), v.max()``; ``u = (v - lo) / (hi - lo + 1e-8)``, the denominator summed in
       Python (float64), then rounded to float32 by the division;
    2. ``hist = histc(u, n, 0, 1)`` (bin ``floor(n u)``, ``u = 1`` in the last bin);
       ``pdf = hist / (sum(hist) + 1e-8)``; ``cdf = cumsum(pdf)``.

    Then each source value's bin is looked up as ``k = clamp(int(u_s (n - 1)), 0, n - 1)``
    (truncation, with ``n - 1`` where histc used ``n``: a value may read the CDF of the bin below its
    own), its matched bin is the FIRST ``j`` minimising ``|cdf_t[j] - cdf_s[k]|`` (``torch.argmin``),
    and its value is ``linspace(0, 1, n)[j] (hi_s - lo_s) + lo_s``: the template's CDF shape placed
    in the SOURCE's range. A constant source maps to itself; a constant template maps every source
    value to ``lo_s``.

    Convention:
        ``source`` ``(N,)`` and ``template`` ``(M,)`` float32 tensors (N, M >= 1), same device.
        Returns ``(N,)`` float32. Computes the ``(n, n)`` bin-to-bin distance once (the authors
        compute ``(N, n)``; the argmin of equal rows is equal, so the values are identical).
    """
    n = AUTHORS_BINS

    def normalised(v: torch.Tensor) -> tuple[torch.Tensor, float, float]:
        lo, hi = v.min().item(), v.max().item()
        return (v - lo) / (hi - lo + AUTHORS_EPS), lo, hi

    def cdf(u: torch.Tensor) -> torch.Tensor:
        hist = torch.histc(u, bins=n, min=0.0, max=1.0)
        return torch.cumsum(hist / (hist.sum() + AUTHORS_EPS), dim=0)

    u_s, lo_s, hi_s = normalised(source)
    u_t, _, _ = normalised(template)
    cdf_s, cdf_t = cdf(u_s), cdf(u_t)
    bins = torch.clamp((u_s * (n - 1)).long(), 0, n - 1)
    # matched bin of every source bin: first argmin over the template bins
    bin_map = torch.argmin(torch.abs(cdf_t.unsqueeze(0) - cdf_s.unsqueeze(1)), dim=1)
    levels = torch.linspace(0.0, 1.0, n, device=source.device)
    return levels[bin_map[bins]] * (hi_s - lo_s) + lo_s


def _authors_psnr(gt: torch.Tensor, gen: torch.Tensor, valid: torch.Tensor) -> float:
    """``10 log10(1 / MSE)`` over ``valid`` (expanded to the images' channels) in float32; ``inf``
    where ``torch.isclose(MSE, 0)`` (default tolerances: ``MSE <= 1e-8``)."""
    diff = (gt - gen)[valid.expand_as(gt)]
    mse = torch.mean(diff**2)
    if torch.isclose(mse, torch.tensor(0.0, device=mse.device)):
        return math.inf
    return float((10.0 * torch.log10(1.0 / mse)).item())


def _authors_mae(gt: torch.Tensor, gen: torch.Tensor, valid: torch.Tensor) -> float:
    """``mean |gt - gen|`` over ``valid`` (expanded to the images' channels) in float32."""
    return float(torch.mean(torch.abs((gt - gen)[valid.expand_as(gt)])).item())


def authors_inputs(generated, reference, mask) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The authors' evaluation inputs: ``(generated, reference, valid)``.

    Convention:
        Images quantised by :func:`quantize_8bit` and read as ``uint8 / 255`` in float32,
        ``(1, 3, H, W)`` on the CPU; ``valid`` the bool mask ``(1, 1, H, W)`` (the 8-bit mask
        ``>= 0.5``). Raises :class:`MetricUnavailable` for an empty mask or non-finite values.
    """
    g = _authors_image(generated, "generated")
    r = _authors_image(reference, "reference")
    if g.shape != r.shape:
        raise ValueError(f"image sizes differ: {tuple(g.shape[-2:])} vs {tuple(r.shape[-2:])}")
    valid = _authors_mask(mask, tuple(g.shape[-2:]))
    if not bool(valid.any()):
        raise MetricUnavailable(EMPTY_MASK_REASON)
    return g, r, valid


def authors_metrics(
    generated, reference, mask, *, grayscale: bool = True, histogram_match: bool = True
) -> AuthorsScores:
    """PSNR and MAE exactly as the authors' ``eval/masked_metrics.py`` computes them from PNG files.

    Steps (float32 torch on the CPU; ``G`` / ``R`` the generated / reference images):

    1. :func:`authors_inputs`: both images quantised to 8 bits as ``save_png`` writes them and read
       back as ``value / 255``; the mask read as an 8-bit image ``/ 255 >= 0.5``.
    2. ``grayscale=True``: :func:`authors_gray` of both. ``histogram_match=True``: the generated gray
       values inside the mask are replaced by :func:`authors_histogram_matching` onto the
       reference's, and the whole generated gray image is clamped to [0, 1] (the reference is not).
    3. PSNR ``= 10 log10(1 / MSE)`` over the mask (``inf`` where ``torch.isclose(MSE, 0)``, i.e.
       ``MSE <= 1e-8``); MAE ``= mean |R - G'|`` over the mask.

    The authors report the matched gray pair (``psnr_gray_matched``, ``mae_gray_matched``, the
    defaults here), and the unmatched PSNR of the gray (``histogram_match=False``) and of the RGB
    images (``grayscale=False, histogram_match=False``); they do not match RGB images
    (``grayscale=False, histogram_match=True`` raises ``ValueError``). The unmatched MAE is the same
    float32 mean of the unmatched pair.

    Convention:
        Images as in the module (float in [0, 1], values outside clipped by the quantisation, or
        ``uint8``); masks bool (``True`` = scored) or 8-bit / float values. Scoring the in-memory
        images equals scoring the PNG files snell_bench writes. Raises :class:`MetricUnavailable` for
        an empty mask (after thresholding) or non-finite pixel values.
    """
    if histogram_match and not grayscale:
        raise ValueError(
            "the authors' evaluation matches gray values only: with metrics.protocol='authors' use "
            "grayscale=True, or histogram_match=False for their RGB PSNR"
        )
    g, r, valid = authors_inputs(generated, reference, mask)
    if grayscale:
        g, r = authors_gray(g), authors_gray(r)
    if histogram_match:
        g = g.clone()
        g[valid] = authors_histogram_matching(g[valid], r[valid])
        g = torch.clamp(g, 0.0, 1.0)
    return AuthorsScores(_authors_psnr(r, g, valid), _authors_mae(r, g, valid))


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
