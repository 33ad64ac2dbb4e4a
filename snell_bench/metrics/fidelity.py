"""Masked fidelity metrics as objects: batch accumulators of masked PSNR and MAE, and masked LPIPS,
under the paper's evaluation protocol or the authors' released one. The functional forms and the
shared conventions (images, masks, grayscale, histogram matching, protocols, results) are those of
:mod:`snell_bench.metrics.functional`.

Convention:
    - Batches: :class:`MaskedPSNR` and :class:`MaskedMAE` take images ``(B, 3, H, W)`` with masks
      ``(B, 1, H, W)`` (or one mask for the whole batch) in ``update``, score each image with the
      functional form and ``compute`` the mean over the images with a value; images without one
      (empty mask, non-finite pixels) are counted in ``missing`` and their reasons kept.
    - Protocol (config key ``metrics.protocol``) for LPIPS (VGG), computed by the pure functions
      :func:`masked_lpips`, :func:`authors_lpips` and :func:`authors_lpips_box` around a network
      callable (:data:`LpipsNetwork`), wrapped by :class:`MaskedLPIPS`:

      * ``"paper"`` (the paper's text says only "masked LPIPS"; snell_bench's reading, VGG as the
        authors' code uses): the spatial LPIPS map of the two RGB images as they are (full frame,
        neither masked, gray nor matched), averaged over the mask pixels.
      * ``"authors"`` (``eval/masked_metrics.py``), on the 8-bit images and mask as they read them
        (:func:`~snell_bench.metrics.functional.authors_inputs`): ``lpips``: the spatial map of the
        images multiplied by the mask (black outside it), averaged over the mask pixels;
        ``lpips_box``: the plain (non-spatial) LPIPS of the bounding-box crop of those masked images,
        in [-1, 1] (``eval/eval.py``) or mapped to [0, 1] (``eval/masked_metrics.py``; config key
        ``metrics.lpips_box_range``).

    - Every LPIPS value at a pixel also depends on the pixels of its receptive field. No gradients.
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
    authors_inputs,
    check_protocol,
    masked_mae,
    masked_psnr,
)
from snell_bench.utils.tensors import as_tensor, hwc_to_bchw

__all__ = [
    "BOX_PAPER_REASON",
    "BOX_RANGES",
    "LpipsNetwork",
    "MaskedLPIPS",
    "MaskedMAE",
    "MaskedPSNR",
    "authors_lpips",
    "authors_lpips_box",
    "check_box_range",
    "masked_lpips",
]


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


#: The network interface of the LPIPS functions: ``net(in0, in1, spatial)`` with ``in0`` the
#: generated and ``in1`` the reference input, both ``(1, 3, H, W)``; returns the spatial distance map
#: ``(1, 1, H, W)`` when ``spatial`` is True, else the plain LPIPS value (any shape with one element).
#: Inputs are passed as given (``lpips.LPIPS`` reads them as [-1, 1]; no ``normalize``).
LpipsNetwork = Callable[[torch.Tensor, torch.Tensor, bool], torch.Tensor]

#: The reason reported under ``paper`` for the authors' bounding-box LPIPS.
BOX_PAPER_REASON = "the bounding-box LPIPS is part of the authors' evaluation only (metrics.protocol=authors)"


def masked_lpips(net: LpipsNetwork, generated, reference, mask) -> float:
    """LPIPS of the paper's protocol: the spatial LPIPS map of the two RGB images averaged over the
    mask.

    The paper's text says only "masked LPIPS": it names neither the backbone, nor how the mask
    applies, nor any preprocessing (the grayscale conversion and the histogram matching are stated
    for PSNR and MAE). snell_bench reads it as the VGG backbone (the authors' code's), the full RGB
    images as they are, scaled to [-1, 1] (``2 x - 1``), and the spatial map averaged over the mask:
    the network sees the object in its context, and the mask only selects which pixels count.

    Convention:
        Images and masks as in :mod:`snell_bench.metrics.functional` (float in [0, 1], not
        quantised; one-channel images repeated to 3 channels). ``net`` as :data:`LpipsNetwork`. The
        map's mean over the mask pixels in float64. Raises :class:`MetricUnavailable` for an empty
        mask or non-finite pixel values.
    """
    g, r, m = _prepare_pair(generated, reference, mask, False)
    if not m.any():
        raise MetricUnavailable(EMPTY_MASK_REASON)
    if not (np.isfinite(g).all() and np.isfinite(r).all()):
        raise MetricUnavailable(NON_FINITE_REASON)
    lp = net(_lpips_input(g), _lpips_input(r), True)
    return float(lp.reshape(m.shape).detach().cpu().to(torch.float64)[torch.from_numpy(m)].mean())


def _lpips_input(a: np.ndarray) -> torch.Tensor:
    """``(H, W, C)`` in [0, 1] -> ``(1, 3, H, W)`` float32 in [-1, 1]."""
    t = hwc_to_bchw(a)
    if t.shape[1] == 1:
        t = t.expand(-1, 3, -1, -1)
    return t * 2.0 - 1.0


def _authors_masked_inputs(generated, reference, mask):
    """The authors' LPIPS inputs: the 8-bit images times the mask, scaled ``x 2 - 1`` (float32)."""
    g, r, valid = authors_inputs(generated, reference, mask)
    m = valid.to(g.dtype).expand_as(g)
    return (g * m) * 2.0 - 1.0, (r * m) * 2.0 - 1.0, valid


def authors_lpips(net: LpipsNetwork, generated, reference, mask) -> float:
    """The authors' ``lpips_spatial``: the spatial LPIPS map of the masked images, averaged over the
    mask.

    Steps (float32): the images and mask as the authors read their PNGs
    (:func:`~snell_bench.metrics.functional.authors_inputs`); both images multiplied by the mask
    (black outside it) and scaled ``x 2 - 1``; ``net(gen, ref, spatial=True)``; the map's mean over
    the mask pixels. Unlike :func:`masked_lpips` the network sees black around the object.

    Convention:
        As :func:`~snell_bench.metrics.functional.authors_metrics` for the inputs; ``net`` as
        :data:`LpipsNetwork`. Raises :class:`MetricUnavailable` for an empty mask or non-finite
        values.
    """
    g, r, valid = _authors_masked_inputs(generated, reference, mask)
    lp = net(g, r, True).detach().cpu()
    return float(lp.reshape(valid.shape)[valid].mean())


#: The input ranges of the authors' bounding-box LPIPS (config key ``metrics.lpips_box_range``).
BOX_RANGES = ("signed", "unit")


def check_box_range(box_range) -> str:
    """``box_range`` checked: one of :data:`BOX_RANGES`, else ``ValueError`` naming the key."""
    if box_range not in BOX_RANGES:
        raise ValueError(
            f"metrics.lpips_box_range={box_range!r} is unknown: use 'signed' (eval/eval.py, the range "
            "lpips reads) or 'unit' (eval/masked_metrics.py)"
        )
    return box_range


def authors_lpips_box(net: LpipsNetwork, generated, reference, mask, box_range: str = "signed") -> float:
    """The authors' ``lpips_non_spatial``: the plain LPIPS of the mask's bounding box.

    Steps (float32): the masked images in [-1, 1] as in :func:`authors_lpips`; the crop
    ``[y_min, y_max] x [x_min, x_max]`` (inclusive) of the mask pixels, given to
    ``net(gen, ref, spatial=False)``:

    - ``box_range="signed"`` (``eval/eval.py``, which scores the files the released pipeline
      writes): the crop in [-1, 1] as it is, the range ``lpips.LPIPS`` reads;
    - ``box_range="unit"`` (``eval/masked_metrics.py``): the crop mapped back with ``(x + 1) / 2``
      to [0, 1] and passed without ``normalize=True``, so the network reads it as [-1, 1]: half
      the contrast, centred on mid-grey instead of black.

    The value is the network's mean over the crop (black pixels of the box outside the mask
    included).

    Convention:
        As :func:`authors_lpips`. The crop must be large enough for the network (VGG: 16 pixels a
        side; :class:`MaskedLPIPS` reports a smaller box as missing). An unknown ``box_range``
        raises ``ValueError`` naming ``metrics.lpips_box_range``.
    """
    check_box_range(box_range)
    g, r, valid = _authors_masked_inputs(generated, reference, mask)
    rows = torch.nonzero(valid[0, 0].any(dim=1)).flatten()
    cols = torch.nonzero(valid[0, 0].any(dim=0)).flatten()
    y0, y1 = int(rows.min()), int(rows.max()) + 1
    x0, x1 = int(cols.min()), int(cols.max()) + 1
    g_crop, r_crop = g[:, :, y0:y1, x0:x1], r[:, :, y0:y1, x0:x1]
    if box_range == "unit":
        g_crop, r_crop = (g_crop + 1.0) / 2.0, (r_crop + 1.0) / 2.0
    return float(net(g_crop, r_crop, False).detach().cpu().reshape(()))


#: Smallest input side each backbone accepts (VGG16: four 2x2 max-pools before its last layer;
#: the others found by trying every size).
_MIN_SIDE = {"vgg": 16, "alex": 31, "squeeze": 17}


class MaskedLPIPS(torch.nn.Module):
    """LPIPS (VGG) of a masked region, under the paper's protocol or the authors'.

    - ``protocol="paper"``: :func:`masked_lpips`: the spatial LPIPS map of the two RGB images as they
      are (full frame, unmasked, not gray, not matched) averaged over the mask pixels. The options
      ``grayscale=True`` / ``histogram_match=True`` (snell_bench's, off by default) score the gray
      images, the generated one matched to the reference inside the mask, instead.
    - ``protocol="authors"``: :func:`authors_lpips` (``box=False``, their ``lpips_spatial``, reported
      as ``lpips``) or :func:`authors_lpips_box` (``box=True``, their ``lpips_non_spatial``, reported
      as ``lpips_box``), on the 8-bit images.

    Convention:
        - Backbone weights (never downloaded): ``weights_path`` (config key ``metrics.lpips_weights``),
          a torchvision state_dict file of the backbone (``vgg16-397923af.pth`` for ``net="vgg"``),
          else the same file name in the torch hub cache (``<torch.hub.get_dir()>/checkpoints``).
          Neither present: :class:`MetricUnavailable` naming ``metrics.lpips_weights``. The calibrated
          linear layers ship with the ``lpips`` package.
        - ``allow_random_backbone=True`` (with ``weights_path=None``) builds a randomly initialised
          backbone (seeded, no cache lookup) for plumbing tests only: its values are meaningless.
        - Inputs follow the module's image/mask convention. ``grayscale``, ``histogram_match`` and
          ``method`` are options of the ``paper`` protocol only, ``box`` of ``authors`` only; the other
          combinations raise ``ValueError``.
        - ``forward`` returns a float; an empty mask, non-finite pixel values or an input smaller than
          the backbone accepts raise :class:`MetricUnavailable`; an unknown ``protocol`` raises
          ``ValueError`` naming ``metrics.protocol``.
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

    @torch.no_grad()
    def network(self, in0: torch.Tensor, in1: torch.Tensor, spatial: bool) -> torch.Tensor:
        """``lpips.LPIPS(in0, in1)`` with ``spatial`` set for this call (:data:`LpipsNetwork`).

        Convention:
            Inputs ``(1, 3, H, W)`` passed as given (read as [-1, 1]), moved to the model's device;
            returns the map ``(1, 1, H, W)`` or the value ``(1, 1, 1, 1)`` on the CPU. An input side
            below what the backbone accepts raises :class:`MetricUnavailable`.
        """
        side = min(in0.shape[-2:])
        if side < _MIN_SIDE[self.net]:
            raise MetricUnavailable(
                f"LPIPS input {tuple(in0.shape[-2:])} is smaller than the {self.net} backbone accepts "
                f"({_MIN_SIDE[self.net]} pixels a side)"
            )
        device = next(self.model.parameters()).device
        previous = self.model.spatial
        self.model.spatial = spatial
        try:
            return self.model(in0.to(device), in1.to(device)).cpu()
        finally:
            self.model.spatial = previous

    def _paper_pair(self, generated, reference, mask, grayscale: bool, histogram_match: bool, method: str):
        """The ``paper`` inputs: RGB as given, or gray (and matched) with snell_bench's options."""
        if not (grayscale or histogram_match):
            return generated, reference
        g, r, m = _prepare_pair(generated, reference, mask, grayscale)
        if not (np.isfinite(g).all() and np.isfinite(r).all()):
            raise MetricUnavailable(NON_FINITE_REASON)
        if histogram_match and m.any():
            g = g.copy()
            for c in range(g.shape[-1]):
                g[..., c][m] = _match_values(g[..., c][m], r[..., c][m], method)
        return g, r

    @staticmethod
    def _check_options(protocol: str, grayscale: bool, histogram_match: bool, method: str, box: bool) -> str:
        protocol = check_protocol(protocol)
        if protocol == "authors" and (grayscale or histogram_match or method != "cdf"):
            raise ValueError(
                "grayscale, histogram_match and method are options of metrics.protocol='paper'; the "
                "authors' LPIPS scores the masked RGB images: leave them at their defaults"
            )
        if protocol == "paper" and box:
            raise ValueError(f"box=True: {BOX_PAPER_REASON}")
        return protocol

    @torch.no_grad()
    def spatial_map(
        self,
        generated,
        reference,
        mask,
        *,
        grayscale: bool = False,
        histogram_match: bool = False,
        method: str = "cdf",
        protocol: str = "paper",
    ) -> torch.Tensor:
        """The spatial LPIPS map ``(H, W)`` whose mean over the mask is :meth:`forward`'s value.

        Convention:
            ``paper``: the map of the (preprocessed) full images; ``authors``: the map of the masked
            8-bit images.
        """
        recorded: list[torch.Tensor] = []

        def keep(in0, in1, spatial):
            out = self.network(in0, in1, spatial)
            recorded.append(out)
            return out

        self.forward(
            generated,
            reference,
            mask,
            grayscale=grayscale,
            histogram_match=histogram_match,
            method=method,
            protocol=protocol,
            _network=keep,
        )
        return recorded[0][0, 0]

    @torch.no_grad()
    def forward(
        self,
        generated,
        reference,
        mask,
        *,
        grayscale: bool = False,
        histogram_match: bool = False,
        method: str = "cdf",
        protocol: str = "paper",
        box: bool = False,
        box_range: str = "signed",
        _network: LpipsNetwork | None = None,
    ) -> float:
        """LPIPS of the pair under ``protocol`` (see the class); ``box`` selects the authors'
        bounding-box LPIPS, ``box_range`` its input range (:func:`authors_lpips_box`)."""
        protocol = self._check_options(protocol, grayscale, histogram_match, method, box)
        net = self.network if _network is None else _network
        if protocol == "authors":
            if box:
                return authors_lpips_box(net, generated, reference, mask, box_range)
            return authors_lpips(net, generated, reference, mask)
        g, r = self._paper_pair(generated, reference, mask, grayscale, histogram_match, method)
        return masked_lpips(net, g, r, mask)
