"""The interface every monocular depth estimator implements, and the helpers the backends share.

Convention:
    - Input: ``(H, W, 3)`` float sRGB in [0, 1] (any size: each model's image processor resizes it, and
      the depth comes back at ``(H, W)``).
    - Output: :class:`DepthEstimate` with ``depth`` ``(H, W)`` float32, the camera-frame z coordinate
      (not the ray length) in metres at pixel centres, NaN where the model marks a pixel invalid or
      gives a non-finite or non-positive value; ``intrinsics`` ``(fx, fy, cx, cy)`` in pixels of the
      input image with *integer pixel centres* (the convention of :mod:`snell_bench.scene.camera`: the
      centre of a ``W``-wide image is ``cx = (W - 1) / 2``), or ``None`` when the model does not
      estimate them.
    - Weights are read from a local folder or the Hugging Face cache only, never downloaded; missing
      weights raise :class:`~snell_bench.models.errors.WeightsNotFoundError` with the message of
      :func:`weights_help`, naming the config key ``depth.path``.
    - Device: ``"cpu"`` (default; ``None`` is the same), ``"cuda[:i]"`` (must be available:
      :class:`~snell_bench.models.errors.DeviceNotAvailableError` naming ``depth.device``) or ``"auto"``
      (CUDA when available, else the CPU): :func:`resolve_depth_device`.
    - Depth edges (config key ``depth.edge_rtol``): :func:`depth_edge_mask` marks the pixels at a
      depth discontinuity, which an estimator with ``edge_rtol`` set turns into missing depth (NaN).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import torch
from scipy import ndimage

from .devices import resolve_device

__all__ = [
    "DEPTH_ANYTHING_V2_METRIC_INDOOR_ID",
    "DEPTH_PRO_ID",
    "HF_REPO_ID",
    "MOGE2_ID",
    "DepthEstimate",
    "DepthEstimator",
    "check_image",
    "cut_depth_edges",
    "depth_edge_mask",
    "resolve_depth_device",
    "valid_depth",
    "weights_help",
]

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


def depth_edge_mask(depth: np.ndarray, rtol: float, kernel_size: int = 3) -> np.ndarray:
    """The pixels at a depth discontinuity: MoGe's rule (utils3d's depth-map edge with a relative
    tolerance, as MoGe's export and the authors' ``utils/moge2_infer.py`` apply it).

    Convention:
        ``depth`` is an ``(H, W)`` z-depth; NaN, inf and values <= 0 are missing. A valid pixel is an
        edge when the spread of depth over its ``kernel_size`` x ``kernel_size`` neighbourhood (cut
        at the image border), ``max - min``, is more than ``rtol`` times its own depth. A missing
        neighbour counts as infinitely far (MoGe marks missing depth ``inf``), so every valid pixel
        next to a missing one is an edge. Missing pixels are never edges (they are out already).
        For a step from ``z1`` to ``z2 > z1`` the near side is cut when ``(z2 - z1) / z1 > rtol``,
        the far side only when ``(z2 - z1) / z2 > rtol``; a plane seen at a grazing angle is cut
        where the depth changes by more than ``rtol / 2`` of itself per pixel.

    Args:
        depth: ``(H, W)`` z-depth.
        rtol: the relative tolerance, > 0 (the authors: 0.1).
        kernel_size: the side of the neighbourhood, odd.

    Returns:
        bool ``(H, W)``, ``True`` on an edge.

    Raises:
        ValueError: for a depth that is not 2-D, ``rtol`` not > 0 or an even ``kernel_size``.
    """
    d = np.asarray(depth, np.float64)
    if d.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {d.shape}")
    if not (rtol > 0 and np.isfinite(rtol)):
        raise ValueError(f"depth.edge_rtol must be a number > 0 (e.g. 0.1) or null (no cut), got {rtol}")
    if kernel_size < 1 or kernel_size % 2 == 0:
        raise ValueError(f"kernel_size must be odd and >= 1, got {kernel_size}")
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(d) & (d > 0)
    far = np.where(valid, d, np.inf)
    # mode="nearest" repeats border values: the max and min over the window cut at the border
    hi = ndimage.maximum_filter(far, size=kernel_size, mode="nearest")
    lo = ndimage.minimum_filter(far, size=kernel_size, mode="nearest")
    with np.errstate(invalid="ignore"):
        spread = hi - lo  # inf next to a missing pixel
        return valid & (spread / np.where(valid, d, 1.0) > rtol)


def cut_depth_edges(depth: np.ndarray, rtol: float | None) -> np.ndarray:
    """float32 ``depth`` with NaN on the pixels :func:`depth_edge_mask` marks (``rtol=None``: as is)."""
    out = np.array(depth, dtype=np.float32)
    if rtol is not None:
        out[depth_edge_mask(out, float(rtol))] = np.nan
    return out


def weights_help(what: str, *, example: str, layout: str) -> str:
    """The message of a :class:`WeightsNotFoundError`: what is missing and how to set ``depth.path``."""
    return (
        f"depth estimator weights not found: {what}. Set the config key depth.path to a local folder with {layout}, "
        f"e.g. `depth.path=/data/{example.split('/')[-1]}`, or to a Hugging Face id already in the local cache "
        f"(e.g. `depth.path={example}`). To populate the Hugging Face cache, on a machine with internet run "
        f"`hf download {example}` and copy the cache (~/.cache/huggingface/hub, or $HF_HOME/hub) to this machine, "
        f"or point depth.path at the downloaded snapshot folder. Weights are never downloaded by snell_bench."
    )
