"""Baselines through diffusers: other text-to-image models and FLUX Fill inpainting.

Convention:
    - Images: ``(1, 3, H, W)`` float32 sRGB in [0, 1] on the CPU, in and out; the pipelines see
      8-bit PIL images.
    - Weights come from a local folder or the Hugging Face cache only (``local_files_only``); they
      are never downloaded. A missing model raises :class:`WeightsNotFoundError` naming the config
      key ``method.model_id``.
    - Device: CUDA by default (:class:`DeviceNotAvailableError` when there is none); ``device="cpu"``
      runs on the CPU, explicitly only. Precision: bfloat16 on CUDA and float32 elsewhere, unless
      ``dtype`` is given.
    - Randomness: a ``torch.Generator`` on the pipeline's device seeded with ``seed``.
"""

from __future__ import annotations

import numpy as np
import torch

from snell_bench.models.devices import default_dtype, dtype_kwarg, parse_dtype, resolve_device
from snell_bench.models.errors import WeightsNotFoundError
from snell_bench.utils.tensors import bchw_to_hwc, hwc_to_bchw

__all__ = ["generate_external", "inpaint_external"]


def _load(pipeline_cls, model_id: str, device: str | torch.device | None, dtype: torch.dtype | str | None):
    """``pipeline_cls.from_pretrained(model_id)`` from local files, on ``device`` in ``dtype``."""
    dev = resolve_device(
        device,
        unavailable=(
            f"{model_id} needs a CUDA GPU and none is available on this machine (model.device); "
            "pass device='cpu' to run it on the CPU anyway (float32, slow)"
        ),
    )
    dt = parse_dtype(dtype) or default_dtype(dev)
    try:
        pipe = pipeline_cls.from_pretrained(model_id, local_files_only=True, **dtype_kwarg(dt))
    except (OSError, ValueError) as e:
        raise WeightsNotFoundError(
            f"weights of {model_id} not found locally ({e}); set method.model_id to a local folder with the diffusers "
            "layout, or download the model into the Hugging Face cache on a machine with internet"
        ) from e
    return pipe.to(dev)


def _to_tensor(pil) -> torch.Tensor:
    return hwc_to_bchw(np.asarray(pil.convert("RGB"), np.float32) / 255.0)


def _generator(pipe, seed: int) -> torch.Generator:
    return torch.Generator(pipe.device).manual_seed(int(seed))


def generate_external(
    model_id: str,
    prompt: str,
    size: tuple[int, int],
    *,
    seed: int = 0,
    steps: int = 20,
    device: str | torch.device | None = None,
    dtype: torch.dtype | str | None = None,
) -> torch.Tensor:
    """Text-to-image with any diffusers pipeline ``AutoPipelineForText2Image`` can load.

    Args:
        model_id: a local diffusers folder or a Hugging Face id in the local cache
            (config key ``method.model_id``).
        prompt: the text prompt.
        size: the image size ``(H, W)``.
        seed: seeds the pipeline's generator.
        steps: the number of inference steps.
        device: ``None`` (CUDA, which must be available), ``"cuda[:i]"`` or ``"cpu"``.
        dtype: a dtype or its name (:func:`~snell_bench.models.devices.parse_dtype`); ``None``:
            bfloat16 on CUDA, float32 otherwise.

    Returns:
        The image ``(1, 3, H, W)``, float32 in [0, 1], on the CPU.

    Raises:
        WeightsNotFoundError: if the model is not available locally.
        DeviceNotAvailableError: if CUDA is needed and missing.
    """
    from diffusers import AutoPipelineForText2Image

    pipe = _load(AutoPipelineForText2Image, model_id, device, dtype)
    H, W = size
    out = pipe(prompt=prompt, height=H, width=W, num_inference_steps=steps, generator=_generator(pipe, seed)).images[0]
    return _to_tensor(out)


def inpaint_external(
    model_id: str,
    prompt: str,
    i_minus: torch.Tensor,
    mask: np.ndarray,
    *,
    seed: int = 0,
    steps: int = 20,
    device: str | torch.device | None = None,
    dtype: torch.dtype | str | None = None,
) -> torch.Tensor:
    """FLUX Fill: repaint the object region of I⁻ from the full prompt.

    Args:
        model_id: a local ``FluxFillPipeline`` folder or a Hugging Face id in the local cache
            (config key ``method.model_id``).
        prompt: the full prompt (scene and object).
        i_minus: the object-free image ``(1, 3, H, W)`` in [0, 1]; ``H`` and ``W`` multiples of 16.
        mask: boolean ``(H, W)``, the region to repaint.
        seed: seeds the pipeline's generator.
        steps: the number of inference steps.
        device: ``None`` (CUDA, which must be available), ``"cuda[:i]"`` or ``"cpu"``.
        dtype: a dtype or its name; ``None``: bfloat16 on CUDA, float32 otherwise.

    Returns:
        The image ``(1, 3, H, W)``, float32 in [0, 1], on the CPU.

    Raises:
        WeightsNotFoundError: if the model is not available locally.
        DeviceNotAvailableError: if CUDA is needed and missing.
    """
    from diffusers import FluxFillPipeline
    from PIL import Image

    pipe = _load(FluxFillPipeline, model_id, device, dtype)
    H, W = i_minus.shape[-2:]
    img = Image.fromarray((bchw_to_hwc(i_minus) * 255).round().astype(np.uint8))
    m = Image.fromarray((np.asarray(mask) * 255).astype(np.uint8))
    out = pipe(
        prompt=prompt,
        image=img,
        mask_image=m,
        height=H,
        width=W,
        num_inference_steps=steps,
        generator=_generator(pipe, seed),
    ).images[0]
    return _to_tensor(out)
