"""FLUX (diffusers) as a :class:`~snell_bench.models.base.Generator`: VAE, text conditioning and the
transformer's velocity, with the sampling loop left to the caller.

Convention
----------
- Images: float32 ``(B, 3, H, W)`` in [0, 1], ``H`` and ``W`` multiples of 16. The VAE sees
  ``2 x - 1``; latents are normalised as in FLUX: ``z = (mean_or_sample - shift) * scale``
  (FLUX.1-dev: shift 0.1159, scale 0.3611), and ``decode`` inverts it and clamps to [0, 1].
- Latents: unpacked ``(B, 16, H/8, W/8)``. The transformer sees them packed into 2x2 patches,
  ``(B, (h/2)(w/2), 64)`` (diffusers' ``FluxPipeline._pack_latents``), with image position ids
  ``(row, col)`` of the patch grid (``_prepare_latent_image_ids``); :meth:`FluxGenerator.velocity`
  packs and unpacks internally.
- Flow matching: ``z_sigma = (1 - sigma) x0 + sigma eps`` and the transformer predicts
  ``v = eps - x0``. The transformer's ``timestep`` input is ``sigma`` itself (``FluxPipeline`` passes
  ``t / 1000`` with ``t = 1000 sigma``; the model multiplies by 1000 inside).
- Guidance: FLUX.1-dev is guidance-distilled: the guidance scale (default 3.5) is an input of the
  transformer (a ``(B,)`` tensor), not classifier-free guidance; one model call per velocity.
- Precision and placement: the model runs in bfloat16 on CUDA and float32 on the CPU (unless
  ``dtype`` is given). Outputs come back on the input's device: ``encode`` / ``decode`` give
  float32, ``velocity`` gives ``z``'s dtype. A :class:`Condition` lives on the model's device.
- Every call runs under :func:`torch.no_grad`; every module is in eval mode.
- Randomness: only ``encode(..., generator=g)`` draws (the VAE posterior sample); everything else
  is deterministic.
"""

from __future__ import annotations

import logging
import os
import re
from pathlib import Path
from typing import Any, Sequence

import torch

from .base import Condition, LatentGeometry
from .errors import DeviceNotAvailableError, WeightsNotFoundError

__all__ = ["FLUX_DEV_ID", "FluxGenerator", "resolve_device", "resolve_weights_folder"]

log = logging.getLogger(__name__)

#: The Hugging Face id of FLUX.1-dev (gated: the licence must be accepted on the hub).
FLUX_DEV_ID = "black-forest-labs/FLUX.1-dev"
#: Sub-folders of a diffusers FLUX layout.
FLUX_COMPONENTS = ("scheduler", "text_encoder", "text_encoder_2", "tokenizer", "tokenizer_2", "transformer", "vae")
VIEWS = ("main", "pano")

_REPO_ID = re.compile(r"^[A-Za-z0-9][\w.-]*/[\w.-]+$")


def _weights_help(what: str) -> str:
    return (
        f"FLUX weights not found: {what}. Set the config key model.path to a local folder with the "
        f"FLUX.1-dev diffusers layout (model_index.json and {', '.join(c + '/' for c in FLUX_COMPONENTS)}), "
        f"e.g. `model.path=/data/FLUX.1-dev`, or to a Hugging Face id already in the local cache. "
        f"To populate the Hugging Face cache, on a machine with internet: accept the licence at "
        f"https://huggingface.co/{FLUX_DEV_ID}, run `hf auth login`, then "
        f"`hf download {FLUX_DEV_ID} --exclude 'flux1-dev.safetensors' 'ae.safetensors'` "
        f"(the diffusers folders only, ~34 GB), and copy the cache (~/.cache/huggingface/hub, or "
        f"$HF_HOME/hub) to this machine, or point model.path at the downloaded snapshot folder. "
        f"Weights are never downloaded by snell_bench."
    )


def resolve_weights_folder(model_id_or_path: str | os.PathLike, *, local_files_only: bool = True, revision: str | None = None) -> str:
    """The local folder of a diffusers FLUX pipeline, from a folder path or a Hugging Face id.

    Convention
    ----------
    - An existing folder must contain ``model_index.json``.
    - A hub id (``owner/name``, not an existing path) is looked up in the Hugging Face cache only
      (``HF_HOME`` / ``HF_HUB_CACHE`` are honoured); with ``local_files_only=False`` the id is
      returned unchanged and diffusers may download it.
    - Anything else raises :class:`WeightsNotFoundError` naming the config key ``model.path``.
    """
    text = os.fspath(model_id_or_path)
    path = Path(text).expanduser()
    if path.is_dir():
        if not (path / "model_index.json").is_file():
            raise WeightsNotFoundError(_weights_help(f"the folder {str(path)!r} has no model_index.json"))
        return str(path)
    if path.exists():
        raise WeightsNotFoundError(_weights_help(f"{str(path)!r} is a file, not a diffusers folder"))
    if not _REPO_ID.match(text):
        raise WeightsNotFoundError(_weights_help(f"no folder {text!r}"))
    if not local_files_only:
        return text
    from huggingface_hub import snapshot_download

    try:
        folder = snapshot_download(repo_id=text, revision=revision, local_files_only=True)
    except Exception as err:  # LocalEntryNotFoundError, HFValidationError, OSError, ...
        raise WeightsNotFoundError(_weights_help(f"{text!r} is not in the Hugging Face cache ({type(err).__name__})")) from err
    if not (Path(folder) / "model_index.json").is_file():
        raise WeightsNotFoundError(_weights_help(f"the cached snapshot {folder!r} has no model_index.json"))
    return folder


def resolve_device(device: str | torch.device | None) -> torch.device:
    """``None`` / ``"auto"`` / ``"cuda[:i]"`` need a CUDA device; ``"cpu"`` forces the CPU.

    Raises :class:`DeviceNotAvailableError` naming the config key ``model.device`` when CUDA is
    asked for (explicitly or by default) and missing."""
    if device is None or str(device) == "auto":
        device = "cuda"
    dev = torch.device(device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise DeviceNotAvailableError(
            "FLUX.1-dev needs a CUDA GPU (its weights are ~34 GB in bfloat16) and none is available on this "
            "machine. Run on a machine with a GPU, or set the config key model.device=cpu to run it on the CPU "
            "anyway (float32, ~70 GB of RAM, minutes per model call). The tests use the tiny random model "
            "(model=tiny_flux) instead."
        )
    return dev


def _default_dtype(device: torch.device) -> torch.dtype:
    return torch.bfloat16 if device.type == "cuda" else torch.float32


_DTYPE_ALIASES = {"bf16": "bfloat16", "fp16": "float16", "half": "float16", "fp32": "float32", "float": "float32"}


def _as_dtype(dtype: torch.dtype | str | None) -> torch.dtype | None:
    """``None``, a ``torch.dtype`` or its name (``"bfloat16"``, ``"bf16"``, ``"torch.float32"``, ...)."""
    if dtype is None or isinstance(dtype, torch.dtype):
        return dtype
    name = str(dtype).removeprefix("torch.")
    value = getattr(torch, _DTYPE_ALIASES.get(name, name), None)
    if not isinstance(value, torch.dtype):
        raise ValueError(f"unknown dtype {dtype!r} (config key model.dtype): use bfloat16, float16 or float32")
    return value


def _dtype_kwarg(dtype: torch.dtype) -> dict:
    """diffusers >= 0.42 takes ``dtype=`` (``torch_dtype=`` is deprecated there); older ones only
    ``torch_dtype=``."""
    try:
        from diffusers.utils.deprecation_utils import _resolve_dtype  # noqa: F401
    except ImportError:
        return {"torch_dtype": dtype}
    return {"dtype": dtype}


def _flux_pipeline_cls():
    from diffusers import FluxPipeline

    return FluxPipeline


class FluxGenerator:
    """A FLUX pipeline's components behind the :class:`~snell_bench.models.base.Generator` protocol.

    Build with :meth:`from_pretrained` (FLUX.1-dev weights from a local folder or the Hugging Face
    cache) or :meth:`from_pipeline` (any ``FluxPipeline``, e.g. the tiny random one). The pipeline's
    ``__call__`` is never used: the caller's sampler owns the loop and calls :meth:`velocity`.

    Convention
    ----------
    See the module docstring: images in [0, 1], unpacked latents ``(B, 16, H/8, W/8)`` normalised
    with FLUX's shift/scale, ``v = eps - x0``, ``timestep = sigma``, guidance as a model input.
    """

    name: str = "flux"
    geometry: LatentGeometry = LatentGeometry(channels=16, downscale=8, multiple=16)

    def __init__(
        self,
        pipe: Any,
        *,
        device: str | torch.device | None = None,
        dtype: torch.dtype | str | None = None,
        guidance: float = 3.5,
        max_sequence_length: int = 512,
        vae_tiling: bool = True,
        vae_slicing: bool = True,
    ):
        """Wrap ``pipe`` (a ``FluxPipeline``), moving it to ``device`` / ``dtype``.

        ``device=None`` keeps the pipeline's current device; ``dtype=None`` means bfloat16 on
        CUDA and float32 otherwise. ``vae_tiling`` lets the VAE work in overlapping tiles on images
        larger than its ``sample_size`` (1024 for FLUX.1-dev: the 1024 x 2048 panorama is tiled);
        ``vae_slicing`` runs the VAE one image at a time. ``max_sequence_length`` is the T5 token
        count (512 for FLUX.1-dev)."""
        vae_factor = int(getattr(pipe, "vae_scale_factor", 8))
        channels = int(pipe.transformer.config.in_channels) // 4
        if (channels, vae_factor) != (self.geometry.channels, self.geometry.downscale):
            raise ValueError(
                f"pipeline has {channels} latent channels and VAE downscale {vae_factor}; FluxGenerator expects "
                f"{self.geometry.channels} and {self.geometry.downscale}"
            )
        if device is None:
            device = next(pipe.transformer.parameters()).device
        device = torch.device(device)
        dtype = _as_dtype(dtype) or _default_dtype(device)
        for component in (pipe.transformer, pipe.vae, pipe.text_encoder, pipe.text_encoder_2):
            if component is None:
                continue
            component.to(device)
            if component.dtype != dtype:  # loaded with ``torch_dtype`` already: keep fp32-pinned layers
                component.to(dtype)
            component.eval().requires_grad_(False)
        if vae_tiling:
            pipe.vae.enable_tiling()
        else:
            pipe.vae.disable_tiling()
        if vae_slicing:
            pipe.vae.enable_slicing()
        else:
            pipe.vae.disable_slicing()
        self.pipe = pipe
        self.device = device
        self.dtype = dtype
        self.guidance = float(guidance)
        self.max_sequence_length = int(max_sequence_length)

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_pipeline(cls, pipe: Any, **kwargs) -> "FluxGenerator":
        """Wrap an already-built ``FluxPipeline`` (keyword arguments as in the constructor)."""
        return cls(pipe, **kwargs)

    @classmethod
    def from_pretrained(
        cls,
        model_id_or_path: str | os.PathLike = FLUX_DEV_ID,
        *,
        device: str | torch.device | None = None,
        dtype: torch.dtype | str | None = None,
        local_files_only: bool = True,
        vae_tiling: bool = True,
        vae_slicing: bool = True,
        guidance: float = 3.5,
        max_sequence_length: int = 512,
        revision: str | None = None,
    ) -> "FluxGenerator":
        """Load FLUX.1-dev (or another FLUX checkpoint in diffusers layout) without downloading.

        ``model_id_or_path`` is a local folder (config key ``model.path``) or a Hugging Face id
        looked up in the local cache. ``device=None`` needs CUDA (config key ``model.device``;
        ``"cpu"`` forces the CPU).

        Raises :class:`WeightsNotFoundError` when the weights are missing or incomplete, and
        :class:`DeviceNotAvailableError` when CUDA is needed but absent."""
        folder = resolve_weights_folder(model_id_or_path, local_files_only=local_files_only, revision=revision)
        dev = resolve_device(device)
        dtype = _as_dtype(dtype) or _default_dtype(dev)
        FluxPipeline = _flux_pipeline_cls()
        try:
            pipe = FluxPipeline.from_pretrained(folder, local_files_only=local_files_only, **_dtype_kwarg(dtype))
        except (OSError, ValueError) as err:  # missing / partial component folders or weight files
            raise WeightsNotFoundError(_weights_help(f"loading {folder!r} failed: {err}")) from err
        return cls(
            pipe,
            device=dev,
            dtype=dtype,
            guidance=guidance,
            max_sequence_length=max_sequence_length,
            vae_tiling=vae_tiling,
            vae_slicing=vae_slicing,
        )

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, device={str(self.device)!r}, dtype={self.dtype}, guidance={self.guidance})"

    # ------------------------------------------------------------------ packing helpers

    @staticmethod
    def pack(z: torch.Tensor) -> torch.Tensor:
        """Unpacked ``(B, C, h, w)`` -> packed ``(B, (h/2)(w/2), 4C)`` (2x2 patches, row-major)."""
        B, C, h, w = z.shape
        if h % 2 or w % 2:
            raise ValueError(f"latent size {h}x{w} must be even to pack into 2x2 patches")
        return _flux_pipeline_cls()._pack_latents(z, B, C, h, w)

    @staticmethod
    def unpack(packed: torch.Tensor, h: int, w: int, downscale: int = 8) -> torch.Tensor:
        """Packed ``(B, (h/2)(w/2), 4C)`` -> unpacked ``(B, C, h, w)``: the inverse of :meth:`pack`."""
        return _flux_pipeline_cls()._unpack_latents(packed, h * downscale, w * downscale, downscale)

    # ------------------------------------------------------------------ VAE

    @torch.no_grad()
    def encode(self, images: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """Images ``(B, 3, H, W)`` in [0, 1] -> normalised latents ``(B, 16, H/8, W/8)`` (float32,
        on the images' device): the posterior's mode, or a sample drawn from ``generator``."""
        if images.ndim != 4 or images.shape[1] != 3:
            raise ValueError(f"images must be (B, 3, H, W), got {tuple(images.shape)}")
        self.geometry.latent_shape(images.shape[-2], images.shape[-1])
        vae = self.pipe.vae
        x = images.to(device=self.device, dtype=self.dtype) * 2 - 1
        dist = vae.encode(x).latent_dist
        lat = dist.mode() if generator is None else dist.sample(generator=generator)
        lat = (lat - vae.config.shift_factor) * vae.config.scaling_factor
        return lat.to(device=images.device, dtype=torch.float32)

    @torch.no_grad()
    def decode(self, latents: torch.Tensor) -> torch.Tensor:
        """Normalised latents ``(B, 16, h, w)`` -> images ``(B, 3, 8h, 8w)`` in [0, 1] (float32,
        on the latents' device)."""
        self._check_latents(latents)
        vae = self.pipe.vae
        z = latents.to(device=self.device, dtype=self.dtype) / vae.config.scaling_factor + vae.config.shift_factor
        img = vae.decode(z, return_dict=False)[0]
        return ((img.float() + 1) / 2).clamp_(0, 1).to(latents.device)

    # ------------------------------------------------------------------ text

    @torch.no_grad()
    def condition(self, prompts: Sequence[str], views: Sequence[str] | None = None, *, guidance: float | None = None) -> Condition:
        """Encode ``prompts`` with CLIP (pooled) and T5 (tokens).

        ``data``: ``prompt_embeds`` ``(B, L, D)``, ``pooled_prompt_embeds`` ``(B, P)``,
        ``text_ids`` ``(B, L, 3)`` (zeros; the transformer uses one row), ``guidance`` ``(B,)``
        float32 (``guidance`` or the generator's default), ``views``. FLUX ignores the view."""
        if isinstance(prompts, str):
            prompts = [prompts]
        prompts = list(prompts)
        views = ["main"] * len(prompts) if views is None else ([views] if isinstance(views, str) else list(views))
        if len(views) != len(prompts):
            raise ValueError(f"{len(prompts)} prompts but {len(views)} views")
        bad = sorted({v for v in views if v not in VIEWS})
        if bad:
            raise ValueError(f"unknown views {bad}; expected one of {VIEWS}")
        prompt_embeds, pooled, text_ids = self.pipe.encode_prompt(
            prompt=prompts, prompt_2=None, device=self.device, max_sequence_length=self.max_sequence_length
        )
        B = len(prompts)
        g = self.guidance if guidance is None else float(guidance)
        data = {
            "prompt_embeds": prompt_embeds.to(self.dtype),
            "pooled_prompt_embeds": pooled.to(self.dtype),
            "text_ids": text_ids.to(self.dtype).unsqueeze(0).expand(B, -1, -1),
            "guidance": torch.full((B,), g, dtype=torch.float32, device=self.device),
            "views": views,
        }
        return Condition(prompts=prompts, data=data)

    # ------------------------------------------------------------------ transformer

    @torch.no_grad()
    def velocity(self, z: torch.Tensor, sigma, cond: Condition) -> torch.Tensor:
        """The velocity ``v = eps - x0`` ``(B, 16, h, w)`` of latents ``z`` at noise level ``sigma``
        (a float, or a ``(B,)`` tensor), in ``z``'s dtype and on ``z``'s device.

        All ``B`` latents go through the transformer in one call; ``cond`` has ``B`` prompts, or
        one prompt that is used for all."""
        self._check_latents(z)
        B, C, h, w = z.shape
        cond = self._match_batch(cond, B)
        sig = torch.as_tensor(sigma, dtype=torch.float32).to(self.device).reshape(-1)
        if sig.numel() == 1:
            sig = sig.expand(B)
        if sig.numel() != B:
            raise ValueError(f"sigma has {sig.numel()} entries for a batch of {B}")
        pipe, dtype = self.pipe, self.dtype
        packed = pipe._pack_latents(z.to(device=self.device, dtype=dtype), B, C, h, w)
        img_ids = pipe._prepare_latent_image_ids(B, h // 2, w // 2, self.device, dtype)
        # as FluxPipeline: t = 1000 sigma in the model dtype, passed as t / 1000
        timestep = (sig * 1000).to(dtype) / 1000
        guidance = cond.data["guidance"].to(self.device, torch.float32) if pipe.transformer.config.guidance_embeds else None
        out = pipe.transformer(
            hidden_states=packed,
            timestep=timestep,
            guidance=guidance,
            pooled_projections=cond.data["pooled_prompt_embeds"].to(self.device, dtype),
            encoder_hidden_states=cond.data["prompt_embeds"].to(self.device, dtype),
            txt_ids=cond.data["text_ids"][0].to(self.device, dtype),
            img_ids=img_ids,
            return_dict=False,
        )[0]
        v = pipe._unpack_latents(out, h * self.geometry.downscale, w * self.geometry.downscale, self.geometry.downscale)
        return v.to(device=z.device, dtype=z.dtype)

    # ------------------------------------------------------------------ schedule

    def sigmas(self, num_steps: int, height: int, width: int) -> torch.Tensor:
        """FluxPipeline's noise levels for ``num_steps`` steps at image size ``height x width``:
        float32 ``(num_steps + 1,)``, decreasing, ending in 0 (resolution-dependent shift ``mu``
        from ``calculate_shift`` on the packed sequence length)."""
        import numpy as np
        from diffusers.pipelines.flux.pipeline_flux import calculate_shift

        _, h, w = self.geometry.latent_shape(height, width)
        sched_cfg = self.pipe.scheduler.config
        scheduler = type(self.pipe.scheduler).from_config(sched_cfg)
        mu = calculate_shift(
            (h // 2) * (w // 2),
            sched_cfg.get("base_image_seq_len", 256),
            sched_cfg.get("max_image_seq_len", 4096),
            sched_cfg.get("base_shift", 0.5),
            sched_cfg.get("max_shift", 1.15),
        )
        scheduler.set_timesteps(sigmas=np.linspace(1.0, 1 / num_steps, num_steps), mu=mu, device="cpu")
        return scheduler.sigmas.to(torch.float32).clone()

    # ------------------------------------------------------------------ internals

    def _check_latents(self, z: torch.Tensor) -> None:
        C = self.geometry.channels
        if z.ndim != 4 or z.shape[1] != C:
            raise ValueError(f"latents must be (B, {C}, h, w), got {tuple(z.shape)}")
        if z.shape[-2] % 2 or z.shape[-1] % 2:
            raise ValueError(f"latent size {z.shape[-2]}x{z.shape[-1]} must be even (images a multiple of {self.geometry.multiple})")

    @staticmethod
    def _match_batch(cond: Condition, B: int) -> Condition:
        n = len(cond)
        if n == B:
            return cond
        if n != 1:
            raise ValueError(f"condition has {n} prompts for a batch of {B} latents (give {B} or 1)")
        data = {
            k: (v.expand(B, *v.shape[1:]) if isinstance(v, torch.Tensor) else (list(v) * B if isinstance(v, list) else v))
            for k, v in cond.data.items()
        }
        return Condition(prompts=list(cond.prompts) * B, data=data)
