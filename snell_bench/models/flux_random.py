"""FLUX.1 [dev], Fill [dev] and Kontext [dev] at their real size with random weights, built from
their published configurations in code (no file read, nothing downloaded): real shapes and real
cost, meaningless pixels. They make a GPU node measurable without weights (``model.random_init``,
``benchmarks/bench_gpu.py``) and let the test suite run the full-size loop on the ``meta`` device.

Convention:
    - Every module is built on the ``meta`` device (no memory, no time), cast to ``dtype`` there,
      and only then materialised on ``device`` (``Module.to_empty``), so a 12 B transformer never
      exists in float32 on the host. On ``meta`` nothing is materialised: the modules have shapes,
      dtypes and parameter counts, and every forward pass propagates shapes only.
    - Materialised weights are drawn in place on the target device from ``seed`` (one
      ``torch.Generator`` on that device, parameters in their registration order): matrices and
      kernels uniform in ``±1/sqrt(fan_in)`` (torch's default ``Linear`` / ``Conv`` bound), 1-D
      ``weight`` parameters (norm scales) 1, biases and every other 1-D parameter 0, so activations
      stay finite in bfloat16 through all 57 blocks. The only buffers, ``position_ids`` of the CLIP
      embeddings, are rebuilt as ``arange``; any other buffer is an error (it would hold garbage).
    - The tokenizers are real but file-less (:mod:`snell_bench.models.tiny_text`): CLIP's BPE
      vocabulary from open_clip, and ByT5's bytes on the T5 side (ids < 384, inside T5's 32128):
      the 77 CLIP and 512 T5 tokens the model sees have the real count.
    - Fill and Kontext share FLUX.1-dev's text encoders and VAE (the released checkpoints ship the
      same weights): built with ``shared=`` a pipeline, they take its modules instead of new ones.
    - Every pipeline built here carries ``random_weights = True``.

Sizes (parameters, bfloat16 bytes): transformer 11.9 B (23.8 GB), T5-XXL encoder 4.76 B (9.5 GB),
CLIP-L text 123 M (0.25 GB), VAE 84 M (0.17 GB): 33.7 GB for FLUX.1-dev; Fill's transformer reads
384 channels instead of 64 (+4 M parameters); Kontext's is FLUX.1-dev's.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import torch

__all__ = [
    "FLUX_DEV_TRANSFORMER",
    "FLUX_FILL_TRANSFORMER",
    "FLUX_VAE",
    "FLUX_SCHEDULER",
    "T5_XXL_ENCODER",
    "CLIP_L_TEXT",
    "KINDS",
    "random_module",
    "build_random_flux_pipeline",
]

#: ``black-forest-labs/FLUX.1-dev/transformer/config.json`` (``FluxTransformer2DModel``).
FLUX_DEV_TRANSFORMER: dict[str, Any] = dict(
    patch_size=1,
    in_channels=64,
    out_channels=None,
    num_layers=19,
    num_single_layers=38,
    attention_head_dim=128,
    num_attention_heads=24,
    joint_attention_dim=4096,
    pooled_projection_dim=768,
    guidance_embeds=True,
    axes_dims_rope=(16, 56, 56),
)
#: FLUX.1-Fill-dev's transformer: the packed latents (64), the packed latents of the masked image
#: (64) and the 8 x 8 pixel mask per latent pixel packed into 2 x 2 patches (256) in, 64 out.
FLUX_FILL_TRANSFORMER: dict[str, Any] = {**FLUX_DEV_TRANSFORMER, "in_channels": 384, "out_channels": 64}
#: ``FLUX.1-dev/vae/config.json`` (``AutoencoderKL``).
FLUX_VAE: dict[str, Any] = dict(
    in_channels=3,
    out_channels=3,
    down_block_types=("DownEncoderBlock2D",) * 4,
    up_block_types=("UpDecoderBlock2D",) * 4,
    block_out_channels=(128, 256, 512, 512),
    layers_per_block=2,
    act_fn="silu",
    latent_channels=16,
    norm_num_groups=32,
    sample_size=1024,
    scaling_factor=0.3611,
    shift_factor=0.1159,
    force_upcast=True,
    use_quant_conv=False,
    use_post_quant_conv=False,
    mid_block_add_attention=True,
)
#: ``FLUX.1-dev/scheduler/scheduler_config.json`` (``FlowMatchEulerDiscreteScheduler``).
FLUX_SCHEDULER: dict[str, Any] = dict(
    num_train_timesteps=1000,
    shift=3.0,
    use_dynamic_shifting=True,
    base_shift=0.5,
    max_shift=1.15,
    base_image_seq_len=256,
    max_image_seq_len=4096,
)
#: ``FLUX.1-dev/text_encoder_2/config.json``: the encoder of Google's T5 v1.1 XXL.
T5_XXL_ENCODER: dict[str, Any] = dict(
    vocab_size=32128,
    d_model=4096,
    d_kv=64,
    d_ff=10240,
    num_layers=24,
    num_heads=64,
    relative_attention_num_buckets=32,
    relative_attention_max_distance=128,
    dropout_rate=0.1,
    layer_norm_epsilon=1e-6,
    feed_forward_proj="gated-gelu",
    tie_word_embeddings=False,
    is_encoder_decoder=False,
    use_cache=False,
)
#: ``FLUX.1-dev/text_encoder/config.json``: OpenAI CLIP ViT-L/14's text tower.
CLIP_L_TEXT: dict[str, Any] = dict(
    vocab_size=49408,
    hidden_size=768,
    intermediate_size=3072,
    projection_dim=768,
    num_hidden_layers=12,
    num_attention_heads=12,
    max_position_embeddings=77,
    hidden_act="quick_gelu",
    layer_norm_eps=1e-5,
    pad_token_id=1,
    bos_token_id=0,
    eos_token_id=2,
)

#: The pipelines :func:`build_random_flux_pipeline` builds.
KINDS = ("dev", "fill", "kontext")


def _check_buffers(module: torch.nn.Module) -> list[str]:
    bad = [n for n, _ in module.named_buffers() if not n.endswith("position_ids")]
    if bad:
        raise RuntimeError(
            f"{type(module).__name__} has buffers {bad[:4]} that random initialisation cannot rebuild; "
            "extend snell_bench.models.flux_random._init_ to set them"
        )
    return bad


@torch.no_grad()
def _init_(module: torch.nn.Module, generator: torch.Generator) -> None:
    """Draw ``module``'s (materialised, uninitialised) parameters in place; see the module docs."""
    for name, p in module.named_parameters():
        if p.ndim >= 2:
            bound = 1.0 / math.sqrt(max(1, p[0].numel()))
            p.uniform_(-bound, bound, generator=generator)
        elif name.endswith("weight"):
            p.fill_(1.0)
        else:
            p.zero_()
    for _, b in module.named_buffers():  # position_ids (checked in random_module)
        b.copy_(torch.arange(b.shape[-1], device=b.device, dtype=b.dtype).expand_as(b))


def random_module(
    build: Callable[[], torch.nn.Module],
    *,
    device: str | torch.device = "meta",
    dtype: torch.dtype = torch.bfloat16,
    seed: int = 0,
) -> torch.nn.Module:
    """``build()`` on the ``meta`` device, cast to ``dtype``, materialised on ``device`` with random
    weights drawn from ``seed`` (nothing materialised when ``device`` is ``meta``); in eval mode,
    without gradients.

    Args:
        build: constructs the module (called under ``torch.device("meta")``).
        device: where the weights live.
        dtype: their dtype.
        seed: seeds the draws (a generator on ``device``).

    Returns:
        The module.

    Raises:
        RuntimeError: if the module has buffers other than ``position_ids``.
    """
    with torch.device("meta"):
        module = build()
    _check_buffers(module)
    # torch's own cast: floating tensors only (the integer position ids stay), without the warning
    # diffusers gives for casting a module it did not load
    module = torch.nn.Module.to(module, dtype).eval().requires_grad_(False)
    device = torch.device(device)
    if device.type != "meta":
        module = module.to_empty(device=device)
        _init_(module, torch.Generator(device).manual_seed(int(seed)))
    return module


def _transformer(config: dict) -> Callable[[], torch.nn.Module]:
    from diffusers import FluxTransformer2DModel

    return lambda: FluxTransformer2DModel(**config)


def _vae() -> torch.nn.Module:
    from diffusers import AutoencoderKL

    return AutoencoderKL(**FLUX_VAE)


def _t5() -> torch.nn.Module:
    from transformers import T5Config, T5EncoderModel

    return T5EncoderModel(T5Config(**T5_XXL_ENCODER))


def _clip() -> torch.nn.Module:
    from transformers import CLIPTextConfig, CLIPTextModel

    return CLIPTextModel(CLIPTextConfig(**CLIP_L_TEXT))


def build_random_flux_pipeline(
    kind: str = "dev",
    *,
    device: str | torch.device = "meta",
    dtype: torch.dtype = torch.bfloat16,
    seed: int = 0,
    shared: Any = None,
    transformer: dict | None = None,
):
    """A ``FluxPipeline`` (``kind="dev"``), ``FluxFillPipeline`` (``"fill"``) or
    ``FluxKontextPipeline`` (``"kontext"``) at FLUX.1's real size with random weights.

    Args:
        kind: one of :data:`KINDS`.
        device: where the weights are materialised (``meta``: nowhere).
        dtype: the weights' dtype (bfloat16: the released checkpoints').
        seed: seeds the weights; the transformer, VAE, T5 and CLIP draw from ``seed``, ``seed + 1``,
            ``seed + 2``, ``seed + 3``.
        shared: a pipeline whose text encoders, tokenizers and VAE are reused (the released Fill and
            Kontext checkpoints ship FLUX.1-dev's); ``None``: new ones.
        transformer: overrides of the transformer's configuration (e.g. fewer blocks for a test).

    Returns:
        The pipeline, with ``random_weights = True``.

    Raises:
        ValueError: for an unknown kind.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown FLUX pipeline kind {kind!r}; expected one of {KINDS}")
    from diffusers import FlowMatchEulerDiscreteScheduler, FluxFillPipeline, FluxKontextPipeline, FluxPipeline

    from .tiny_text import clip_tokenizer_from_open_clip_vocab, t5_byte_tokenizer

    config = {**(FLUX_FILL_TRANSFORMER if kind == "fill" else FLUX_DEV_TRANSFORMER), **(transformer or {})}
    kw = dict(device=device, dtype=dtype)
    if shared is not None:
        parts = {k: getattr(shared, k) for k in ("vae", "text_encoder", "text_encoder_2", "tokenizer", "tokenizer_2")}
    else:
        parts = dict(
            vae=random_module(_vae, seed=seed + 1, **kw),
            text_encoder_2=random_module(_t5, seed=seed + 2, **kw),
            text_encoder=random_module(_clip, seed=seed + 3, **kw),
            tokenizer=clip_tokenizer_from_open_clip_vocab(),
            tokenizer_2=t5_byte_tokenizer(),
        )
    cls = {"dev": FluxPipeline, "fill": FluxFillPipeline, "kontext": FluxKontextPipeline}[kind]
    pipe = cls(
        scheduler=FlowMatchEulerDiscreteScheduler(**FLUX_SCHEDULER),
        transformer=random_module(_transformer(config), seed=seed, **kw),
        **parts,
    )
    pipe.random_weights = True
    return pipe
