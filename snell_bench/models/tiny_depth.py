"""Depth Pro and metric Depth Anything V2 at toy size with random weights, built from configs in code
(CPU tests; their outputs mean nothing): the transformers code paths of
:class:`~snell_bench.models.transformers_depth.TransformersDepth` without any checkpoint.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from .depth_base import DepthEstimate
from .transformers_depth import TransformersDepth

__all__ = ["TinyDepthWithFloor", "floor_depth", "tiny_depth_anything", "tiny_depth_pro"]


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


def floor_depth(height: int, width: int, intrinsics, floor_m: float) -> np.ndarray:
    """The z-depth of a level floor ``floor_m`` metres below the camera (the plane ``y = floor_m`` of
    the OpenCV camera frame, y down), ``(height, width)`` float32 at integer pixel centres: the ray
    through row ``v`` meets it at ``z = floor_m fy / (v - cy)``; ``inf`` on and above the horizon
    (``v <= cy``)."""
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    dv = np.arange(height, dtype=np.float64) - cy
    z = np.full(height, np.inf)
    below = dv > 0
    z[below] = float(floor_m) * fy / dv[below]
    return np.repeat(z[:, None], width, axis=1).astype(np.float32)


class TinyDepthWithFloor(TransformersDepth):
    """A tiny random depth network in front of which a level floor stands (CPU stand-in).

    A random network's depth has no supporting surface, so nothing could be placed on it: this
    stand-in keeps the network's code path and output and puts a level floor ``floor_m`` below the
    camera (:func:`floor_depth` with the network's own intrinsics), the nearer of the two per
    pixel. Its depth means nothing beyond that floor; the object stands on it (a level camera:
    ``scene.up`` ``[0, -1, 0]``).
    """

    def __init__(self, *args: Any, floor_m: float, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if not (math.isfinite(float(floor_m)) and float(floor_m) > 0):
            raise ValueError(f"floor_m={floor_m!r}: the floor's distance below the camera in metres must be > 0")
        self.floor_m = float(floor_m)

    def __call__(self, image: np.ndarray) -> DepthEstimate:
        est = super().__call__(image)
        if est.intrinsics is None:
            return est
        H, W = est.depth.shape
        floor = floor_depth(H, W, est.intrinsics, self.floor_m)
        return DepthEstimate(depth=np.fmin(est.depth, floor), intrinsics=est.intrinsics)


def tiny_depth_pro(
    seed: int = 0, *, device: str | torch.device | None = "cpu", floor_m: float | None = None
) -> TransformersDepth:
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
        floor_m: a level floor this many metres below the camera in front of the network's depth
            (:class:`TinyDepthWithFloor`: a surface to place the object on); ``None``: the
            network's depth alone.

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
    if floor_m is not None:
        return TinyDepthWithFloor(model, processor, device=device, name="tiny_depth_pro", floor_m=floor_m)
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
