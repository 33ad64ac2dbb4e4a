"""Masked fidelity metrics as objects: batch accumulators of masked PSNR and MAE, and masked LPIPS,
under the paper's evaluation protocol or the authors' released one. The functional forms and the
shared conventions (images, masks, grayscale, histogram matching, protocols, results) are those of
:mod:`snell_bench.metrics.functional`.

Convention:
    - Batches: :class:`MaskedPSNR` and :class:`MaskedMAE` take images ``(B, 3, H, W)`` with masks
      ``(B, 1, H, W)`` (or one mask for the whole batch) in ``update``, score each image with the
      functional form and ``compute`` the mean over the images with a value; images without one
      (empty mask, non-finite pixels) are counted in ``missing`` and their reasons kept.
    - Protocol (config key ``metrics.protocol``) for LPIPS:

      * ``"paper"`` (the paper's text): LPIPS on the matched grayscale full images, its spatial map
        averaged over the mask.
      * ``"authors"`` (the authors' released evaluation code): LPIPS on the RGB images (neither gray
        nor matched), both multiplied by the mask (black outside it), averaged over the whole image.

    - LPIPS: the spatial LPIPS map (``spatial=True``) of the preprocessed full images, averaged over
      the mask (``paper``), or the plain LPIPS value of the masked images (``authors``). Its value at a
      masked pixel also depends on the pixels of its receptive field. No gradients.
    - Results: a Python ``float`` (never NaN), or :class:`~snell_bench.metrics.functional.MetricUnavailable`
      with a ``reason``.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from snell_bench.metrics.functional import (
    EMPTY_MASK_REASON,
    NON_FINITE_REASON,
    MetricUnavailable,
    _match_values,
    _prepare_pair,
    check_protocol,
    masked_mae,
    masked_psnr,
)
from snell_bench.utils.tensors import as_tensor, hwc_to_bchw

__all__ = ["MaskedLPIPS", "MaskedMAE", "MaskedPSNR"]


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
    with a value (``missing`` counts the others: empty mask, non-finite pixels). The options are those
    of the functional form, ``protocol`` included."""

    _fn: Callable[..., float]

    def __init__(
        self, *, histogram_match: bool = True, grayscale: bool = True, method: str = "cdf", protocol: str = "paper"
    ):
        self.kwargs = dict(
            histogram_match=histogram_match, grayscale=grayscale, method=method, protocol=check_protocol(protocol)
        )
        self.reset()

    def reset(self) -> None:
        self.values: list[float] = []
        self.missing = 0
        self._reasons: list[str] = []

    def update(self, generated, reference, mask) -> None:
        for g, r, m in _iter_batch(generated, reference, mask):
            try:
                self.values.append(type(self)._fn(g, r, m, **self.kwargs))
            except MetricUnavailable as e:
                self.missing += 1
                if e.reason not in self._reasons:
                    self._reasons.append(e.reason)

    def compute(self) -> float:
        if not self.values:
            raise MetricUnavailable("; ".join(self._reasons) if self.missing else "no images scored")
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
    """LPIPS (VGG) of a masked region, under the paper's protocol or the authors'.

    - ``protocol="paper"``: both images converted to grayscale, the generated image's masked
      histogram matched to the reference's (as for PSNR; pixels outside the mask keep their gray
      values), the gray images repeated to 3 channels and scaled to [-1, 1]; the value is the mean of
      the ``(H, W)`` spatial LPIPS map over the masked pixels.
    - ``protocol="authors"``: both RGB images (neither gray nor matched) multiplied by the mask (zero,
      i.e. black, outside it), scaled to [-1, 1], and given to LPIPS as they are: the value is what
      ``lpips.LPIPS(net, spatial=False)(gen * mask, ref * mask, normalize=True)`` returns, each
      layer's distance map averaged over the WHOLE image. Pixels outside the mask are black in both
      inputs and add little distance, so the value shrinks with the mask's share of the image: it is
      comparable only between images scored with the same mask.

    Convention:
        - Backbone weights (never downloaded): ``weights_path`` (config key ``metrics.lpips_weights``),
          a torchvision state_dict file of the backbone (``vgg16-397923af.pth`` for ``net="vgg"``),
          else the same file name in the torch hub cache (``<torch.hub.get_dir()>/checkpoints``).
          Neither present: :class:`MetricUnavailable` naming ``metrics.lpips_weights``. The calibrated
          linear layers ship with the ``lpips`` package.
        - ``allow_random_backbone=True`` (with ``weights_path=None``) builds a randomly initialised
          backbone (seeded, no cache lookup) for plumbing tests only: its values are meaningless.
        - Inputs follow the module's image/mask convention. ``grayscale``, ``histogram_match`` and
          ``method`` are options of the ``paper`` preprocessing (``False`` skips a step); ``authors``
          fixes its own (RGB, unmatched) and does not read them.
        - ``forward`` returns a float (see above); an empty mask or non-finite pixel values raise
          :class:`MetricUnavailable`; an unknown ``protocol`` raises ``ValueError`` naming
          ``metrics.protocol``.
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

    def _inputs(self, generated, reference, mask, grayscale: bool, histogram_match: bool, method: str, protocol: str):
        """The LPIPS inputs ``(1, 3, H, W)`` in [-1, 1] of ``protocol`` and the bool mask ``(H, W)``."""
        check_protocol(protocol)
        if protocol == "authors":
            grayscale, histogram_match = False, False
        g, r, m = _prepare_pair(generated, reference, mask, grayscale)
        if not (np.isfinite(g).all() and np.isfinite(r).all()):
            raise MetricUnavailable(NON_FINITE_REASON)
        if histogram_match and m.any():
            g = g.copy()
            for c in range(g.shape[-1]):
                g[..., c][m] = _match_values(g[..., c][m], r[..., c][m], method)
        if protocol == "authors":
            g, r = g * m[..., None], r * m[..., None]
        device = next(self.model.parameters()).device

        def to_tensor(a: np.ndarray) -> torch.Tensor:
            t = hwc_to_bchw(a)
            if t.shape[1] == 1:
                t = t.expand(-1, 3, -1, -1)
            return (t * 2.0 - 1.0).to(device)

        return to_tensor(g), to_tensor(r), m

    @torch.no_grad()
    def spatial_map(
        self,
        generated,
        reference,
        mask,
        *,
        grayscale: bool = True,
        histogram_match: bool = True,
        method: str = "cdf",
        protocol: str = "paper",
    ) -> torch.Tensor:
        """The spatial LPIPS map ``(H, W)`` of the pair preprocessed as ``protocol`` does.

        Convention:
            ``paper``: the mask drives the histogram matching; ``authors``: the map of the masked RGB
            images (its mean is close to, not exactly, the ``authors`` value of :meth:`forward`).
        """
        g, r, _ = self._inputs(generated, reference, mask, grayscale, histogram_match, method, protocol)
        return self.model(g, r)[0, 0].cpu()

    def _whole_image(self, g: torch.Tensor, r: torch.Tensor) -> float:
        """``lpips.LPIPS`` with ``spatial=False``: each layer's map averaged over the whole image."""
        spatial = self.model.spatial
        self.model.spatial = False
        try:
            return float(self.model(g, r).reshape(()).double())
        finally:
            self.model.spatial = spatial

    @torch.no_grad()
    def forward(
        self,
        generated,
        reference,
        mask,
        *,
        grayscale: bool = True,
        histogram_match: bool = True,
        method: str = "cdf",
        protocol: str = "paper",
    ) -> float:
        """LPIPS of the pair under ``protocol`` (see the class); :class:`MetricUnavailable` for an empty mask."""
        g, r, m = self._inputs(generated, reference, mask, grayscale, histogram_match, method, protocol)
        if not m.any():
            raise MetricUnavailable(EMPTY_MASK_REASON)
        if protocol == "authors":
            return self._whole_image(g, r)
        lp = self.model(g, r)[0, 0].cpu().to(torch.float64)
        return float(lp[torch.from_numpy(m)].mean())
