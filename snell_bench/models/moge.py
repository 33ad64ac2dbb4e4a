"""MoGe-2 behind :class:`~snell_bench.models.depth_base.DepthEstimator`: metric depth, a validity mask
and the intrinsics from one image.

Convention (see :mod:`snell_bench.models.depth_base` for the shared ones):
    - ``moge.model.v2.MoGeModel`` from the optional ``dlr-moge`` package (extra ``depth``), imported
      only when an estimator is built; e.g. ``Ruicheng/moge-2-vitl-normal``.
    - ``infer`` gives normalised intrinsics (image edges at 0 and 1, the centre of pixel ``i`` at
      ``(i + 0.5) / W``): ``fx = W fx_n``, ``fy = H fy_n``, ``cx = W cx_n - 0.5``, ``cy = H cy_n - 0.5``;
      pixels outside its mask (``inf`` depth) are NaN.
    - ``edge_rtol`` (config key ``depth.edge_rtol``; ``None``: off, the default): pixels at depth
      edges (:func:`~snell_bench.models.depth_base.depth_edge_mask`, evaluated with MoGe's mask) are
      NaN too, as the authors' ``utils/moge2_infer.py`` cuts its mesh (``--threshold 0.1``).
    - The checkpoint ``model.pt`` is read from a local file, a folder or the Hugging Face cache only,
      never downloaded; missing weights raise :class:`~snell_bench.models.errors.WeightsNotFoundError`
      naming the config key ``depth.path``.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .depth_base import (
    HF_REPO_ID,
    MOGE2_ID,
    DepthEstimate,
    check_image,
    cut_depth_edges,
    resolve_depth_device,
    valid_depth,
    weights_help,
)
from .errors import WeightsNotFoundError

__all__ = ["MoGe2Depth", "moge_checkpoint"]

_MOGE_CHECKPOINT = "model.pt"
_MOGE_EXTRA_HELP = 'pip install "snell_bench[depth]" (or make setup EXTRAS=test,depth)'


def _import_moge_model() -> Any:
    try:
        from moge.model.v2 import MoGeModel
    except ImportError as err:
        raise ImportError(
            f"MoGe-2 needs the optional dependency dlr-moge (module moge.model.v2), which is not installed "
            f"({err}); install the optional extra depth: {_MOGE_EXTRA_HELP}"
        ) from err
    return MoGeModel


def moge_checkpoint(path: str | os.PathLike | None) -> str:
    """The local ``model.pt`` of a MoGe checkpoint given as a file, a folder or a cached hub id."""
    layout = f"the MoGe checkpoint file {_MOGE_CHECKPOINT}"
    if path is None:
        raise WeightsNotFoundError(weights_help("depth.path is not set", example=MOGE2_ID, layout=layout))
    text = os.fspath(path)
    local = Path(text).expanduser()
    if local.is_file():
        return str(local)
    if local.is_dir():
        if (local / _MOGE_CHECKPOINT).is_file():
            return str(local / _MOGE_CHECKPOINT)
        raise WeightsNotFoundError(
            weights_help(f"the folder {text!r} has no {_MOGE_CHECKPOINT}", example=MOGE2_ID, layout=layout)
        )
    if not HF_REPO_ID.match(text):
        raise WeightsNotFoundError(weights_help(f"no file or folder {text!r}", example=MOGE2_ID, layout=layout))
    from huggingface_hub import hf_hub_download

    try:
        return hf_hub_download(repo_id=text, filename=_MOGE_CHECKPOINT, repo_type="model", local_files_only=True)
    except Exception as err:  # LocalEntryNotFoundError, HFValidationError, OSError, ...
        raise WeightsNotFoundError(
            weights_help(
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
        edge_rtol: cut depth edges at this relative tolerance (:func:`cut_depth_edges`);
            ``None``: keep every pixel MoGe's mask keeps.
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
        edge_rtol: float | None = None,
    ):
        if edge_rtol is not None and not (float(edge_rtol) > 0 and np.isfinite(float(edge_rtol))):
            raise ValueError(f"depth.edge_rtol must be a number > 0 (the authors: 0.1) or null, got {edge_rtol}")
        self.edge_rtol = None if edge_rtol is None else float(edge_rtol)
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
        edge_rtol: float | None = None,
    ) -> MoGe2Depth:
        """Load a MoGe-2 checkpoint from local files.

        Args:
            path: the checkpoint ``model.pt``, a folder holding it, or a Hugging Face id whose
                ``model.pt`` is in the local cache (config key ``depth.path``).
            device: see :func:`resolve_depth_device` (config key ``depth.device``).
            resolution_level: see :class:`MoGe2Depth`.
            num_tokens: see :class:`MoGe2Depth`.
            use_fp16: see :class:`MoGe2Depth`.
            edge_rtol: see :class:`MoGe2Depth` (config key ``depth.edge_rtol``).

        Returns:
            The estimator.

        Raises:
            ImportError: when ``dlr-moge`` is not installed (naming the optional extra ``depth``).
            WeightsNotFoundError: naming ``depth.path``, when the checkpoint is not on this machine.
            DeviceNotAvailableError: when CUDA is asked for and missing.
        """
        MoGeModel = _import_moge_model()
        checkpoint = moge_checkpoint(path)
        dev = resolve_depth_device(device)
        try:
            model = MoGeModel.from_pretrained(checkpoint)
        except (OSError, RuntimeError, KeyError) as err:
            raise WeightsNotFoundError(
                weights_help(
                    f"loading {checkpoint!r} failed ({err})", example=MOGE2_ID, layout=f"the MoGe {_MOGE_CHECKPOINT}"
                )
            ) from err
        return cls(
            model,
            device=dev,
            resolution_level=resolution_level,
            num_tokens=num_tokens,
            use_fp16=use_fp16,
            edge_rtol=edge_rtol,
        )

    @torch.no_grad()
    def __call__(self, image: np.ndarray) -> DepthEstimate:
        """Estimate the metric depth and intrinsics of ``image``.

        Args:
            image: ``(H, W, 3)`` float sRGB in [0, 1], any size.

        Returns:
            The estimate at ``(H, W)``, with intrinsics.
        """
        img = check_image(image)
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
        return DepthEstimate(depth=cut_depth_edges(valid_depth(depth), self.edge_rtol), intrinsics=intrinsics)
