"""Monocular depth estimators behind one small interface: metric z-depth (and, where the model
estimates them, the intrinsics) from one sRGB image.

Backends:
    - :class:`TransformersDepth`: transformers' ``DepthProForDepthEstimation`` (Depth Pro: metric depth
      and the horizontal field of view, e.g. ``apple/DepthPro-hf``) and ``DepthAnythingForDepthEstimation``
      (Depth Anything V2, metric checkpoints only, e.g. ``depth-anything/Depth-Anything-V2-Metric-Indoor-Large-hf``).
    - :class:`MoGe2Depth`: MoGe-2 (``moge.model.v2.MoGeModel`` from the optional ``dlr-moge`` package,
      e.g. ``Ruicheng/moge-2-vitl-normal``): metric depth, a validity mask and the intrinsics.
    - :func:`tiny_depth_pro` / :func:`tiny_depth_anything`: the two transformers architectures at toy
      size with random weights, built from configs in code (CPU tests; their outputs mean nothing).

Convention:
    - Input: ``(H, W, 3)`` float sRGB in [0, 1] (any size: each model's image processor resizes it, and
      the depth comes back at ``(H, W)``).
    - Output: :class:`DepthEstimate` with ``depth`` ``(H, W)`` float32, the camera-frame z coordinate
      (not the ray length) in metres at pixel centres, NaN where the model marks a pixel invalid or
      gives a non-finite or non-positive value; ``intrinsics`` ``(fx, fy, cx, cy)`` in pixels of the
      input image with *integer pixel centres* (the convention of :mod:`snell_bench.scene.camera`: the
      centre of a ``W``-wide image is ``cx = (W - 1) / 2``), or ``None`` when the model does not
      estimate them (Depth Anything).
    - Depth Pro: depth and focal length come from transformers'
      ``DepthProImageProcessor.post_process_depth_estimation``: ``f = 0.5 W / tan(fov / 2)`` from the
      predicted horizontal field of view (degrees), ``depth = f / (W * canonical_inverse_depth)``
      resized bilinearly (in inverse depth) to the input size and clamped to [1e-4, 1e4] m;
      intrinsics ``(f, f, (W - 1) / 2, (H - 1) / 2)`` (square pixels, centred principal point).
    - Depth Anything V2: ``predicted_depth`` is metres only for ``depth_estimation_type="metric"``
      checkpoints (sigmoid times ``max_depth``); relative checkpoints (relative inverse depth) are refused.
      The processor's ``post_process_depth_estimation`` resizes bicubically to the input size.
    - MoGe-2: ``infer`` gives normalised intrinsics (image edges at 0 and 1, the centre of pixel ``i``
      at ``(i + 0.5) / W``): ``fx = W fx_n``, ``fy = H fy_n``, ``cx = W cx_n - 0.5``, ``cy = H cy_n - 0.5``;
      pixels outside its mask (``inf`` depth) are NaN.
    - Weights are read from a local folder or the Hugging Face cache only (``local_files_only=True``),
      never downloaded; missing weights raise :class:`~snell_bench.models.errors.WeightsNotFoundError`
      naming the config key ``depth.path``.
    - Device: ``"cpu"`` (default; ``None`` is the same), ``"cuda[:i]"`` (must be available:
      :class:`~snell_bench.models.errors.DeviceNotAvailableError` naming ``depth.device``) or ``"auto"``
      (CUDA when available, else the CPU). Models are in eval mode; every call runs under
      :func:`torch.no_grad`.
    - transformers and moge are imported only when an estimator is built.
"""

from __future__ import annotations

import logging
import math
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
import torch

from .devices import parse_dtype, resolve_device
from .errors import WeightsNotFoundError

__all__ = [
    "DEPTH_ANYTHING_V2_METRIC_INDOOR_ID",
    "DEPTH_PRO_ID",
    "MOGE2_ID",
    "DepthEstimate",
    "DepthEstimator",
    "MoGe2Depth",
    "TransformersDepth",
    "resolve_depth_device",
    "tiny_depth_anything",
    "tiny_depth_pro",
]

log = logging.getLogger(__name__)

#: Hugging Face ids of the real checkpoints (config key ``depth.path``).
DEPTH_PRO_ID = "apple/DepthPro-hf"
DEPTH_ANYTHING_V2_METRIC_INDOOR_ID = "depth-anything/Depth-Anything-V2-Metric-Indoor-Large-hf"
MOGE2_ID = "Ruicheng/moge-2-vitl-normal"

_REPO_ID = re.compile(r"^[A-Za-z0-9][\w.-]*/[\w.-]+$")
_MOGE_CHECKPOINT = "model.pt"
_MOGE_EXTRA_HELP = 'pip install "snell_bench[depth]" (or make setup EXTRAS=test,depth)'


# ---------------------------------------------------------------------------------------- interface


@dataclass
class DepthEstimate:
    """The output of a :class:`DepthEstimator`.

    Attributes:
        depth: ``(H, W)`` float32 metric z-depth in metres at pixel centres; NaN where invalid.
        intrinsics: ``(fx, fy, cx, cy)`` in pixels of the input image (integer pixel centres), or
            ``None`` when the model does not estimate them.
    """

    depth: np.ndarray
    intrinsics: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        depth = np.asarray(self.depth)
        if depth.ndim != 2:
            raise ValueError(f"DepthEstimate.depth must be (H, W), got shape {depth.shape}")
        self.depth = depth.astype(np.float32, copy=False)
        if self.intrinsics is not None:
            vals = tuple(float(v) for v in self.intrinsics)
            if len(vals) != 4:
                raise ValueError(f"DepthEstimate.intrinsics must be (fx, fy, cx, cy), got {self.intrinsics!r}")
            self.intrinsics = vals  # type: ignore[assignment]

    def camera(self):
        """The pinhole :class:`~snell_bench.scene.camera.Camera` of the intrinsics at the depth's size.

        Returns:
            The camera, or ``None`` when there are no intrinsics.
        """
        if self.intrinsics is None:
            return None
        from snell_bench.scene.camera import Camera

        fx, fy, cx, cy = self.intrinsics
        H, W = self.depth.shape
        return Camera(K=np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), width=W, height=H)


@runtime_checkable
class DepthEstimator(Protocol):
    """Metric depth (and possibly intrinsics) from one image.

    Attributes:
        name: a short identifier (``depth_pro``, ``depth_anything_v2``, ``moge2``, ``tiny_depth_pro``, ...).
    """

    name: str

    def __call__(self, image: np.ndarray) -> DepthEstimate:
        """Estimate the depth of ``image``.

        Args:
            image: ``(H, W, 3)`` float32 sRGB in [0, 1].

        Returns:
            The estimate at the input size ``(H, W)``.
        """
        ...


# ---------------------------------------------------------------------------------------- helpers


def resolve_depth_device(device: str | torch.device | None) -> torch.device:
    """The device a depth estimator runs on.

    Args:
        device: ``None`` or ``"cpu"`` (the CPU), ``"auto"`` (CUDA when available, else the CPU),
            ``"cuda[:i]"`` (must be available) or any torch device (config key ``depth.device``).

    Returns:
        The device.

    Raises:
        DeviceNotAvailableError: if CUDA is asked for explicitly and missing.

    Examples:
        >>> resolve_depth_device(None), resolve_depth_device("cpu")
        (device(type='cpu'), device(type='cpu'))
    """
    if device is None:
        return torch.device("cpu")
    if str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return resolve_device(
        device,
        unavailable=f"depth.device={device!s} needs CUDA and none is available on this machine; set depth.device=cpu",
    )


def _check_image(image: np.ndarray) -> np.ndarray:
    """``image`` as a C-contiguous float32 ``(H, W, 3)`` array clipped to [0, 1]."""
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"the image must be (H, W, 3) sRGB, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.floating):
        raise TypeError(f"the image must be float sRGB in [0, 1], got dtype {arr.dtype}")
    if min(arr.shape[:2]) < 2:
        raise ValueError(f"the image must be at least 2 x 2 pixels, got {arr.shape[0]} x {arr.shape[1]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("the image has non-finite values")
    return np.ascontiguousarray(np.clip(arr, 0.0, 1.0), dtype=np.float32)


def _valid_depth(depth: np.ndarray) -> np.ndarray:
    """float32 depth with NaN where it is non-finite or not positive."""
    depth = np.asarray(depth, dtype=np.float32).copy()
    with np.errstate(invalid="ignore"):
        depth[~(np.isfinite(depth) & (depth > 0))] = np.nan
    return depth


def _weights_help(what: str, *, example: str, layout: str) -> str:
    return (
        f"depth estimator weights not found: {what}. Set the config key depth.path to a local folder with {layout}, "
        f"e.g. `depth.path=/data/{example.split('/')[-1]}`, or to a Hugging Face id already in the local cache "
        f"(e.g. `depth.path={example}`). To populate the Hugging Face cache, on a machine with internet run "
        f"`hf download {example}` and copy the cache (~/.cache/huggingface/hub, or $HF_HOME/hub) to this machine, "
        f"or point depth.path at the downloaded snapshot folder. Weights are never downloaded by snell_bench."
    )


#: model type -> the estimator's default name (transformers' metric Depth Anything checkpoints are V2).
_DEFAULT_NAMES = {"depth_pro": "depth_pro", "depth_anything": "depth_anything_v2"}

_HF_LAYOUT = "the Hugging Face layout (config.json, model.safetensors, preprocessor_config.json)"


# ---------------------------------------------------------------------------------------- transformers


class TransformersDepth:
    """Depth Pro or metric Depth Anything V2 through transformers.

    Convention:
        - ``model.config.model_type`` is ``depth_pro`` (with its field-of-view head: without it the depth
          is not metric) or ``depth_anything`` with ``depth_estimation_type == "metric"``.
        - The image goes to the processor as a float tensor in [0, 1] (``do_rescale=False``); the processor
          resizes and normalises it; ``post_process_depth_estimation`` brings the depth back to ``(H, W)``.
        - Depth Pro gives intrinsics ``(f, f, (W - 1) / 2, (H - 1) / 2)`` with
          ``f = 0.5 W / tan(fov / 2)``; a predicted field of view outside (0, 180) degrees gives an
          all-NaN depth and no intrinsics (with a warning). Depth Anything gives no intrinsics.
        - The model runs in ``dtype`` (default float32); the post-processing runs in float32.

    Args:
        model: a ``DepthProForDepthEstimation`` or ``DepthAnythingForDepthEstimation``.
        processor: its image processor (``DepthProImageProcessor`` / ``DPTImageProcessor``).
        device: see :func:`resolve_depth_device`.
        dtype: a dtype or its name (:func:`~snell_bench.models.devices.parse_dtype`); ``None``: float32.
        name: the estimator's name; default ``depth_pro`` / ``depth_anything_v2``.

    Raises:
        ValueError: for another architecture, a Depth Pro without its field-of-view head, or a relative
            Depth Anything.
    """

    def __init__(
        self,
        model: Any,
        processor: Any,
        *,
        device: str | torch.device | None = "cpu",
        dtype: torch.dtype | str | None = None,
        name: str | None = None,
    ):
        self.kind = _check_transformers_config(model.config, source=type(model).__name__)
        if self.kind == "depth_pro" and getattr(model, "fov_model", None) is None:
            raise ValueError(
                "this Depth Pro model has no field-of-view head (use_fov_model=False): its depth is not metric; "
                f"use a checkpoint with use_fov_model=true, e.g. depth.path={DEPTH_PRO_ID}"
            )
        self.device = resolve_depth_device(device)
        self.dtype = parse_dtype(dtype) or torch.float32
        self.model = model.to(device=self.device, dtype=self.dtype).eval().requires_grad_(False)
        self.processor = processor
        self.name = name or _DEFAULT_NAMES[self.kind]

    @classmethod
    def from_pretrained(
        cls,
        path: str | os.PathLike | None = DEPTH_PRO_ID,
        *,
        device: str | torch.device | None = "cpu",
        dtype: torch.dtype | str | None = None,
        name: str | None = None,
    ) -> TransformersDepth:
        """Load a Depth Pro or metric Depth Anything V2 checkpoint from local files.

        The config is read first: an unsupported architecture or a relative Depth Anything is refused
        before any weight is loaded.

        Args:
            path: a local folder or a Hugging Face id in the local cache (config key ``depth.path``).
            device: see :func:`resolve_depth_device` (config key ``depth.device``).
            dtype: the weights' dtype; ``None``: float32.
            name: the estimator's name; default ``depth_pro`` / ``depth_anything_v2``.

        Returns:
            The estimator.

        Raises:
            WeightsNotFoundError: naming ``depth.path``, when the config, weights or image processor
                are not on this machine.
            ValueError: for an unsupported architecture or a relative Depth Anything checkpoint.
            DeviceNotAvailableError: when CUDA is asked for and missing.
        """
        from transformers import (
            AutoConfig,
            AutoImageProcessor,
            DepthAnythingForDepthEstimation,
            DepthProForDepthEstimation,
        )

        if path is None:
            raise WeightsNotFoundError(_weights_help("depth.path is not set", example=DEPTH_PRO_ID, layout=_HF_LAYOUT))
        text = os.fspath(path)
        example = DEPTH_ANYTHING_V2_METRIC_INDOOR_ID if "depth-anything" in text.lower() else DEPTH_PRO_ID
        local = Path(text).expanduser()
        if not local.is_dir() and not _REPO_ID.match(text):
            raise WeightsNotFoundError(_weights_help(f"no folder {text!r}", example=example, layout=_HF_LAYOUT))
        source = str(local) if local.is_dir() else text
        try:
            config = AutoConfig.from_pretrained(source, local_files_only=True)
        except (OSError, ValueError) as err:
            raise WeightsNotFoundError(
                _weights_help(
                    f"the config of {text!r} is not available locally ({err})", example=example, layout=_HF_LAYOUT
                )
            ) from err
        kind = _check_transformers_config(config, source=f"depth.path={text}")
        model_cls = DepthProForDepthEstimation if kind == "depth_pro" else DepthAnythingForDepthEstimation
        if kind == "depth_anything":
            example = DEPTH_ANYTHING_V2_METRIC_INDOOR_ID
        dev = resolve_depth_device(device)
        dt = parse_dtype(dtype) or torch.float32
        try:
            model = model_cls.from_pretrained(source, local_files_only=True, dtype=dt)
            processor = AutoImageProcessor.from_pretrained(source, local_files_only=True)
        except OSError as err:
            raise WeightsNotFoundError(
                _weights_help(f"loading {text!r} failed ({err})", example=example, layout=_HF_LAYOUT)
            ) from err
        return cls(model, processor, device=dev, dtype=dt, name=name)

    @torch.no_grad()
    def __call__(self, image: np.ndarray) -> DepthEstimate:
        """Estimate the metric depth of ``image``.

        Args:
            image: ``(H, W, 3)`` float sRGB in [0, 1], any size.

        Returns:
            The estimate at ``(H, W)``: Depth Pro with intrinsics, Depth Anything without.
        """
        img = _check_image(image)
        H, W = img.shape[:2]
        chw = torch.from_numpy(img).permute(2, 0, 1)
        inputs = self.processor(images=chw, return_tensors="pt", do_rescale=False)
        pixel_values = inputs["pixel_values"].to(device=self.device, dtype=self.dtype)
        outputs = self.model(pixel_values=pixel_values)
        outputs["predicted_depth"] = outputs.predicted_depth.float()
        if self.kind == "depth_pro":
            return self._depth_pro(outputs, H, W)
        result = self.processor.post_process_depth_estimation(outputs, target_sizes=[(H, W)])[0]
        depth = result["predicted_depth"].reshape(H, W).cpu().numpy()
        return DepthEstimate(depth=_valid_depth(depth), intrinsics=None)

    def _depth_pro(self, outputs: Any, H: int, W: int) -> DepthEstimate:
        fov = outputs.field_of_view.float()
        outputs["field_of_view"] = fov
        fov_deg = float(fov.reshape(-1)[0])
        if not (math.isfinite(fov_deg) and 0.0 < fov_deg < 180.0):
            log.warning(
                "%s predicted a field of view of %r degrees: no metric depth for this image", self.name, fov_deg
            )
            return DepthEstimate(depth=np.full((H, W), np.nan, np.float32), intrinsics=None)
        result = self.processor.post_process_depth_estimation(outputs, target_sizes=[(H, W)])[0]
        f = float(result["focal_length"])
        depth = result["predicted_depth"].reshape(H, W).cpu().numpy()
        return DepthEstimate(depth=_valid_depth(depth), intrinsics=(f, f, (W - 1) / 2.0, (H - 1) / 2.0))


def _check_transformers_config(config: Any, *, source: str) -> str:
    """``"depth_pro"`` or ``"depth_anything"``; refuses other architectures and relative Depth Anything."""
    kind = getattr(config, "model_type", None)
    if kind == "depth_pro":
        return kind
    if kind == "depth_anything":
        est = getattr(config, "depth_estimation_type", "relative")
        if est != "metric":
            raise ValueError(
                f"{source}: this Depth Anything checkpoint has depth_estimation_type={est!r}: it predicts relative "
                "inverse depth, not metres. Use a metric checkpoint (depth_estimation_type='metric'), e.g. "
                f"depth.path={DEPTH_ANYTHING_V2_METRIC_INDOOR_ID} (indoor, max 20 m) or "
                "depth-anything/Depth-Anything-V2-Metric-Outdoor-Large-hf (outdoor, max 80 m)"
            )
        return kind
    raise ValueError(
        f"{source}: model type {kind!r} is not a supported depth estimator; supported: depth_pro "
        f"(e.g. {DEPTH_PRO_ID}) and metric depth_anything (e.g. {DEPTH_ANYTHING_V2_METRIC_INDOOR_ID})"
    )


# ---------------------------------------------------------------------------------------- MoGe-2


def _import_moge_model() -> Any:
    try:
        from moge.model.v2 import MoGeModel
    except ImportError as err:
        raise ImportError(
            f"MoGe-2 needs the optional dependency dlr-moge (module moge.model.v2), which is not installed "
            f"({err}); install the optional extra depth: {_MOGE_EXTRA_HELP}"
        ) from err
    return MoGeModel


def _moge_checkpoint(path: str | os.PathLike | None) -> str:
    """The local ``model.pt`` of a MoGe checkpoint given as a file, a folder or a cached hub id."""
    layout = f"the MoGe checkpoint file {_MOGE_CHECKPOINT}"
    if path is None:
        raise WeightsNotFoundError(_weights_help("depth.path is not set", example=MOGE2_ID, layout=layout))
    text = os.fspath(path)
    local = Path(text).expanduser()
    if local.is_file():
        return str(local)
    if local.is_dir():
        if (local / _MOGE_CHECKPOINT).is_file():
            return str(local / _MOGE_CHECKPOINT)
        raise WeightsNotFoundError(
            _weights_help(f"the folder {text!r} has no {_MOGE_CHECKPOINT}", example=MOGE2_ID, layout=layout)
        )
    if not _REPO_ID.match(text):
        raise WeightsNotFoundError(_weights_help(f"no file or folder {text!r}", example=MOGE2_ID, layout=layout))
    from huggingface_hub import hf_hub_download

    try:
        return hf_hub_download(repo_id=text, filename=_MOGE_CHECKPOINT, repo_type="model", local_files_only=True)
    except Exception as err:  # LocalEntryNotFoundError, HFValidationError, OSError, ...
        raise WeightsNotFoundError(
            _weights_help(
                f"{text!r} is not in the Hugging Face cache ({type(err).__name__})", example=MOGE2_ID, layout=layout
            )
        ) from err


class MoGe2Depth:
    """MoGe-2 (``moge.model.v2.MoGeModel``): metric depth, a validity mask and the intrinsics.

    Convention:
        - ``infer`` gets the image as a ``(3, H, W)`` float32 tensor in [0, 1] on the model's device and
          returns ``depth`` ``(H, W)`` (``inf`` outside ``mask``), ``mask`` ``(H, W)`` bool and
          normalised ``intrinsics`` ``(3, 3)``; the depth is NaN outside the mask or where it is
          non-finite or not positive.
        - Intrinsics: ``fx = W K[0, 0]``, ``fy = H K[1, 1]``, ``cx = W K[0, 2] - 0.5``,
          ``cy = H K[1, 2] - 0.5`` (MoGe's normalised coordinates put the centre of pixel ``i`` at
          ``(i + 0.5) / W``; here pixel centres are integers).
        - fp16 autocast (``use_fp16``) only on CUDA by default.

    Args:
        model: a ``MoGeModel`` (or anything with its ``infer``).
        device: see :func:`resolve_depth_device`.
        resolution_level: MoGe's ``resolution_level`` (0-9: more ViT tokens, finer detail, slower).
        num_tokens: MoGe's ``num_tokens`` (overrides ``resolution_level``); ``None``: from the level.
        use_fp16: mixed precision; ``None``: on CUDA only.
    """

    name = "moge2"

    def __init__(
        self,
        model: Any,
        *,
        device: str | torch.device | None = "cpu",
        resolution_level: int = 9,
        num_tokens: int | None = None,
        use_fp16: bool | None = None,
    ):
        self.device = resolve_depth_device(device)
        self.model = model.to(self.device).eval()
        self.resolution_level = int(resolution_level)
        self.num_tokens = None if num_tokens is None else int(num_tokens)
        self.use_fp16 = (self.device.type == "cuda") if use_fp16 is None else bool(use_fp16)

    @classmethod
    def from_pretrained(
        cls,
        path: str | os.PathLike | None = MOGE2_ID,
        *,
        device: str | torch.device | None = "cpu",
        resolution_level: int = 9,
        num_tokens: int | None = None,
        use_fp16: bool | None = None,
    ) -> MoGe2Depth:
        """Load a MoGe-2 checkpoint from local files.

        Args:
            path: the checkpoint ``model.pt``, a folder holding it, or a Hugging Face id whose
                ``model.pt`` is in the local cache (config key ``depth.path``).
            device: see :func:`resolve_depth_device` (config key ``depth.device``).
            resolution_level: see :class:`MoGe2Depth`.
            num_tokens: see :class:`MoGe2Depth`.
            use_fp16: see :class:`MoGe2Depth`.

        Returns:
            The estimator.

        Raises:
            ImportError: when ``dlr-moge`` is not installed (naming the optional extra ``depth``).
            WeightsNotFoundError: naming ``depth.path``, when the checkpoint is not on this machine.
            DeviceNotAvailableError: when CUDA is asked for and missing.
        """
        MoGeModel = _import_moge_model()
        checkpoint = _moge_checkpoint(path)
        dev = resolve_depth_device(device)
        try:
            model = MoGeModel.from_pretrained(checkpoint)
        except (OSError, RuntimeError, KeyError) as err:
            raise WeightsNotFoundError(
                _weights_help(
                    f"loading {checkpoint!r} failed ({err})", example=MOGE2_ID, layout=f"the MoGe {_MOGE_CHECKPOINT}"
                )
            ) from err
        return cls(model, device=dev, resolution_level=resolution_level, num_tokens=num_tokens, use_fp16=use_fp16)

    @torch.no_grad()
    def __call__(self, image: np.ndarray) -> DepthEstimate:
        """Estimate the metric depth and intrinsics of ``image``.

        Args:
            image: ``(H, W, 3)`` float sRGB in [0, 1], any size.

        Returns:
            The estimate at ``(H, W)``, with intrinsics.
        """
        img = _check_image(image)
        H, W = img.shape[:2]
        chw = torch.from_numpy(img).permute(2, 0, 1).contiguous().to(self.device)
        with warnings.catch_warnings():
            # infer's float32 post-processing opens a CPU autocast region, which torch declines with a warning
            warnings.filterwarnings("ignore", message="In CPU autocast, but the target dtype is not supported")
            out = self.model.infer(
                chw, num_tokens=self.num_tokens, resolution_level=self.resolution_level, use_fp16=self.use_fp16
            )
        depth = out["depth"].float().cpu().numpy().reshape(H, W)
        mask = out.get("mask")
        if mask is not None:
            depth = np.where(mask.cpu().numpy().reshape(H, W).astype(bool), depth, np.nan)
        K = out["intrinsics"].double().cpu().numpy().reshape(3, 3)
        intrinsics = (W * K[0, 0], H * K[1, 1], W * K[0, 2] - 0.5, H * K[1, 2] - 0.5)
        return DepthEstimate(depth=_valid_depth(depth), intrinsics=intrinsics)


# ---------------------------------------------------------------------------------------- tiny models


def _calibrate_affine(layer: torch.nn.Module, stats: torch.Tensor, *, mean: float, std: float | None) -> None:
    """Rescale ``layer``'s weight and shift its bias so its output ``stats`` get ``mean`` (and ``std``)."""
    scale = 1.0 if std is None else std / max(float(stats.std()), 1e-12)
    with torch.no_grad():
        layer.weight.mul_(scale)
        layer.bias.copy_(scale * (layer.bias - float(stats.mean())) + mean)


def _reference_pixels(processor: Any, height: int, width: int) -> torch.Tensor:
    """A fixed smooth-plus-noise test image through ``processor`` (the calibration input)."""
    g = torch.Generator().manual_seed(1234)
    yy, xx = torch.meshgrid(torch.linspace(0, 1, height), torch.linspace(0, 1, width), indexing="ij")
    img = torch.stack([xx, yy, 0.5 + 0.3 * torch.sin(7 * xx) * torch.cos(5 * yy)])
    img = (0.7 * img + 0.3 * torch.rand(3, height, width, generator=g)).clamp(0, 1)
    return processor(images=img, return_tensors="pt", do_rescale=False)["pixel_values"]


def _tiny_dinov2(num_layers: int, patch_size: int, **kwargs: Any) -> dict:
    return dict(
        model_type="dinov2",
        num_hidden_layers=num_layers,
        hidden_size=16,
        num_attention_heads=2,
        intermediate_size=32,
        patch_size=patch_size,
        **kwargs,
    )


def tiny_depth_pro(seed: int = 0, *, device: str | torch.device | None = "cpu") -> TransformersDepth:
    """Depth Pro's architecture at toy size with random weights (CPU tests; its depth means nothing).

    Convention:
        - ``DepthProConfig``: patch size 16, scaled images (0.25, 0.5, 1) with overlaps (0, 0.5, 0.25)
          and feature dims (16, 16, 8), one intermediate hook (layer 1, dim 8), fusion width 16, merge
          padding 1, the field-of-view head (1 head layer); the image, patch and FoV encoders are
          DINOv2 ViTs (width 16, 2 heads, MLP 32, patch 8; 2, 2 and 1 layers).
        - ``DepthProImageProcessor`` at 64 x 64 (= patch size / smallest ratio; the real one: 1536);
          the predicted canonical inverse depth is 64 x 64.
        - Built from ``torch.manual_seed(seed)`` in a forked RNG (the caller's RNG is untouched), then
          the depth head's last convolution and the FoV head's last convolution are rescaled/shifted so
          that a fixed reference image gives a canonical inverse depth of 0.3 +- 0.06 (about 3 m at
          60 degrees) and a field of view of 60 degrees: other images give plausible, image-dependent
          values. Deterministic for the seed; eval mode.

    Args:
        seed: seeds the random weights.
        device: see :func:`resolve_depth_device`.

    Returns:
        A :class:`TransformersDepth` named ``tiny_depth_pro``.
    """
    from transformers import DepthProConfig, DepthProForDepthEstimation, DepthProImageProcessor

    config = DepthProConfig(
        patch_size=16,
        fusion_hidden_size=16,
        intermediate_hook_ids=[1],
        intermediate_feature_dims=[8],
        scaled_images_ratios=[0.25, 0.5, 1.0],
        scaled_images_overlap_ratios=[0.0, 0.5, 0.25],
        scaled_images_feature_dims=[16, 16, 8],
        merge_padding_value=1,
        use_fov_model=True,
        num_fov_head_layers=1,
        image_model_config=_tiny_dinov2(2, 8),
        patch_model_config=_tiny_dinov2(2, 8),
        fov_model_config=_tiny_dinov2(1, 8),
    )
    processor = DepthProImageProcessor(size={"height": 64, "width": 64})
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = DepthProForDepthEstimation(config).eval()
    depth_layer, fov_layer = model.head.layers[-2], model.fov_model.head.layers[-1]
    seen: dict[str, torch.Tensor] = {}
    hooks = [
        depth_layer.register_forward_hook(lambda m, i, o: seen.__setitem__("depth", o.detach())),
        fov_layer.register_forward_hook(lambda m, i, o: seen.__setitem__("fov", o.detach())),
    ]
    with torch.no_grad():
        model(pixel_values=_reference_pixels(processor, 64, 96))
    for h in hooks:
        h.remove()
    _calibrate_affine(depth_layer, seen["depth"], mean=0.3, std=0.06)
    _calibrate_affine(fov_layer, seen["fov"], mean=60.0, std=None)
    return TransformersDepth(model, processor, device=device, name="tiny_depth_pro")


def tiny_depth_anything(seed: int = 0, *, device: str | torch.device | None = "cpu") -> TransformersDepth:
    """Metric Depth Anything V2's architecture at toy size with random weights (CPU tests).

    Convention:
        - ``DepthAnythingConfig``: ``depth_estimation_type="metric"``, ``max_depth=20`` (the indoor
          checkpoints' value), patch 14, reassemble width 16, neck (8, 8, 16, 16), fusion 8, head 8; the
          backbone is a DINOv2 (4 layers, width 16, 2 heads, MLP 32, patch 14, features of layers 1-4).
        - ``DPTImageProcessor`` as the real checkpoints' (keep the aspect ratio, multiple of 14, bicubic,
          ImageNet mean / std) at 56 x 56 instead of 518 x 518.
        - Built from ``torch.manual_seed(seed)`` in a forked RNG; the neck and head convolutions use
          PyTorch's default initialisation (transformers' small normal one makes their output vanish),
          and the head's last convolution is rescaled/shifted so that a fixed reference image gives
          depths of about 3 m (pre-sigmoid logit(3 / 20) +- 0.3). Deterministic for the seed; eval mode.

    Args:
        seed: seeds the random weights.
        device: see :func:`resolve_depth_device`.

    Returns:
        A :class:`TransformersDepth` named ``tiny_depth_anything``.
    """
    from transformers import DepthAnythingConfig, DepthAnythingForDepthEstimation, Dinov2Config, DPTImageProcessor

    backbone = Dinov2Config(
        **{k: v for k, v in _tiny_dinov2(4, 14).items() if k != "model_type"},
        image_size=56,
        out_indices=[1, 2, 3, 4],
        reshape_hidden_states=False,
        apply_layernorm=True,
    )
    max_depth = 20
    config = DepthAnythingConfig(
        backbone_config=backbone,
        patch_size=14,
        reassemble_hidden_size=16,
        reassemble_factors=[4, 2, 1, 0.5],
        neck_hidden_sizes=[8, 8, 16, 16],
        fusion_hidden_size=8,
        head_hidden_size=8,
        depth_estimation_type="metric",
        max_depth=max_depth,
    )
    processor = DPTImageProcessor(
        size={"height": 56, "width": 56},
        keep_aspect_ratio=True,
        ensure_multiple_of=14,
        resample=3,  # bicubic
        image_mean=[0.485, 0.456, 0.406],
        image_std=[0.229, 0.224, 0.225],
        do_pad=False,
    )
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = DepthAnythingForDepthEstimation(config).eval()
        for module in (*model.neck.modules(), *model.head.modules()):
            if isinstance(module, (torch.nn.Conv2d, torch.nn.ConvTranspose2d, torch.nn.Linear)):
                module.reset_parameters()
    layer = model.head.conv3
    seen: dict[str, torch.Tensor] = {}
    hook = layer.register_forward_hook(lambda m, i, o: seen.__setitem__("logit", o.detach()))
    with torch.no_grad():
        model(pixel_values=_reference_pixels(processor, 64, 96))
    hook.remove()
    _calibrate_affine(layer, seen["logit"], mean=math.log(3.0 / (max_depth - 3.0)), std=0.3)
    return TransformersDepth(model, processor, device=device, name="tiny_depth_anything")
