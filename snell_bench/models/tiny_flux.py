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
    - No file is downloaded. The T5 side uses the byte-level ``ByT5Tokenizer`` (no vocabulary file);
      the CLIP side uses a ``CLIPTokenizer`` written from open_clip's shipped BPE vocabulary
      (``bpe_simple_vocab_16e6.txt.gz``) into ``$SNELL_BENCH_CACHE/clip_bpe_tokenizer`` (default
      ``~/.cache/snell_bench``; a temporary folder if that is not writable), once per machine.
    - The VAE's ``sample_size`` is 1024, as in FLUX.1-dev, so VAE tiling starts at the same image size.
"""

from __future__ import annotations

import functools
import gzip
import importlib.util
import json
import os
import tempfile
from pathlib import Path

import torch

from snell_bench.utils.io import write_text

from .flux import FluxGenerator

__all__ = ["TinyFluxGenerator", "build_tiny_flux_pipeline", "clip_tokenizer_from_open_clip_vocab"]

#: FLUX.1-dev's VAE latent normalisation.
FLUX_VAE_SCALING_FACTOR = 0.3611
FLUX_VAE_SHIFT_FACTOR = 0.1159

#: CLIP's BPE vocabulary: 256 byte symbols, 256 end-of-word byte symbols, 48894 merges, 2 specials.
_CLIP_NUM_MERGES = 49152 - 256 - 2
_CLIP_VOCAB_SIZE = 49408
_CLIP_BOS, _CLIP_EOS = "<|startoftext|>", "<|endoftext|>"
_TOKENIZER_FOLDER_NAME = "clip_bpe_tokenizer"
#: FLUX Fill's transformer input: packed latents (16 x 4) + packed masked-image latents (16 x 4)
#: + the packed pixel mask (8 x 8 per latent pixel, x 4).
_FILL_IN_CHANNELS = 16 * 4 + 16 * 4 + 8 * 8 * 4


def _open_clip_bpe_path() -> Path:
    spec = importlib.util.find_spec("open_clip")  # locates the package without importing it
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError("open_clip_torch is not installed: it ships the CLIP BPE vocabulary for the tiny FLUX")
    path = Path(list(spec.submodule_search_locations)[0]) / "bpe_simple_vocab_16e6.txt.gz"
    if not path.is_file():
        raise RuntimeError(f"open_clip's BPE vocabulary is missing: {path}")
    return path


def _cache_root() -> Path:
    root = os.environ.get("SNELL_BENCH_CACHE")
    return Path(root).expanduser() if root else Path.home() / ".cache" / "snell_bench"


def _write_clip_tokenizer_files(folder: Path) -> None:
    """Write ``vocab.json`` and ``merges.txt`` (Hugging Face CLIP format) from open_clip's BPE file.

    Each file is written atomically (:func:`~snell_bench.utils.io.write_text`), so concurrent
    writers never expose a partial file.

    Args:
        folder: the target folder (created if missing).

    Raises:
        OSError: if the folder or a file cannot be written.
        RuntimeError: if open_clip or its vocabulary is missing.
    """
    bpe_path = _open_clip_bpe_path()
    from open_clip.tokenizer import bytes_to_unicode

    with gzip.open(bpe_path) as f:
        lines = f.read().decode("utf-8").split("\n")
    merges = lines[1 : _CLIP_NUM_MERGES + 1]
    symbols = list(bytes_to_unicode().values())
    vocab = symbols + [s + "</w>" for s in symbols] + ["".join(m.split()) for m in merges] + [_CLIP_BOS, _CLIP_EOS]
    assert len(vocab) == _CLIP_VOCAB_SIZE, len(vocab)
    folder.mkdir(parents=True, exist_ok=True)
    contents = {
        "vocab.json": json.dumps({tok: i for i, tok in enumerate(vocab)}, ensure_ascii=False),
        "merges.txt": "#version: 0.2\n" + "\n".join(merges) + "\n",
    }
    for name, text in contents.items():
        write_text(folder / name, text)


def _clip_tokenizer_folder() -> Path:
    """The folder holding the CLIP tokenizer files, written on first use."""
    candidates = [
        _cache_root() / _TOKENIZER_FOLDER_NAME,
        Path(tempfile.gettempdir()) / f"snell_bench_{_TOKENIZER_FOLDER_NAME}",
    ]
    for folder in candidates:
        if (folder / "vocab.json").is_file() and (folder / "merges.txt").is_file():
            return folder
        try:
            _write_clip_tokenizer_files(folder)
            return folder
        except OSError:
            continue
    raise RuntimeError(f"could not write the CLIP tokenizer files to any of {[str(c) for c in candidates]}")


@functools.lru_cache(maxsize=1)
def clip_tokenizer_from_open_clip_vocab():
    """A ``CLIPTokenizer`` equal to OpenAI CLIP's, built without a download (memoized: tokenizers
    are not modified by encoding, so one instance is shared)."""
    from transformers import CLIPTokenizer

    return CLIPTokenizer.from_pretrained(str(_clip_tokenizer_folder()), model_max_length=77)


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
        - Text: CLIP text model (width 32, projection 32, CLIP's 49408-token vocabulary, 77 tokens);
          T5 encoder (``d_model`` 32) over ByT5 bytes.
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
    from diffusers import (
        AutoencoderKL,
        FlowMatchEulerDiscreteScheduler,
        FluxFillPipeline,
        FluxKontextPipeline,
        FluxPipeline,
        FluxTransformer2DModel,
    )
    from transformers import ByT5Tokenizer, CLIPTextConfig, CLIPTextModel, T5Config, T5EncoderModel

    tokenizer = clip_tokenizer_from_open_clip_vocab()
    tokenizer_2 = ByT5Tokenizer()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        transformer = FluxTransformer2DModel(
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
        vae = AutoencoderKL(
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
        text_encoder = CLIPTextModel(
            CLIPTextConfig(
                vocab_size=_CLIP_VOCAB_SIZE,
                hidden_size=32,
                intermediate_size=37,
                projection_dim=32,
                num_hidden_layers=2,
                num_attention_heads=4,
                max_position_embeddings=77,
                hidden_act="quick_gelu",
                bos_token_id=tokenizer.bos_token_id,
                eos_token_id=tokenizer.eos_token_id,
                pad_token_id=tokenizer.pad_token_id,
            )
        )
        text_encoder_2 = T5EncoderModel(
            T5Config(
                vocab_size=len(tokenizer_2),
                d_model=32,
                d_kv=8,
                d_ff=37,
                num_layers=2,
                num_heads=4,
                relative_attention_num_buckets=8,
                relative_attention_max_distance=32,
                feed_forward_proj="gated-gelu",
                dropout_rate=0.0,
                is_encoder_decoder=False,
                pad_token_id=tokenizer_2.pad_token_id,
                eos_token_id=tokenizer_2.eos_token_id,
            )
        )
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
