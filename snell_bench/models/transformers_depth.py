"""Depth Pro and metric Depth Anything V2 through transformers behind
:class:`~snell_bench.models.depth_base.DepthEstimator`.

Convention (see :mod:`snell_bench.models.depth_base` for the shared ones):
    - Depth Pro (``DepthProForDepthEstimation``, e.g. ``apple/DepthPro-hf``): depth and focal length
      come from transformers' ``DepthProImageProcessor.post_process_depth_estimation``:
      ``f = 0.5 W / tan(fov / 2)`` from the predicted horizontal field of view (degrees),
      ``depth = f / (W * canonical_inverse_depth)`` resized bilinearly (in inverse depth) to the input
      size and clamped to [1e-4, 1e4] m; intrinsics ``(f, f, (W - 1) / 2, (H - 1) / 2)`` (square
      pixels, centred principal point).
    - Depth Anything V2 (``DepthAnythingForDepthEstimation``, e.g.
      ``depth-anything/Depth-Anything-V2-Metric-Indoor-Large-hf``): ``predicted_depth`` is metres only
      for ``depth_estimation_type="metric"`` checkpoints (sigmoid times ``max_depth``); relative
      checkpoints (relative inverse depth) are refused. The processor's
      ``post_process_depth_estimation`` resizes bicubically to the input size. No intrinsics.
    - Weights: ``local_files_only=True``. Models are in eval mode; every call runs under
      :func:`torch.no_grad`.
    - transformers is imported only when an estimator is loaded.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .depth_base import (
    DEPTH_ANYTHING_V2_METRIC_INDOOR_ID,
    DEPTH_PRO_ID,
    HF_REPO_ID,
    DepthEstimate,
    check_image,
    resolve_depth_device,
    valid_depth,
    weights_help,
)
from .devices import parse_dtype
from .errors import WeightsNotFoundError

__all__ = ["TransformersDepth"]

log = logging.getLogger(__name__)

#: model type -> the estimator's default name (transformers' metric Depth Anything checkpoints are V2).
_DEFAULT_NAMES = {"depth_pro": "depth_pro", "depth_anything": "depth_anything_v2"}

_HF_LAYOUT = "the Hugging Face layout (config.json, model.safetensors, preprocessor_config.json)"


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
