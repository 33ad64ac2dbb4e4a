"""FLUX (diffusers) as a :class:`~snell_bench.models.base.Generator`: VAE, text conditioning and the
transformer's velocity, with the sampling loop left to the caller.

Convention:
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
    - Weights: found in a local folder or the Hugging Face cache, or built at random, by
      :mod:`snell_bench.models.flux_weights` (its names are importable from here too).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from typing import Any

import torch

from snell_bench.sampler.schedule import linear_sigmas

from .base import Condition, LatentGeometry, check_schedule
from .devices import default_dtype, dtype_kwarg, parse_dtype
from .errors import WeightsNotFoundError
from .flux_weights import FLUX_COMPONENTS as FLUX_COMPONENTS  # re-exported: the layout's sub-folders
from .flux_weights import FLUX_DEV_ID, random_flux_pipeline, resolve_device, resolve_weights_folder
from .flux_weights import weights_help as _weights_help

__all__ = ["FLUX_DEV_ID", "FluxGenerator", "random_flux_pipeline", "resolve_device", "resolve_weights_folder"]

log = logging.getLogger(__name__)

VIEWS = ("main", "pano")

#: Scheduler options that :meth:`FluxGenerator.sigmas` leaves to ``set_timesteps``.
_SCHEDULER_OPTIONS_VIA_SET_TIMESTEPS = (
    "shift_terminal",
    "use_karras_sigmas",
    "use_exponential_sigmas",
    "use_beta_sigmas",
)


def _flux_pipeline_cls():
    from diffusers import FluxPipeline

    return FluxPipeline


class FluxGenerator:
    """A FLUX pipeline's components behind the :class:`~snell_bench.models.base.Generator` protocol.

    Build with :meth:`from_pretrained` (FLUX.1-dev weights from a local folder or the Hugging Face
    cache) or :meth:`from_pipeline` (any ``FluxPipeline``, e.g. the tiny random one). The pipeline's
    ``__call__`` is never used: the caller's sampler owns the loop and calls :meth:`velocity`.

    Convention:
        See the module docstring: images in [0, 1], unpacked latents ``(B, 16, H/8, W/8)`` normalised
        with FLUX's shift/scale, ``v = eps - x0``, ``timestep = sigma``, guidance as a model input.
    """

    name: str = "flux"
    geometry: LatentGeometry = LatentGeometry(channels=16, downscale=8, multiple=16)
    #: The VAE's encoder is a diagonal Gaussian: ``encode(..., generator)`` draws from it.
    has_posterior: bool = True

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

        Args:
            pipe: the pipeline whose components are used (its ``__call__`` is not).
            device: where the model runs; ``None`` keeps the pipeline's current device.
            dtype: a dtype or its name (:func:`~snell_bench.models.devices.parse_dtype`);
                ``None`` means bfloat16 on CUDA and float32 otherwise.
            guidance: the default guidance scale (a transformer input).
            max_sequence_length: the T5 token count (512 for FLUX.1-dev).
            vae_tiling: let the VAE work in overlapping tiles on images larger than its
                ``sample_size`` (1024 for FLUX.1-dev: the 1024 x 2048 panorama is tiled).
            vae_slicing: run the VAE one image at a time.

        Raises:
            ValueError: if the pipeline's latent channels or VAE downscale are not FLUX's, or the
                dtype name is unknown.
        """
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
        dtype = parse_dtype(dtype) or default_dtype(device)
        for component in (pipe.transformer, pipe.vae, pipe.text_encoder, pipe.text_encoder_2):
            if component is None:
                continue
            component.to(device)
            if component.dtype != dtype:  # loaded in ``dtype`` already: keep fp32-pinned layers
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
        #: built with random weights (real shapes and cost, meaningless pixels)
        self.random_weights = bool(getattr(pipe, "random_weights", False))
        self.device = device
        self.dtype = dtype
        self.guidance = float(guidance)
        self.max_sequence_length = int(max_sequence_length)

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_pipeline(cls, pipe: Any, **kwargs) -> FluxGenerator:
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
        random_init: bool = False,
        seed: int = 0,
    ) -> FluxGenerator:
        """Load FLUX.1-dev (or another FLUX checkpoint in diffusers layout) without downloading, or
        build it with random weights (``random_init``).

        The text encoders and the VAE are shared with a FLUX Fill or Kontext pipeline loaded in the
        same process from the same weights (:mod:`snell_bench.models.shared`).

        Args:
            model_id_or_path: a local folder (config key ``model.path``) or a Hugging Face id
                looked up in the local cache.
            device: ``None`` needs CUDA (config key ``model.device``); ``"cpu"`` forces the CPU.
            dtype: a dtype or its name; ``None``: bfloat16 on CUDA, float32 otherwise.
            local_files_only: never download (with ``False`` diffusers may).
            vae_tiling: see the constructor.
            vae_slicing: see the constructor.
            guidance: the default guidance scale.
            max_sequence_length: the T5 token count.
            revision: the hub revision of a Hugging Face id.
            random_init: build FLUX.1-dev's architecture with random weights instead
                (:func:`~snell_bench.models.flux_random.build_random_flux_pipeline`; config key
                ``model.random_init``): no weights are read, ``model.path`` is ignored; on ``meta``
                nothing is materialised.
            seed: seeds the random weights.

        Returns:
            The generator (``random_weights`` tells how it was built).

        Raises:
            WeightsNotFoundError: when the weights are missing or incomplete.
            DeviceNotAvailableError: when CUDA is needed but absent.
        """
        from . import shared

        if random_init:
            dev = resolve_device(device)
            dtype = parse_dtype(dtype) or torch.bfloat16
            pipe = random_flux_pipeline("dev", device=dev, dtype=dtype, seed=seed)
        else:
            folder = resolve_weights_folder(model_id_or_path, local_files_only=local_files_only, revision=revision)
            dev = resolve_device(device)
            dtype = parse_dtype(dtype) or default_dtype(dev)
            FluxPipeline = _flux_pipeline_cls()
            identities = shared.folder_identities(folder)
            try:
                pipe = FluxPipeline.from_pretrained(
                    folder,
                    local_files_only=local_files_only,
                    **shared.shared_kwargs(identities, dev, dtype),
                    **dtype_kwarg(dtype),
                )
            except (OSError, ValueError) as err:  # missing / partial component folders or weight files
                raise WeightsNotFoundError(_weights_help(f"loading {folder!r} failed: {err}")) from err
            pipe.to(dev)
            shared.register_components(pipe, identities, dev, dtype)
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
        if self.device.type == "meta":  # shapes only: the encoder ran once per input shape
            key = ("encode", tuple(images.shape), generator is None)
            return self._meta_once(key, torch.float32, lambda: self._encode(images, generator))
        return self._encode(images, generator)

    def _encode(self, images: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
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
        if self.device.type == "meta":  # shapes only: the decoder ran once per input shape
            return self._meta_once(("decode", tuple(latents.shape)), torch.float32, lambda: self._decode(latents))
        return self._decode(latents)

    def _decode(self, latents: torch.Tensor) -> torch.Tensor:
        vae = self.pipe.vae
        z = latents.to(device=self.device, dtype=self.dtype) / vae.config.scaling_factor + vae.config.shift_factor
        img = vae.decode(z, return_dict=False)[0]
        return ((img.float() + 1) / 2).clamp_(0, 1).to(latents.device)

    # ------------------------------------------------------------------ text

    @torch.no_grad()
    def condition(
        self, prompts: Sequence[str], views: Sequence[str] | None = None, *, guidance: float | None = None
    ) -> Condition:
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
        if isinstance(sigma, torch.Tensor):
            sig = sigma.to(device=self.device, dtype=torch.float32).reshape(-1)
        else:  # a fill on the device: no host-to-device copy per call
            sig = torch.full((1,), float(sigma), dtype=torch.float32, device=self.device)
        if sig.numel() == 1:
            sig = sig.expand(B)
        if sig.numel() != B:
            raise ValueError(f"sigma has {sig.numel()} entries for a batch of {B}")
        if self.device.type == "meta":  # shapes only: the transformer ran once per input shape
            key = ("velocity", tuple(z.shape), tuple(cond.data["prompt_embeds"].shape))
            return self._meta_once(key, z.dtype, lambda: self._velocity(z, sig, cond))
        return self._velocity(z, sig, cond)

    def _velocity(self, z: torch.Tensor, sig: torch.Tensor, cond: Condition) -> torch.Tensor:
        B, C, h, w = z.shape
        pipe, dtype = self.pipe, self.dtype
        packed = pipe._pack_latents(z.to(device=self.device, dtype=dtype), B, C, h, w)
        img_ids = self._image_ids(h // 2, w // 2)
        # as FluxPipeline: t = 1000 sigma in the model dtype, passed as t / 1000
        timestep = (sig * 1000).to(dtype) / 1000
        guidance = (
            cond.data["guidance"].to(self.device, torch.float32) if pipe.transformer.config.guidance_embeds else None
        )
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

    def sigmas(self, num_steps: int, height: int, width: int, kind: str = "flux") -> torch.Tensor:
        """The noise schedule for ``num_steps`` steps at image size ``height x width``.

        Args:
            num_steps: the number of denoising steps ``T``.
            height: the image height in pixels (a multiple of 16).
            width: the image width in pixels.
            kind: ``"flux"``: ``FluxPipeline``'s schedule from the pipeline's scheduler and its
                config: ``linspace(1, 1/T, T)`` shifted with ``mu = calculate_shift`` of the packed
                sequence length ``(h / 2) (w / 2)`` (the config's base/max sequence lengths and
                shifts), then 0; ``"linear"``: ``1, 1 - 1/T, ..., 0``.

        Returns:
            A float64 tensor ``(T + 1,)``, decreasing from 1 to 0. With dynamic shifting (FLUX.1-dev)
            the scheduler's own ``time_shift`` is evaluated in float64, which equals FLUX's closed
            form (:func:`~snell_bench.sampler.schedule.flux_sigmas`) bit for bit; ``set_timesteps``
            rounds to float32 first (up to ~7e-8 off), which a float32 model amplifies. Scheduler
            options beyond that (a static shift, ``shift_terminal``, Karras / exponential / beta
            sigmas) go through ``set_timesteps`` and its float32 values.

        Raises:
            ValueError: for an unknown kind, a bad step count, a size that is not a multiple of 16,
                or a scheduler with ``invert_sigmas`` (its noise levels rise from 0 to 1).
        """
        import numpy as np
        from diffusers.pipelines.flux.pipeline_flux import calculate_shift

        check_schedule(kind, num_steps)
        _, h, w = self.geometry.latent_shape(height, width)
        if kind == "linear":
            return linear_sigmas(num_steps)
        cfg = self.pipe.scheduler.config
        if cfg.get("invert_sigmas"):
            raise ValueError("the pipeline's scheduler inverts its sigmas (0 -> 1); the sampler needs them from 1 to 0")
        scheduler = type(self.pipe.scheduler).from_config(cfg)
        mu = calculate_shift(
            (h // 2) * (w // 2),
            cfg.get("base_image_seq_len", 256),
            cfg.get("max_image_seq_len", 4096),
            cfg.get("base_shift", 0.5),
            cfg.get("max_shift", 1.15),
        )
        if (
            cfg.get("use_dynamic_shifting")
            and hasattr(scheduler, "time_shift")
            and not any(cfg.get(k) for k in _SCHEDULER_OPTIONS_VIA_SET_TIMESTEPS)
        ):
            shifted = scheduler.time_shift(
                mu, 1.0, torch.linspace(1.0, 1.0 / num_steps, num_steps, dtype=torch.float64, device="cpu")
            )
        else:  # exactly as FluxPipeline
            scheduler.set_timesteps(sigmas=np.linspace(1.0, 1 / num_steps, num_steps), mu=mu, device="cpu")
            shifted = scheduler.sigmas[:-1].to(torch.float64)
        return torch.cat([shifted, torch.zeros(1, dtype=torch.float64, device="cpu")])

    # ------------------------------------------------------------------ internals

    def _image_ids(self, h2: int, w2: int) -> torch.Tensor:
        """``FluxPipeline._prepare_latent_image_ids`` for an ``h2 x w2`` patch grid, ``(h2 w2, 3)``
        rows ``(0, row, col)`` in the model dtype, built on the device (diffusers builds them on
        the host and copies them at every call) and kept per grid size."""
        cache = self.__dict__.setdefault("_ids", {})
        key = (h2, w2, self.dtype)
        if key not in cache:
            rows = torch.arange(h2, device=self.device, dtype=torch.float32)[:, None].expand(h2, w2)
            cols = torch.arange(w2, device=self.device, dtype=torch.float32)[None, :].expand(h2, w2)
            ids = torch.stack([torch.zeros_like(rows), rows, cols], -1).reshape(h2 * w2, 3)
            cache[key] = ids.to(self.dtype)
        return cache[key]

    def _meta_once(self, key: tuple, dtype: torch.dtype, run) -> torch.Tensor:
        """On ``meta`` a module's output depends on its inputs' shapes alone: run it once per
        ``key`` (the shapes) and answer later calls with an empty tensor of that output's shape
        (a meta forward pass of FLUX.1's 57 blocks costs ~0.6 s of Python dispatch, one of the
        tiled VAE ~1 s)."""
        cache = self.__dict__.setdefault("_meta_shapes", {})
        if key not in cache:
            out = run()
            cache[key] = (tuple(out.shape), out.dtype)
        shape, out_dtype = cache[key]
        return torch.empty(shape, dtype=out_dtype if dtype is None else dtype, device="meta")

    def _check_latents(self, z: torch.Tensor) -> None:
        C = self.geometry.channels
        if z.ndim != 4 or z.shape[1] != C:
            raise ValueError(f"latents must be (B, {C}, h, w), got {tuple(z.shape)}")
        if z.shape[-2] % 2 or z.shape[-1] % 2:
            raise ValueError(
                f"latent size {z.shape[-2]}x{z.shape[-1]} must be even (images a multiple of {self.geometry.multiple})"
            )

    @staticmethod
    def _match_batch(cond: Condition, B: int) -> Condition:
        n = len(cond)
        if n == B:
            return cond
        if n != 1:
            raise ValueError(f"condition has {n} prompts for a batch of {B} latents (give {B} or 1)")
        data = {
            k: (
                v.expand(B, *v.shape[1:])
                if isinstance(v, torch.Tensor)
                else (list(v) * B if isinstance(v, list) else v)
            )
            for k, v in cond.data.items()
        }
        return Condition(prompts=list(cond.prompts) * B, data=data)
