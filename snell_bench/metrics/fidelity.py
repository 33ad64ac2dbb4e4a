"""Masked fidelity metrics: histogram-matched grayscale PSNR and MAE, and masked LPIPS.

Convention:
    - Images: torch float tensors ``(B, 3, H, W)`` or ``(3, H, W)``, or numpy arrays ``(H, W, 3)``;
      sRGB-encoded values in [0, 1] (data range 1; values are not clamped). ``uint8`` inputs are read
      as ``value / 255``. One-channel images (``(B, 1, H, W)``, ``(H, W)``) are taken as already gray.
      The functional metrics score ONE image pair (``B == 1``); :class:`MaskedPSNR` and
      :class:`MaskedMAE` accumulate batches.
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
    - PSNR ``= 10 log10(1 / MSE)`` over the masked pixels (``inf`` for identical pixels);
      MAE ``= mean |generated - reference|`` over the masked pixels.
    - LPIPS: the spatial LPIPS map (``spatial=True``) of the preprocessed full images, averaged over
      the mask. Its value at a masked pixel also depends on the pixels of its receptive field.
    - Results: a Python ``float``, or :class:`MetricUnavailable` with a ``reason`` (empty mask, weights
      not on this machine). A metric is never replaced by a placeholder number.
    - PSNR / MAE compute in float64 numpy on the CPU; no gradients anywhere.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from snell_bench.utils.tensors import as_tensor, hwc_to_bchw

__all__ = [
    "EMPTY_MASK_REASON",
    "GRAY_WEIGHTS",
    "MaskedLPIPS",
    "MaskedMAE",
    "MaskedPSNR",
    "MetricUnavailable",
    "masked_mae",
    "masked_psnr",
    "match_histogram_masked",
    "to_gray",
]

#: Luma weights (R, G, B) of the grayscale conversion.
GRAY_WEIGHTS = (0.299, 0.587, 0.114)

#: The reason reported for an empty mask.
EMPTY_MASK_REASON = "empty mask: no object pixel refracts onto an observed surface"


class MetricUnavailable(Exception):
    """A metric cannot be computed; ``reason`` says why (and, for missing weights or programs, which
    config key to set). Scoring code reports the metric as missing with this reason."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


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


def match_histogram_masked(gen_gray, ref_gray, mask, *, method: str = "cdf"):
    """Match the histogram of ``gen_gray`` to that of ``ref_gray`` inside ``mask``.

    Convention:
        ``gen_gray`` / ``ref_gray``: one-channel images, ``(H, W)`` or with singleton leading dims
        (``(1, 1, H, W)``), numpy or torch. Returns ``gen_gray``'s type and shape (torch: same dtype and
        device; numpy: float64) with the masked pixels remapped and the others unchanged. ``method``:
        ``"cdf"`` (skimage's cumulative-CDF mapping) or ``"rank"`` (exact specification). An empty mask
        returns an unchanged copy.
    """
    g = _squeeze_hw(gen_gray, "gen_gray")
    r = _squeeze_hw(ref_gray, "ref_gray")
    if g.shape != r.shape:
        raise ValueError(f"image sizes differ: {g.shape} vs {r.shape}")
    m = _mask_hw(mask, g.shape)
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
    """Masked (generated, reference) values, shape (N, C), after grayscale and matching."""
    g, r, m = _prepare_pair(generated, reference, mask, grayscale)
    if not m.any():
        raise MetricUnavailable(EMPTY_MASK_REASON)
    gv, rv = g[m], r[m]
    if histogram_match:
        gv = np.stack([_match_values(gv[:, c], rv[:, c], method) for c in range(gv.shape[1])], axis=1)
    return gv, rv


def masked_psnr(
    generated, reference, mask, *, histogram_match: bool = True, grayscale: bool = True, method: str = "cdf"
) -> float:
    """PSNR ``10 log10(1 / MSE)`` over the masked pixels (data range 1).

    Convention:
        Defaults follow the protocol: grayscale, then the generated image's masked histogram is matched
        to the reference's. ``grayscale=False`` scores the RGB channels (matched per channel) and
        averages the squared error over pixels and channels. Returns ``inf`` when the (matched) masked
        pixels are identical. Raises :class:`MetricUnavailable` for an empty mask.
    """
    gv, rv = _masked_values(generated, reference, mask, histogram_match, grayscale, method)
    mse = float(np.mean((gv - rv) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


def masked_mae(
    generated, reference, mask, *, histogram_match: bool = True, grayscale: bool = True, method: str = "cdf"
) -> float:
    """Mean absolute error over the masked pixels; same conventions as :func:`masked_psnr`."""
    gv, rv = _masked_values(generated, reference, mask, histogram_match, grayscale, method)
    return float(np.mean(np.abs(gv - rv)))


def _iter_batch(generated, reference, mask):
    """Yield single-image (generated, reference, mask) triples from batched or single inputs."""
    if isinstance(generated, torch.Tensor) and generated.ndim == 4:
        b = generated.shape[0]
        if not isinstance(reference, torch.Tensor) or reference.shape[0] != b:
            raise ValueError("generated and reference batches differ in size")
        m = as_tensor(mask)
        for i in range(b):
            mi = m[i] if (m.ndim == 4 or (m.ndim == 3 and m.shape[0] == b and b > 1)) else m
            yield generated[i], reference[i], mi
    else:
        yield generated, reference, mask


class _MaskedMean:
    """Accumulates a per-image masked metric over batches; ``compute()`` is the mean over images
    with a non-empty mask (``missing`` counts the others)."""

    _fn: Callable[..., float]

    def __init__(self, *, histogram_match: bool = True, grayscale: bool = True, method: str = "cdf"):
        self.kwargs = dict(histogram_match=histogram_match, grayscale=grayscale, method=method)
        self.reset()

    def reset(self) -> None:
        self.values: list[float] = []
        self.missing = 0

    def update(self, generated, reference, mask) -> None:
        for g, r, m in _iter_batch(generated, reference, mask):
            try:
                self.values.append(type(self)._fn(g, r, m, **self.kwargs))
            except MetricUnavailable:
                self.missing += 1

    def compute(self) -> float:
        if not self.values:
            raise MetricUnavailable(EMPTY_MASK_REASON if self.missing else "no images scored")
        return float(np.mean(self.values))

    def __call__(self, generated, reference, mask) -> float:
        """Score one pair without touching the accumulated state."""
        return type(self)._fn(generated, reference, mask, **self.kwargs)


class MaskedPSNR(_MaskedMean):
    """Class form of :func:`masked_psnr`: ``update`` with batches, ``compute`` the mean PSNR."""

    _fn = staticmethod(masked_psnr)


class MaskedMAE(_MaskedMean):
    """Class form of :func:`masked_mae`: ``update`` with batches, ``compute`` the mean MAE."""

    _fn = staticmethod(masked_mae)


# --------------------------------------------------------------------------------------------
# LPIPS
# --------------------------------------------------------------------------------------------

#: torchvision checkpoint file names of the LPIPS backbones (the torch hub cache names).
_BACKBONE_FILES = {
    "vgg": ("vgg16", "vgg16-397923af.pth"),
    "alex": ("alexnet", "alexnet-owt-7be5be79.pth"),
    "squeeze": ("squeezenet1_1", "squeezenet1_1-b8a52dc0.pth"),
}


class MaskedLPIPS(torch.nn.Module):
    """LPIPS averaged over a mask of its spatial map.

    Convention:
        - Backbone weights (never downloaded): ``weights_path`` (config key ``metrics.lpips_weights``),
          a torchvision state_dict file of the backbone (``vgg16-397923af.pth`` for ``net="vgg"``),
          else the same file name in the torch hub cache (``<torch.hub.get_dir()>/checkpoints``).
          Neither present: :class:`MetricUnavailable` naming ``metrics.lpips_weights``. The calibrated
          linear layers ship with the ``lpips`` package.
        - ``allow_random_backbone=True`` (with ``weights_path=None``) builds a randomly initialised
          backbone (seeded, no cache lookup) for plumbing tests only: its values are meaningless.
        - Inputs follow the module's image/mask convention; by default they are converted to grayscale
          and the generated image's masked histogram is matched to the reference's (as for PSNR), the
          gray image is repeated to 3 channels, and both are scaled to [-1, 1].
        - ``forward`` returns a float: the mean of the ``(H, W)`` LPIPS map over the mask.
    """

    CONFIG_KEY = "metrics.lpips_weights"

    def __init__(
        self,
        weights_path: str | os.PathLike | None = None,
        net: str = "vgg",
        *,
        allow_random_backbone: bool = False,
        device: str | torch.device = "cpu",
    ):
        super().__init__()
        if net not in _BACKBONE_FILES:
            raise ValueError(f"unknown LPIPS backbone {net!r}; one of {sorted(_BACKBONE_FILES)}")
        tv_name, file_name = _BACKBONE_FILES[net]
        path = self._resolve_weights(weights_path, file_name, tv_name, allow_random_backbone)

        import lpips

        with warnings.catch_warnings(), torch.random.fork_rng(devices=[]):
            warnings.simplefilter("ignore")  # torchvision's deprecated `pretrained=` argument
            torch.manual_seed(0)
            self.model = lpips.LPIPS(net=net, pretrained=True, pnet_rand=True, spatial=True, verbose=False)
        self._tv_name = tv_name
        if path is not None:
            self._load_backbone(path)
        self.net = net
        self.backbone_source = str(path) if path is not None else "random"
        self.model.to(device)
        self.eval()

    @classmethod
    def _resolve_weights(cls, weights_path, file_name: str, tv_name: str, allow_random: bool) -> Path | None:
        hint = (
            f"set {cls.CONFIG_KEY} to a torchvision {tv_name} state_dict file (e.g. {file_name}) "
            f"or place {file_name} in {Path(torch.hub.get_dir()) / 'checkpoints'}"
        )
        if weights_path is not None:
            p = Path(weights_path).expanduser()
            if not p.is_file():
                raise MetricUnavailable(f"LPIPS backbone weights not found at {p}: {hint}")
            return p
        if allow_random:
            return None
        cached = Path(torch.hub.get_dir()) / "checkpoints" / file_name
        if cached.is_file():
            return cached
        raise MetricUnavailable(f"no LPIPS {tv_name} backbone weights on this machine: {hint}")

    def _load_backbone(self, path: Path) -> None:
        state = torch.load(path, map_location="cpu", weights_only=True)
        if isinstance(state, dict) and "state_dict" in state:
            state = state["state_dict"]
        mapping = {}  # lpips key -> torchvision key
        for slice_name, slice_mod in self.model.net.named_children():
            if not slice_name.startswith("slice"):
                continue
            for idx, layer in slice_mod.named_children():
                for pname, _ in layer.named_parameters():
                    mapping[f"{slice_name}.{idx}.{pname}"] = f"features.{idx}.{pname}"
        absent = [k for k in mapping.values() if k not in state]
        if absent:
            raise ValueError(
                f"{path} is not a torchvision {self._tv_name} state_dict: "
                f"missing {absent[:3]}{' ...' if len(absent) > 3 else ''}"
            )
        try:
            self.model.net.load_state_dict({dst: state[src] for dst, src in mapping.items()}, strict=True)
        except RuntimeError as e:
            raise ValueError(f"{path} does not fit the LPIPS backbone: {e}") from e

    def _inputs(self, generated, reference, mask, grayscale: bool, histogram_match: bool, method: str):
        g, r, m = _prepare_pair(generated, reference, mask, grayscale)
        if histogram_match and m.any():
            g = g.copy()
            for c in range(g.shape[-1]):
                g[..., c][m] = _match_values(g[..., c][m], r[..., c][m], method)
        device = next(self.model.parameters()).device

        def to_tensor(a: np.ndarray) -> torch.Tensor:
            t = hwc_to_bchw(a)
            if t.shape[1] == 1:
                t = t.expand(-1, 3, -1, -1)
            return (t * 2.0 - 1.0).to(device)

        return to_tensor(g), to_tensor(r), m

    @torch.no_grad()
    def spatial_map(
        self, generated, reference, mask, *, grayscale: bool = True, histogram_match: bool = True, method: str = "cdf"
    ) -> torch.Tensor:
        """The LPIPS map ``(H, W)`` of the preprocessed pair (the mask drives the histogram matching)."""
        g, r, _ = self._inputs(generated, reference, mask, grayscale, histogram_match, method)
        return self.model(g, r)[0, 0].cpu()

    @torch.no_grad()
    def forward(
        self, generated, reference, mask, *, grayscale: bool = True, histogram_match: bool = True, method: str = "cdf"
    ) -> float:
        """Mean of the LPIPS map over the mask; :class:`MetricUnavailable` for an empty mask."""
        g, r, m = self._inputs(generated, reference, mask, grayscale, histogram_match, method)
        if not m.any():
            raise MetricUnavailable(EMPTY_MASK_REASON)
        lp = self.model(g, r)[0, 0].cpu().to(torch.float64)
        return float(lp[torch.from_numpy(m)].mean())
