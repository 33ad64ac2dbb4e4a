"""Baselines through diffusers: other text-to-image models and FLUX Fill inpainting.

Convention:
    - Images: ``(1, 3, H, W)`` float32 sRGB in [0, 1] on the CPU, in and out. The pipelines see
      8-bit PIL images (I⁻ and the mask) and return float images (``output_type="np"``), which are
      passed on unrounded.
    - Weights come from a local folder or the Hugging Face cache only (``local_files_only``); they
      are never downloaded. A missing model raises :class:`WeightsNotFoundError` naming the config
      key ``method.model_id`` (and ``model.fill`` for inpainting).
    - Device: CUDA by default (:class:`DeviceNotAvailableError`, naming ``model.device=cpu``, when
      there is none); ``device="cpu"`` runs on the CPU, explicitly only. The device is resolved
      before any weight is read. Precision: bfloat16 on CUDA and float32 elsewhere, unless
      ``dtype`` is given; it is passed as diffusers' ``dtype=`` keyword.
    - One loaded pipeline is kept (:func:`load_pipeline`, keyed by model, class, device and dtype),
      so the cells of a grid reuse it; loading another one first releases it.
    - Where the weights are and whether they fit the device: :mod:`snell_bench.models.offload`
      (:func:`offload_mode`, :func:`folder_component_bytes` and :func:`local_folder` are importable
      from here too).
    - Steps and guidance: ``None`` is the pipeline's own default, read from the signature of its
      ``__call__`` (:func:`call_settings`). "Guidance" is the pipeline's ``guidance_scale`` when that
      has a default (FLUX.1 / FLUX Fill / FLUX.2: the embedded, distilled guidance; SD3: classifier-free
      guidance against the empty negative prompt), else its ``true_cfg_scale`` (Qwen-Image:
      classifier-free guidance, which the pipeline applies only given a negative prompt, so
      ``" "`` — the model card's "no negative concept" — is passed when it exceeds 1).
    - Randomness: a ``torch.Generator`` on the pipeline's device seeded with ``seed``; everything
      else is the pipeline's own ``__call__``.
"""

from __future__ import annotations

import inspect
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from snell_bench.models.devices import default_dtype, dtype_kwarg, parse_dtype, resolve_device
from snell_bench.models.errors import WeightsNotFoundError
from snell_bench.models.offload import OFFLOAD_MODES as OFFLOAD_MODES  # re-exported
from snell_bench.models.offload import device_budget, folder_component_bytes, local_folder, offload_mode
from snell_bench.utils.tensors import bchw_to_hwc, hwc_to_bchw

__all__ = [
    "CallSettings",
    "call_settings",
    "generate_external",
    "inpaint_external",
    "load_pipeline",
    "offload_mode",
    "folder_component_bytes",
    "local_folder",
]

#: The negative prompt that switches on a ``true_cfg_scale`` pipeline's classifier-free guidance
#: without naming a concept to avoid (Qwen-Image's model card).
EMPTY_NEGATIVE_PROMPT = " "


@dataclass(frozen=True)
class CallSettings:
    """The inference settings of one pipeline call, as passed to its ``__call__``.

    Convention:
        - ``guidance_key`` is the ``__call__`` keyword that ``guidance`` is given as
          (``guidance_scale`` or ``true_cfg_scale``), ``None`` for a pipeline without guidance
          (then ``guidance`` is ``None`` too).
        - ``negative_prompt`` is ``None`` unless the wrapper passes one (``true_cfg_scale`` above 1).

    Attributes:
        pipeline: the pipeline's class name.
        steps: ``num_inference_steps``.
        guidance: the guidance value passed.
        guidance_key: its keyword.
        negative_prompt: the negative prompt passed, if any.
    """

    pipeline: str
    steps: int
    guidance: float | None
    guidance_key: str | None
    negative_prompt: str | None = None

    def call_kwargs(self) -> dict:
        """The keyword arguments these settings add to the pipeline's ``__call__``."""
        kwargs: dict = {"num_inference_steps": self.steps}
        if self.guidance_key is not None:
            kwargs[self.guidance_key] = self.guidance
        if self.negative_prompt is not None:
            kwargs["negative_prompt"] = self.negative_prompt
        return kwargs

    def as_dict(self) -> dict:
        """The settings as a plain dict (for metrics files)."""
        return asdict(self)


def call_settings(pipe, steps: int | None = None, guidance: float | None = None, *, cfg: bool = True) -> CallSettings:
    """The steps and guidance a call of ``pipe`` uses: the given ones, else its ``__call__`` defaults.

    Convention:
        - The guidance keyword is ``guidance_scale`` if the signature has one with a default that is
          not ``None``; else ``true_cfg_scale`` if present; else ``guidance_scale`` (default
          ``None``); else there is none.
        - With ``true_cfg_scale`` above 1, a ``negative_prompt`` parameter and ``cfg`` (config key
          ``method.cfg``), the negative prompt :data:`EMPTY_NEGATIVE_PROMPT` is passed; without
          any (``cfg=False``, as the authors call Qwen-Image), the pipeline skips the guidance: one
          transformer pass per step, ``true_cfg_scale`` passed but unused.

    Args:
        pipe: a diffusers pipeline or pipeline class.
        steps: ``num_inference_steps``; ``None``: the signature's default.
        guidance: the guidance value; ``None``: the signature's default.
        cfg: whether a ``true_cfg_scale`` pipeline gets the negative prompt that turns its
            guidance on.

    Returns:
        The settings.

    Raises:
        ValueError: if ``guidance`` is given for a pipeline without a guidance keyword, or the
            signature has no default step count and ``steps`` is ``None``.
    """
    cls = pipe if isinstance(pipe, type) else type(pipe)
    params = inspect.signature(cls.__call__).parameters

    def default(name):
        p = params.get(name)
        return None if p is None or p.default is inspect.Parameter.empty else p.default

    if steps is None:
        steps = default("num_inference_steps")
        if steps is None:
            raise ValueError(f"{cls.__name__}.__call__ has no default num_inference_steps; set method.steps")
    if "guidance_scale" in params and default("guidance_scale") is not None:
        key = "guidance_scale"
    elif "true_cfg_scale" in params:
        key = "true_cfg_scale"
    elif "guidance_scale" in params:
        key = "guidance_scale"
    else:
        key = None
    if key is None:
        if guidance is not None:
            raise ValueError(f"{cls.__name__} takes no guidance; set method.guidance to null")
        return CallSettings(cls.__name__, int(steps), None, None)
    value = default(key) if guidance is None else guidance
    value = None if value is None else float(value)
    negative = None
    if cfg and key == "true_cfg_scale" and value is not None and value > 1 and "negative_prompt" in params:
        negative = EMPTY_NEGATIVE_PROMPT
    return CallSettings(cls.__name__, int(steps), value, key, negative)


def _pipeline_class(pipeline):
    """The diffusers class named ``pipeline`` (or the class itself); ``None``: from model_index.json."""
    import diffusers

    if pipeline is None:
        return diffusers.DiffusionPipeline
    if isinstance(pipeline, type):
        return pipeline
    cls = getattr(diffusers, str(pipeline), None)
    if not (isinstance(cls, type) and issubclass(cls, diffusers.DiffusionPipeline)):
        raise ValueError(f"{pipeline!r} is not a diffusers pipeline class (e.g. 'FluxFillPipeline')")
    return cls


def _is_local_or_repo_id(model_id: str) -> bool:
    """Whether ``model_id`` is an existing path or could be a Hugging Face repo id."""
    from huggingface_hub.utils import HFValidationError, validate_repo_id

    if Path(model_id).expanduser().exists():
        return True
    try:
        validate_repo_id(model_id)
    except HFValidationError:
        return False
    return True


def _missing(model_id: str, cls, reason: str) -> WeightsNotFoundError:
    import diffusers

    name = "" if cls is diffusers.DiffusionPipeline else f" ({cls.__name__})"
    fill = "Fill" in name or "Inpaint" in name
    keys = "method.model_id (or build the pipeline with model.fill)" if fill else "method.model_id"
    return WeightsNotFoundError(
        f"weights of {model_id}{name} not found locally ({reason}); set {keys} to a local folder with the "
        "diffusers layout, or download the model into the Hugging Face cache on a machine with internet"
    )


#: diffusers' FLUX.1 pipeline classes -> the kind :mod:`snell_bench.models.flux_random` builds.
RANDOM_KINDS = {"FluxPipeline": "dev", "FluxFillPipeline": "fill", "FluxKontextPipeline": "kontext"}


def load_pipeline(
    model_id: str | Path,
    *,
    pipeline: str | type | None = None,
    device: str | torch.device | None = None,
    dtype: torch.dtype | str | None = None,
    memory_gb: float | None = None,
    random_init: bool = False,
    seed: int = 0,
):
    """A diffusers pipeline from local files, on ``device`` in ``dtype`` (each call loads it: how
    long it is kept is the caller's choice, e.g. :class:`~snell_bench.pipeline.pool.ModelPool`).

    Convention:
        - ``pipeline=None`` loads the class that the folder's (or cached snapshot's)
          ``model_index.json`` names (``DiffusionPipeline.from_pretrained``); a class name such as
          ``"FluxFillPipeline"`` loads that class.
        - Always ``local_files_only=True``; the dtype goes through
          :func:`~snell_bench.models.devices.dtype_kwarg` (``dtype=``, never ``torch_dtype=``).
        - The device is resolved before the weights are read, so a missing GPU fails fast.
        - Components whose weights equal those of a pipeline already loaded in this process (FLUX
          Fill's and Kontext's text encoders and VAE are FLUX.1-dev's) are taken from it, not
          loaded again (:mod:`snell_bench.models.shared`).
        - A pipeline whose weights do not fit the device (``memory_gb``, else 90 % of the GPU's
          memory) runs with diffusers' offloading (:func:`offload_mode`; FLUX.2-dev's ~112 GB on
          an 80 GB GPU: ``model``); the mode is in ``pipe.offload_mode``.

    Args:
        model_id: a local diffusers folder or a Hugging Face id in the local cache (config key
            ``method.model_id``).
        pipeline: ``None``, or the name of a diffusers pipeline class (or the class).
        device: ``None`` / ``"auto"`` (CUDA, which must be available), ``"cuda[:i]"`` or ``"cpu"``.
        dtype: a dtype or its name (:func:`~snell_bench.models.devices.parse_dtype`); ``None``:
            bfloat16 on CUDA, float32 otherwise.
        memory_gb: the device memory (GiB) the weights may take (config key ``models.memory_gb``).
        random_init: build a FLUX.1 pipeline (``FluxPipeline``, ``FluxFillPipeline``,
            ``FluxKontextPipeline``) at full size with random weights instead of loading it
            (config key ``model.random_init``); ``model_id`` is not read.
        seed: seeds the random weights.

    Returns:
        The pipeline, on ``device``.

    Raises:
        WeightsNotFoundError: if the model is not available locally.
        DeviceNotAvailableError: if CUDA is needed and missing.
        ValueError: if ``pipeline`` names no diffusers pipeline class, or ``random_init`` is asked
            for another pipeline than FLUX.1's.
    """
    from snell_bench.models import shared

    model_id = str(model_id)
    cls = _pipeline_class(pipeline)
    dev = resolve_device(
        device,
        unavailable=(
            f"{model_id} runs on a CUDA GPU by default and none is available on this machine; set "
            "model.device=cpu (device='cpu') to run it on the CPU anyway (float32, slow)"
        ),
    )
    if random_init:
        return _random_pipeline(cls, model_id, dev, dtype, seed)
    dt = parse_dtype(dtype) or default_dtype(dev)
    if not _is_local_or_repo_id(model_id):
        raise _missing(model_id, cls, "no such folder, and not a Hugging Face model id")
    folder = local_folder(model_id)
    identities = shared.folder_identities(folder) if folder is not None else {}
    try:
        pipe = cls.from_pretrained(
            folder or model_id,
            local_files_only=True,
            **shared.shared_kwargs(identities, dev, dt),
            **dtype_kwarg(dt),
        )
    except OSError as e:  # includes huggingface_hub's LocalEntryNotFoundError
        raise _missing(model_id, cls, str(e)) from e
    sizes = folder_component_bytes(folder) if folder is not None else {}
    mode = offload_mode(sizes, device_budget(dev, memory_gb)) if dev.type == "cuda" else "none"
    return _place(pipe, mode, dev, identities, dt)


def _random_pipeline(cls: type, model_id: str, dev: torch.device, dtype: torch.dtype | str | None, seed: int):
    """``load_pipeline(..., random_init=True)``: the FLUX.1 pipeline of class ``cls`` at full size
    with random weights on ``dev`` in ``dtype`` (``None``: bfloat16), ``offload_mode`` ``"none"``;
    ``ValueError`` naming ``model.random_init`` for another class (``model_id`` is only named in
    that message)."""
    kind = RANDOM_KINDS.get(cls.__name__)
    if kind is None:
        raise ValueError(
            f"model.random_init=true builds FLUX.1 pipelines only ({', '.join(RANDOM_KINDS)}), not "
            f"{cls.__name__} for {model_id}; set model.random_init=false"
        )
    from snell_bench.models.flux_weights import random_flux_pipeline

    pipe = random_flux_pipeline(kind, device=dev, dtype=parse_dtype(dtype) or torch.bfloat16, seed=seed)
    pipe.offload_mode = "none"
    return pipe


def _place(pipe, mode: str, dev: torch.device, identities: dict, dtype: torch.dtype):
    """Run a loaded ``pipe`` on ``dev`` with offload ``mode`` (:func:`offload_mode`), recorded in
    ``pipe.offload_mode``; a pipeline wholly on the device offers its components for sharing
    (:func:`~snell_bench.models.shared.register_components` with their ``identities``)."""
    from snell_bench.models import shared

    if mode == "none":
        pipe = pipe.to(dev)
        shared.register_components(pipe, identities, dev, dtype)
    elif mode == "model":
        pipe.enable_model_cpu_offload(device=dev)
    else:
        pipe.enable_sequential_cpu_offload(device=dev)
    pipe.offload_mode = mode
    return pipe


def _to_tensor(images: np.ndarray, size: tuple[int, int], pipe) -> torch.Tensor:
    """The first ``(H, W, 3)`` float image of a pipeline's ``np`` output as ``(1, 3, H, W)`` in [0, 1]."""
    img = np.asarray(images[0], np.float32)
    if img.shape[:2] != tuple(size):
        multiple = 2 * int(getattr(pipe, "vae_scale_factor", 8))
        raise ValueError(
            f"{type(pipe).__name__} returned a {img.shape[0]}x{img.shape[1]} image for {size[0]}x{size[1]}: "
            f"use sizes that are multiples of {multiple}"
        )
    return hwc_to_bchw(np.clip(img, 0.0, 1.0))


def _generator(pipe, seed: int) -> torch.Generator:
    return torch.Generator(pipe.device).manual_seed(int(seed))


def generate_external(
    pipe_or_model_id,
    prompt: str,
    size: tuple[int, int],
    *,
    seed: int = 0,
    steps: int | None = None,
    guidance: float | None = None,
    device: str | torch.device | None = None,
    dtype: torch.dtype | str | None = None,
    pipeline: str | type | None = None,
    return_settings: bool = False,
    cfg: bool = True,
) -> torch.Tensor | tuple[torch.Tensor, CallSettings]:
    """Text-to-image with a diffusers pipeline (FLUX.2-dev, Qwen-Image, SD3.5-Large, FLUX.1, ...).

    Convention:
        - The call is the pipeline's own ``__call__`` with ``prompt``, ``height``, ``width``, the
          :class:`CallSettings` keywords, the seeded generator and ``output_type="np"``; nothing else.
        - Defaults (diffusers 0.42): Flux2Pipeline 50 steps, ``guidance_scale`` 4.0;
          QwenImagePipeline 50 steps, ``true_cfg_scale`` 4.0 (negative prompt ``" "``);
          StableDiffusion3Pipeline 28 steps, ``guidance_scale`` 7.0; FluxPipeline 28 steps,
          ``guidance_scale`` 3.5.

    Args:
        pipe_or_model_id: a built text-to-image pipeline (used as it is), or a local diffusers
            folder / Hugging Face id in the local cache (config key ``method.model_id``), loaded with
            :func:`load_pipeline` on ``device`` in ``dtype``.
        prompt: the text prompt.
        size: the image size ``(H, W)``, multiples of 16 for these models.
        seed: seeds the pipeline's generator.
        steps: the number of inference steps; ``None``: the pipeline's default.
        guidance: the guidance value (see the module's convention); ``None``: the pipeline's default.
        device: ``None`` (CUDA, which must be available), ``"cuda[:i]"`` or ``"cpu"``.
        dtype: a dtype or its name; ``None``: bfloat16 on CUDA, float32 otherwise.
        pipeline: the pipeline class name; ``None``: the one ``model_index.json`` names.
        return_settings: also return the :class:`CallSettings` used.
        cfg: a ``true_cfg_scale`` pipeline's guidance on or off (:func:`call_settings`).

    Returns:
        The image ``(1, 3, H, W)``, float32 in [0, 1], on the CPU; with ``return_settings``, the pair
        ``(image, settings)``.

    Raises:
        WeightsNotFoundError: if the model is not available locally.
        DeviceNotAvailableError: if CUDA is needed and missing.
        ValueError: if the pipeline returns another size than ``size``.
    """
    if isinstance(pipe_or_model_id, (str, Path)):
        pipe = load_pipeline(pipe_or_model_id, pipeline=pipeline, device=device, dtype=dtype)
    else:
        pipe = pipe_or_model_id
    settings = call_settings(pipe, steps, guidance, cfg=cfg)
    H, W = size
    out = pipe(
        prompt=prompt,
        height=int(H),
        width=int(W),
        generator=_generator(pipe, seed),
        output_type="np",
        **settings.call_kwargs(),
    ).images
    img = _to_tensor(out, (H, W), pipe)
    return (img, settings) if return_settings else img


def inpaint_external(
    pipe_or_model_id,
    prompt: str,
    i_minus: torch.Tensor,
    mask: np.ndarray,
    *,
    seed: int = 0,
    steps: int | None = None,
    guidance: float | None = None,
    device: str | torch.device | None = None,
    dtype: torch.dtype | str | None = None,
    pipeline: str | type | None = "FluxFillPipeline",
    return_settings: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, CallSettings]:
    """FLUX Fill: repaint the masked region of I⁻ from the full prompt.

    Convention:
        - ``pipe_or_model_id`` is a built pipeline (e.g. the tiny one, or the ``model.fill`` node's),
          used as it is unless ``device`` / ``dtype`` is given (then moved there), or a model id /
          folder loaded with :func:`load_pipeline`.
        - The call is the pipeline's ``__call__`` with ``prompt``, the 8-bit PIL image and mask,
          ``height``, ``width``, the :class:`CallSettings` keywords (FluxFillPipeline: 50 steps,
          ``guidance_scale`` 30.0 by default), the seeded generator and ``output_type="np"``.

    Args:
        pipe_or_model_id: a diffusers inpainting pipeline, or a local folder / Hugging Face id in
            the local cache (config key ``method.model_id``).
        prompt: the full prompt (scene and object).
        i_minus: the object-free image ``(1, 3, H, W)`` in [0, 1]; ``H`` and ``W`` multiples of 16.
        mask: boolean ``(H, W)``, the region to repaint.
        seed: seeds the pipeline's generator.
        steps: the number of inference steps; ``None``: the pipeline's default.
        guidance: the guidance value; ``None``: the pipeline's default.
        device: ``None`` (CUDA for a model id, which must be available; a built pipeline stays
            where it is), ``"cuda[:i]"`` or ``"cpu"``.
        dtype: a dtype or its name; ``None``: bfloat16 on CUDA, float32 otherwise (a built pipeline
            keeps its own).
        pipeline: the class to load a model id with; ``None``: the one ``model_index.json`` names.
        return_settings: also return the :class:`CallSettings` used.

    Returns:
        The image ``(1, 3, H, W)``, float32 in [0, 1], on the CPU; with ``return_settings``, the pair
        ``(image, settings)``.

    Raises:
        WeightsNotFoundError: if the model is not available locally.
        DeviceNotAvailableError: if CUDA is needed and missing.
        ValueError: if the mask's shape is not the image's.
    """
    from PIL import Image

    if isinstance(pipe_or_model_id, (str, Path)):
        pipe = load_pipeline(pipe_or_model_id, pipeline=pipeline, device=device, dtype=dtype)
    else:
        pipe = pipe_or_model_id
        if device is not None or dtype is not None:
            dev = resolve_device(
                device if device is not None else pipe.device,
                unavailable="no CUDA GPU is available on this machine; set model.device=cpu (device='cpu')",
            )
            pipe = pipe.to(dev, parse_dtype(dtype) or pipe.dtype)
    H, W = i_minus.shape[-2:]
    mask = np.asarray(mask, bool)
    if mask.shape != (H, W):
        raise ValueError(f"mask of shape {mask.shape} for an image of {H}x{W}")
    settings = call_settings(pipe, steps, guidance)
    img = Image.fromarray((np.clip(bchw_to_hwc(i_minus), 0, 1) * 255).round().astype(np.uint8))
    m = Image.fromarray(mask.astype(np.uint8) * 255)
    out = pipe(
        prompt=prompt,
        image=img,
        mask_image=m,
        height=int(H),
        width=int(W),
        generator=_generator(pipe, seed),
        output_type="np",
        **settings.call_kwargs(),
    ).images
    res = _to_tensor(out, (H, W), pipe)
    return (res, settings) if return_settings else res
