"""Baselines through diffusers on a GPU: other text-to-image models and FLUX Fill inpainting.

Convention: images ``(1, 3, H, W)`` float32 sRGB in [0, 1] on the CPU. Weights come from a local
folder or the Hugging Face cache only (``local_files_only``); they are never downloaded.
"""

from __future__ import annotations

import numpy as np
import torch

from snell_bench.models.errors import DeviceNotAvailableError, WeightsNotFoundError

__all__ = ["generate_external", "inpaint_external"]


def _load(pipeline_cls, model_id: str):
    if not torch.cuda.is_available():
        raise DeviceNotAvailableError(f"{model_id} needs a CUDA GPU; none is available (model.device)")
    try:
        pipe = pipeline_cls.from_pretrained(model_id, torch_dtype=torch.bfloat16, local_files_only=True)
    except (OSError, ValueError) as e:
        raise WeightsNotFoundError(
            f"weights of {model_id} not found locally ({e}); set method.model_id to a local folder with the diffusers "
            "layout, or download the model into the Hugging Face cache on a machine with internet"
        ) from e
    return pipe.to("cuda")


def _to_tensor(pil) -> torch.Tensor:
    return torch.from_numpy(np.asarray(pil.convert("RGB"), np.float32) / 255.0).permute(2, 0, 1)[None]


def generate_external(model_id: str, prompt: str, size: tuple[int, int], *, seed: int = 0, steps: int = 20) -> torch.Tensor:
    """Text-to-image with any diffusers pipeline ``AutoPipelineForText2Image`` can load."""
    from diffusers import AutoPipelineForText2Image

    pipe = _load(AutoPipelineForText2Image, model_id)
    H, W = size
    g = torch.Generator("cuda").manual_seed(int(seed))
    out = pipe(prompt=prompt, height=H, width=W, num_inference_steps=steps, generator=g).images[0]
    return _to_tensor(out)


def inpaint_external(model_id: str, prompt: str, i_minus: torch.Tensor, mask: np.ndarray, *, seed: int = 0,
                     steps: int = 20) -> torch.Tensor:
    """FLUX Fill: repaint the object region of I⁻ from the full prompt."""
    from diffusers import FluxFillPipeline
    from PIL import Image

    pipe = _load(FluxFillPipeline, model_id)
    H, W = i_minus.shape[-2:]
    img = Image.fromarray((i_minus[0].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8))
    m = Image.fromarray((np.asarray(mask) * 255).astype(np.uint8))
    g = torch.Generator("cuda").manual_seed(int(seed))
    out = pipe(prompt=prompt, image=img, mask_image=m, height=H, width=W, num_inference_steps=steps, generator=g).images[0]
    return _to_tensor(out)
