"""A tiny FLUX pipeline with random weights, built offline from configs in code (for tests).

It has the architecture of FLUX.1-dev (a guidance-distilled ``FluxTransformer2DModel``, a 16-channel
``AutoencoderKL`` with downscale 8, a CLIP text encoder for the pooled embedding and a T5 encoder
for the token embeddings), only far smaller, so every code path of
:class:`~snell_bench.models.flux.FluxGenerator` runs on a CPU in milliseconds. Its outputs mean
nothing: the weights are random.

Convention:
    - Built deterministically from ``seed`` inside :func:`torch.random.fork_rng`: the caller's global
      RNG state is left untouched, and two builds with the same seed have identical weights.
    - Every module is in ``.eval()`` mode (modules built from configs start in train mode, and T5's
      dropout would otherwise randomise the embeddings).
    - No file is downloaded. Tokenizers and text encoders come from :mod:`snell_bench.models.tiny_text`:
      the byte-level ``ByT5Tokenizer`` (no vocabulary file) on the T5 side, a ``CLIPTokenizer`` written
      once per machine from open_clip's shipped BPE vocabulary on the CLIP side.
    - The VAE's ``sample_size`` is 1024, as in FLUX.1-dev, so VAE tiling starts at the same image size.
"""

from __future__ import annotations

import torch

from .flux import FluxGenerator
from .tiny_text import clip_tokenizer_from_open_clip_vocab, t5_byte_tokenizer, tiny_clip_text_encoder, tiny_t5_encoder

__all__ = ["TinyFluxGenerator", "build_tiny_flux_pipeline"]

#: FLUX.1-dev's VAE latent normalisation.
FLUX_VAE_SCALING_FACTOR = 0.3611
FLUX_VAE_SHIFT_FACTOR = 0.1159

#: FLUX Fill's transformer input: packed latents (16 x 4) + packed masked-image latents (16 x 4)
#: + the packed pixel mask (8 x 8 per latent pixel, x 4).
_FILL_IN_CHANNELS = 16 * 4 + 16 * 4 + 8 * 8 * 4


def build_tiny_flux_pipeline(seed: int = 0, *, fill: bool = False, kontext: bool = False):
    """A ``FluxPipeline`` (or ``FluxFillPipeline``, or ``FluxKontextPipeline``) with FLUX.1-dev's
    architecture at toy size and random weights.

    Convention:
        - Transformer: ``in_channels=64`` (16 latent channels x 2x2 patches), 1 double + 1 single
          block, 2 heads of 16, text width 32, pooled width 32, RoPE axes (4, 6, 6), guidance-embedded.
          The Fill variant (as FLUX.1-Fill-dev) reads ``in_channels = 64 + 64 + 256 = 384`` (the
          packed noisy latents, the packed latents of the masked image, and the 8x8 pixel mask per
          latent pixel packed into 2x2 patches) and writes ``out_channels=64``. The Kontext variant
          (as FLUX.1-Kontext-dev) has the plain 64-channel transformer: the packed latents of the
          context image are concatenated to the noisy ones along the sequence, not the channels.
        - VAE: 16 latent channels, 4 blocks (downscale 8), channels (8, 16, 16, 16), 4 norm groups,
          no quant convs, scaling 0.3611 / shift 0.1159 (FLUX.1-dev's values).
        - Text: CLIP text model (width 32, projection 32, MLP 37, 4 heads, CLIP's 49408-token
          vocabulary, 77 tokens); T5 encoder (``d_model`` 32, feed-forward 37, 4 heads) over ByT5 bytes
          (:func:`~snell_bench.models.tiny_text.tiny_clip_text_encoder`,
          :func:`~snell_bench.models.tiny_text.tiny_t5_encoder`).
        - Scheduler: ``FlowMatchEulerDiscreteScheduler`` with FLUX.1-dev's dynamic shifting
          (sequence lengths 256 / 4096, shifts 0.5 / 1.15).
        - Weights are drawn from ``torch.manual_seed(seed)`` in a forked RNG; every module is in eval mode.
          The plain and the Kontext variant of a seed share every weight (the same draws in the same
          order); only the pipeline class differs.

    Args:
        seed: seeds the random weights.
        fill: build a ``FluxFillPipeline`` (inpainting) instead of a ``FluxPipeline``.
        kontext: build a ``FluxKontextPipeline`` (image editing from a context image) instead.

    Returns:
        The pipeline, on the CPU in float32.

    Raises:
        ValueError: if both ``fill`` and ``kontext`` are set.
    """
    if fill and kontext:
        raise ValueError("build_tiny_flux_pipeline: choose fill=True or kontext=True, not both")
    from diffusers import FlowMatchEulerDiscreteScheduler, FluxFillPipeline, FluxKontextPipeline, FluxPipeline

    tokenizer = clip_tokenizer_from_open_clip_vocab()
    tokenizer_2 = t5_byte_tokenizer()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        transformer = _tiny_transformer(fill)
        vae = _tiny_vae()
        text_encoder = tiny_clip_text_encoder(tokenizer, 32, intermediate_size=37, num_heads=4)
        text_encoder_2 = tiny_t5_encoder(tokenizer_2, 32, d_ff=37, num_heads=4)
    scheduler = FlowMatchEulerDiscreteScheduler(
        base_image_seq_len=256,
        base_shift=0.5,
        max_image_seq_len=4096,
        max_shift=1.15,
        use_dynamic_shifting=True,
    )
    for module in (transformer, vae, text_encoder, text_encoder_2):
        module.eval().requires_grad_(False)
    pipeline_cls = FluxFillPipeline if fill else FluxKontextPipeline if kontext else FluxPipeline
    return pipeline_cls(
        scheduler=scheduler,
        vae=vae,
        text_encoder=text_encoder,
        tokenizer=tokenizer,
        text_encoder_2=text_encoder_2,
        tokenizer_2=tokenizer_2,
        transformer=transformer,
    )


def _tiny_transformer(fill: bool):
    """The tiny ``FluxTransformer2DModel`` of :func:`build_tiny_flux_pipeline` (FLUX Fill's input
    width with ``fill``), drawn from the global RNG (the caller seeds it and puts it in eval mode)."""
    from diffusers import FluxTransformer2DModel

    return FluxTransformer2DModel(
        patch_size=1,
        in_channels=_FILL_IN_CHANNELS if fill else 64,
        out_channels=64,
        num_layers=1,
        num_single_layers=1,
        attention_head_dim=16,
        num_attention_heads=2,
        joint_attention_dim=32,
        pooled_projection_dim=32,
        axes_dims_rope=(4, 6, 6),
        guidance_embeds=True,
    )


def _tiny_vae():
    """The tiny 16-channel ``AutoencoderKL`` of :func:`build_tiny_flux_pipeline` (downscale 8,
    FLUX.1-dev's ``sample_size`` and latent normalisation), drawn from the global RNG (the caller
    seeds it and puts it in eval mode)."""
    from diffusers import AutoencoderKL

    return AutoencoderKL(
        in_channels=3,
        out_channels=3,
        down_block_types=("DownEncoderBlock2D",) * 4,
        up_block_types=("UpDecoderBlock2D",) * 4,
        block_out_channels=(8, 16, 16, 16),
        layers_per_block=1,
        latent_channels=16,
        norm_num_groups=4,
        sample_size=1024,
        scaling_factor=FLUX_VAE_SCALING_FACTOR,
        shift_factor=FLUX_VAE_SHIFT_FACTOR,
        use_quant_conv=False,
        use_post_quant_conv=False,
    )


class TinyFluxGenerator(FluxGenerator):
    """:class:`FluxGenerator` around :func:`build_tiny_flux_pipeline` (CPU, float32 by default).

    Convention:
        - ``name == "tiny_flux"``; same geometry (16 channels, downscale 8, sizes multiple of 16),
          latent normalisation, packing, timestep, guidance and schedule conventions as FLUX.1-dev.
        - Outputs are deterministic functions of ``seed`` and the inputs; they mean nothing.

    Args:
        seed: seeds the random weights.
        device: where the model runs (``None``: the CPU).
        dtype: a dtype or its name (:func:`~snell_bench.models.devices.parse_dtype`); ``None``:
            bfloat16 on CUDA, float32 elsewhere.
        guidance: the default guidance scale.
        max_sequence_length: the T5 token count.
        vae_tiling: see :class:`FluxGenerator`.
        vae_slicing: see :class:`FluxGenerator`.
    """

    name = "tiny_flux"

    def __init__(
        self,
        seed: int = 0,
        *,
        device: str | torch.device | None = "cpu",
        dtype: torch.dtype | str | None = torch.float32,
        guidance: float = 3.5,
        max_sequence_length: int = 512,
        vae_tiling: bool = True,
        vae_slicing: bool = True,
    ):
        super().__init__(
            build_tiny_flux_pipeline(seed),
            device="cpu" if device is None else device,
            dtype=dtype,
            guidance=guidance,
            max_sequence_length=max_sequence_length,
            vae_tiling=vae_tiling,
            vae_slicing=vae_slicing,
        )
        self.seed = seed
