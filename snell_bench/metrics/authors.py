"""The authors' released evaluation (``eval/masked_metrics.py``) reproduced in float32 torch on
the 8-bit images snell_bench writes: :func:`authors_metrics` (PSNR and MAE), the inputs as the
authors read them from PNG files (:func:`quantize_8bit`, :func:`authors_inputs`), their grayscale
(:func:`authors_gray`) and their 256-bin histogram matching (:func:`authors_histogram_matching`).

These are the ``metrics.protocol="authors"`` branch of
:func:`~snell_bench.metrics.functional.masked_psnr`, :func:`~snell_bench.metrics.functional.masked_mae`
and :func:`~snell_bench.metrics.functional.match_histogram_masked`; every name is re-exported by
:mod:`snell_bench.metrics.functional`.

Convention:
    - Images: as in :mod:`snell_bench.metrics.functional` (float in [0, 1], or ``uint8``), quantised
      to 8 bits as :func:`snell_bench.utils.io.save_png` writes them and read back as ``value / 255``
      in float32, ``(1, 3, H, W)`` on the CPU; a one-channel image as a gray PNG opened as RGB.
    - Masks: bool (``True`` = scored) as given; any other read as an 8-bit image, ``value / 255 >=``
      :data:`AUTHORS_MASK_THRESHOLD`.
    - Results: Python floats (PSNR ``inf`` where ``MSE <= 1e-8``), or :class:`MetricUnavailable` for
      an empty mask or non-finite pixel values. Float32 on the CPU (the authors' default device is
      CUDA, whose float32 reductions may differ in the last bits); no gradients.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
import torch

from snell_bench.metrics.common import EMPTY_MASK_REASON, GRAY_WEIGHTS, NON_FINITE_REASON, MetricUnavailable

__all__ = [
    "AUTHORS_BINS",
    "AUTHORS_EPS",
    "AUTHORS_MASK_THRESHOLD",
    "AuthorsScores",
    "authors_gray",
    "authors_histogram_matching",
    "authors_inputs",
    "authors_metrics",
    "quantize_8bit",
]

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
