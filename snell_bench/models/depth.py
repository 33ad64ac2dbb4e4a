"""Monocular depth estimators behind one small interface: metric z-depth (and, where the model
estimates them, the intrinsics) from one sRGB image.

Backends:
    - :class:`TransformersDepth`: transformers' ``DepthProForDepthEstimation`` (Depth Pro: metric depth
      and the horizontal field of view, e.g. ``apple/DepthPro-hf``) and ``DepthAnythingForDepthEstimation``
      (Depth Anything V2, metric checkpoints only, e.g. ``depth-anything/Depth-Anything-V2-Metric-Indoor-Large-hf``).
    - :class:`MoGe2Depth` (:mod:`snell_bench.models.moge`): MoGe-2 (``moge.model.v2.MoGeModel`` from the
      optional ``dlr-moge`` package, e.g. ``Ruicheng/moge-2-vitl-normal``): metric depth, a validity mask
      and the intrinsics.
    - :func:`tiny_depth_pro` / :func:`tiny_depth_anything` (:mod:`snell_bench.models.tiny_depth`): the two
      transformers architectures at toy size with random weights, built from configs in code (CPU tests;
      their outputs mean nothing).

The interface and the shared helpers are here; :class:`MoGe2Depth`, :func:`tiny_depth_pro` and
:func:`tiny_depth_anything` are re-exported from their modules (imported on first use).

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

import importlib
import logging
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np
import torch

from .devices import parse_dtype, resolve_device
from .errors import WeightsNotFoundError

if TYPE_CHECKING:
    from .moge import MoGe2Depth
    from .tiny_depth import tiny_depth_anything, tiny_depth_pro

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

#: A Hugging Face model id (``owner/name``), as opposed to a local path.
HF_REPO_ID = re.compile(r"^[A-Za-z0-9][\w.-]*/[\w.-]+$")


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


def check_image(image: np.ndarray) -> np.ndarray:
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


def valid_depth(depth: np.ndarray) -> np.ndarray:
    """float32 depth with NaN where it is non-finite or not positive."""
    depth = np.asarray(depth, dtype=np.float32).copy()
    with np.errstate(invalid="ignore"):
        depth[~(np.isfinite(depth) & (depth > 0))] = np.nan
    return depth


def weights_help(what: str, *, example: str, layout: str) -> str:
    """The message of a :class:`WeightsNotFoundError`: what is missing and how to set ``depth.path``."""
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
            raise WeightsNotFoundError(weights_help("depth.path is not set", example=DEPTH_PRO_ID, layout=_HF_LAYOUT))
        text = os.fspath(path)
        example = DEPTH_ANYTHING_V2_METRIC_INDOOR_ID if "depth-anything" in text.lower() else DEPTH_PRO_ID
        local = Path(text).expanduser()
        if not local.is_dir() and not HF_REPO_ID.match(text):
            raise WeightsNotFoundError(weights_help(f"no folder {text!r}", example=example, layout=_HF_LAYOUT))
        source = str(local) if local.is_dir() else text
        try:
            config = AutoConfig.from_pretrained(source, local_files_only=True)
        except (OSError, ValueError) as err:
            raise WeightsNotFoundError(
                weights_help(
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
                weights_help(f"loading {text!r} failed ({err})", example=example, layout=_HF_LAYOUT)
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
        img = check_image(image)
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
        return DepthEstimate(depth=valid_depth(depth), intrinsics=None)

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
        return DepthEstimate(depth=valid_depth(depth), intrinsics=(f, f, (W - 1) / 2.0, (H - 1) / 2.0))


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


# ---------------------------------------------------------------------------------------- re-exports

#: name -> the module (relative to this package) that defines it.
_REEXPORTS = {"MoGe2Depth": ".moge", "tiny_depth_pro": ".tiny_depth", "tiny_depth_anything": ".tiny_depth"}


def __getattr__(name: str) -> Any:
    """:class:`MoGe2Depth`, :func:`tiny_depth_pro` and :func:`tiny_depth_anything`, imported on first use
    (their modules import this one)."""
    if name in _REEXPORTS:
        return getattr(importlib.import_module(_REEXPORTS[name], __package__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
