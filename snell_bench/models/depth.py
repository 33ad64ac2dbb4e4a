"""Monocular depth estimators behind one small interface: metric z-depth (and, where the model
estimates them, the intrinsics) from one sRGB image.

Backends:
    - :class:`TransformersDepth` (:mod:`snell_bench.models.transformers_depth`): transformers'
      ``DepthProForDepthEstimation`` (Depth Pro: metric depth and the horizontal field of view, e.g.
      ``apple/DepthPro-hf``) and ``DepthAnythingForDepthEstimation`` (Depth Anything V2, metric
      checkpoints only, e.g. ``depth-anything/Depth-Anything-V2-Metric-Indoor-Large-hf``).
    - :class:`MoGe2Depth` (:mod:`snell_bench.models.moge`): MoGe-2 (``moge.model.v2.MoGeModel`` from the
      optional ``dlr-moge`` package, e.g. ``Ruicheng/moge-2-vitl-normal``): metric depth, a validity mask
      and the intrinsics.
    - :func:`tiny_depth_pro` / :func:`tiny_depth_anything` (:mod:`snell_bench.models.tiny_depth`): the two
      transformers architectures at toy size with random weights, built from configs in code (CPU tests;
      their outputs mean nothing).

The interface (:class:`DepthEstimator`, :class:`DepthEstimate`) and the helpers the backends share
are in :mod:`snell_bench.models.depth_base`; this module gathers every backend under one name, the
one the ``depth`` config group's ``_target_`` entries use.

Convention:
    - Input and output as :mod:`snell_bench.models.depth_base` states them (``(H, W, 3)`` sRGB in;
      camera-frame z in metres, NaN where invalid, and intrinsics with integer pixel centres out);
      Depth Anything estimates no intrinsics.
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

from .depth_base import (
    DEPTH_ANYTHING_V2_METRIC_INDOOR_ID,
    DEPTH_PRO_ID,
    MOGE2_ID,
    DepthEstimate,
    DepthEstimator,
    resolve_depth_device,
)
from .moge import MoGe2Depth
from .tiny_depth import tiny_depth_anything, tiny_depth_pro
from .transformers_depth import TransformersDepth

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
