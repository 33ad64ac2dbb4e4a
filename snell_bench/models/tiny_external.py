"""Tiny random-weight versions of the text-to-image baselines, built offline from configs in code.

:func:`build_tiny_pipeline` returns a ``Flux2Pipeline`` (FLUX.2-dev), a ``QwenImagePipeline``
(Qwen-Image) or a ``StableDiffusion3Pipeline`` (SD3.5-Large) with the real pipeline's component
classes, wiring and latent geometry, only far smaller, so that
:func:`~snell_bench.models.external.generate_external` runs each of them on a CPU in well under a
second, through ``save_pretrained`` and ``from_pretrained(..., local_files_only=True)`` exactly as
with the real weights. The images mean nothing: the weights are random.

Convention:
    - Built deterministically from ``seed`` inside :func:`torch.random.fork_rng`: the caller's global
      RNG state is left untouched, and two builds with the same seed have identical weights.
    - Every module is in ``.eval()`` mode with ``requires_grad`` off; the pipeline is on the CPU in
      float32.
    - Image sizes must be multiples of 16 (a VAE downscale of 8 and 2x2 latent patches), as for the
      real models; 32 x 48 is a good test size.
    - No file is downloaded. Tokenizers are byte-level BPE tokenizers over the 256 byte symbols plus
      the special tokens each prompt format needs, with merges that make every word of the
      pipeline's fixed prompt text one token; SD3's CLIP tokenizers are
      :func:`~snell_bench.models.tiny_text.clip_tokenizer_from_open_clip_vocab` (OpenAI CLIP's real
      vocabulary), its T5 tokenizer is the file-less ``ByT5Tokenizer``
      (:func:`~snell_bench.models.tiny_text.t5_byte_tokenizer`).
    - FLUX.2: the ``tokenizer`` component is a ``PixtralProcessor`` (as in FLUX.2-dev) with a
      Mistral-style chat template (``[SYSTEM_PROMPT]...[/SYSTEM_PROMPT][INST]...[/INST]``); the text
      encoder is a ``Mistral3ForConditionalGeneration`` with 30 decoder layers, because the
      pipeline stacks the hidden states of layers 10, 20 and 30 by default.
    - Qwen-Image: the prompt template's fixed prefix (system message and ``<|im_start|>user``)
      tokenizes to exactly ``prompt_template_encode_start_idx`` (34) tokens, as with the real
      Qwen2 tokenizer, so the prompt embedding starts at the user's prompt.
"""

from __future__ import annotations

import re

import torch

from .tiny_flux import build_tiny_flux_pipeline
from .tiny_text import clip_tokenizer_from_open_clip_vocab, t5_byte_tokenizer, tiny_clip_text_encoder, tiny_t5_encoder

__all__ = ["TINY_KINDS", "QWEN_IMAGE_PROMPT_TEMPLATE", "build_tiny_pipeline", "byte_level_symbols"]

#: The kinds :func:`build_tiny_pipeline` builds, with the diffusers pipeline class of each.
TINY_KINDS: dict[str, str] = {
    "flux2": "Flux2Pipeline",
    "qwen_image": "QwenImagePipeline",
    "sd3": "StableDiffusion3Pipeline",
    "flux": "FluxPipeline",
    "flux_fill": "FluxFillPipeline",
}

#: ``QwenImagePipeline.prompt_template_encode`` (diffusers 0.42): the tiny tokenizer's merges make
#: its fixed parts single tokens.
QWEN_IMAGE_PROMPT_TEMPLATE = (
    "<|im_start|>system\nDescribe the image by detailing the color, shape, size, texture, quantity, text, spatial "
    "relationships of the objects and background:<|im_end|>\n<|im_start|>user\n{}<|im_end|>\n<|im_start|>assistant\n"
)

_QWEN_SPECIAL_TOKENS = (
    "<|endoftext|>",
    "<|im_start|>",
    "<|im_end|>",
    "<|vision_start|>",
    "<|vision_end|>",
    "<|image_pad|>",
    "<|video_pad|>",
)
_MISTRAL_SPECIAL_TOKENS = (
    "<unk>",
    "<s>",
    "</s>",
    "<pad>",
    "[INST]",
    "[/INST]",
    "[SYSTEM_PROMPT]",
    "[/SYSTEM_PROMPT]",
    "[IMG]",
    "[IMG_BREAK]",
    "[IMG_END]",
)
#: A Mistral-style chat template for text and image messages (content as a string or as a list of
#: ``{"type": "text" | "image", ...}`` items).
_MISTRAL_CHAT_TEMPLATE = (
    "{{ bos_token }}{% for message in messages %}"
    "{% if message['content'] is string %}{% set text = message['content'] %}"
    "{% else %}{% set ns = namespace(text='') %}{% for item in message['content'] %}"
    "{% if item['type'] == 'text' %}{% set ns.text = ns.text + item['text'] %}"
    "{% elif item['type'] == 'image' %}{% set ns.text = ns.text + '[IMG]' %}{% endif %}"
    "{% endfor %}{% set text = ns.text %}{% endif %}"
    "{% if message['role'] == 'system' %}[SYSTEM_PROMPT]{{ text }}[/SYSTEM_PROMPT]"
    "{% elif message['role'] == 'user' %}[INST]{{ text }}[/INST]"
    "{% else %}{{ text }}{{ eos_token }}{% endif %}{% endfor %}"
)


def byte_level_symbols() -> list[str]:
    """The 256 byte symbols of byte-level BPE (GPT-2's ``bytes_to_unicode`` table), in byte order.

    Convention:
        - Printable Latin-1 bytes map to themselves; the others to ``chr(256 + i)`` in order, e.g.
          the space to ``"Ġ"`` and the newline to ``"Ċ"``.

    Returns:
        ``symbols[b]`` is the symbol of byte ``b``.
    """
    printable = [*range(ord("!"), ord("~") + 1), *range(ord("¡"), ord("¬") + 1), *range(ord("®"), ord("ÿ") + 1)]
    table, extra = {}, 0
    for b in range(256):
        if b in printable:
            table[b] = chr(b)
        else:
            table[b] = chr(256 + extra)
            extra += 1
    return [table[b] for b in range(256)]


def _vocab_and_merges(specials, pre_tokenizer, texts) -> tuple[dict[str, int], list[tuple[str, str]]]:
    """A byte-level BPE vocabulary: ``specials``, the 256 byte symbols, and merges that join every
    pre-token of ``texts`` (split around the special tokens) left to right into one token."""
    vocab = {tok: i for i, tok in enumerate(specials)}
    for symbol in byte_level_symbols():
        vocab.setdefault(symbol, len(vocab))
    merges: list[tuple[str, str]] = []
    split = re.compile("(" + "|".join(re.escape(t) for t in specials) + ")")
    for text in texts:
        for piece in split.split(text):
            if not piece or piece in specials:
                continue
            for word, _ in pre_tokenizer.pre_tokenize_str(piece):
                for i in range(1, len(word)):
                    if word[: i + 1] not in vocab:
                        merges.append((word[:i], word[i]))
                        vocab[word[: i + 1]] = len(vocab)
    return vocab, merges


def _qwen_tokenizer():
    """A ``Qwen2Tokenizer`` (Qwen's pre-tokenizer, byte-level BPE) whose merges cover the fixed text
    of :data:`QWEN_IMAGE_PROMPT_TEMPLATE`."""
    from transformers import Qwen2Tokenizer

    extra = list(_QWEN_SPECIAL_TOKENS[1:])
    bare = Qwen2Tokenizer(vocab={_QWEN_SPECIAL_TOKENS[0]: 0}, merges=[])
    vocab, merges = _vocab_and_merges(
        _QWEN_SPECIAL_TOKENS, bare.backend_tokenizer.pre_tokenizer, QWEN_IMAGE_PROMPT_TEMPLATE.split("{}")
    )
    return Qwen2Tokenizer(vocab=vocab, merges=merges, extra_special_tokens=extra)


def _mistral_processor():
    """A ``PixtralProcessor``: a byte-level BPE tokenizer with Mistral's special tokens (merges over
    FLUX.2's system message), a Pixtral image processor and a Mistral-style chat template."""
    from diffusers.pipelines.flux2.system_messages import SYSTEM_MESSAGE
    from tokenizers import AddedToken, Tokenizer, decoders, models, pre_tokenizers
    from transformers import PixtralImageProcessor, PixtralProcessor, PreTrainedTokenizerFast

    pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    vocab, merges = _vocab_and_merges(_MISTRAL_SPECIAL_TOKENS, pre_tokenizer, [SYSTEM_MESSAGE])
    backend = Tokenizer(models.BPE(vocab=vocab, merges=merges, unk_token="<unk>"))
    backend.pre_tokenizer = pre_tokenizer
    backend.decoder = decoders.ByteLevel()
    backend.add_special_tokens([AddedToken(t, special=True, normalized=False) for t in _MISTRAL_SPECIAL_TOKENS])
    tokenizer = PreTrainedTokenizerFast(
        tokenizer_object=backend, bos_token="<s>", eos_token="</s>", unk_token="<unk>", pad_token="<pad>"
    )
    image_processor = PixtralImageProcessor(patch_size=16, size={"longest_edge": 64})
    return PixtralProcessor(
        image_processor=image_processor,
        tokenizer=tokenizer,
        patch_size=16,
        spatial_merge_size=2,
        chat_template=_MISTRAL_CHAT_TEMPLATE,
    )


def _tiny_flux2(seed: int):
    from diffusers import AutoencoderKLFlux2, FlowMatchEulerDiscreteScheduler, Flux2Pipeline, Flux2Transformer2DModel
    from transformers import Mistral3Config, Mistral3ForConditionalGeneration

    processor = _mistral_processor()
    tok = processor.tokenizer
    width = 16  # the text encoder's hidden size; the transformer reads 3 stacked layers
    config = Mistral3Config(
        text_config={
            "model_type": "mistral",
            "vocab_size": len(tok),
            "hidden_size": width,
            "intermediate_size": 32,
            "head_dim": 8,
            "num_attention_heads": 2,
            "num_key_value_heads": 1,
            "num_hidden_layers": 30,
            "max_position_embeddings": 1024,
            "rms_norm_eps": 1e-5,
            "rope_theta": 1e9,
            "sliding_window": None,
            "bos_token_id": tok.bos_token_id,
            "eos_token_id": tok.eos_token_id,
            "pad_token_id": tok.pad_token_id,
        },
        vision_config={
            "model_type": "pixtral",
            "hidden_size": 16,
            "intermediate_size": 32,
            "num_hidden_layers": 1,
            "num_attention_heads": 2,
            "head_dim": 8,
            "image_size": 64,
            "patch_size": 16,
            "num_channels": 3,
        },
        image_token_index=tok.convert_tokens_to_ids("[IMG]"),
        spatial_merge_size=2,
        vision_feature_layer=-1,
    )
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        text_encoder = Mistral3ForConditionalGeneration(config)
        transformer = Flux2Transformer2DModel(
            patch_size=1,
            in_channels=128,  # 32 latent channels x 2x2 patches
            num_layers=1,
            num_single_layers=1,
            attention_head_dim=16,
            num_attention_heads=2,
            joint_attention_dim=3 * width,
            timestep_guidance_channels=256,
            axes_dims_rope=(4, 4, 4, 4),
        )
        vae = AutoencoderKLFlux2(
            block_out_channels=(8, 16, 16, 16),
            layers_per_block=1,
            latent_channels=32,
            norm_num_groups=4,
            use_quant_conv=False,
            use_post_quant_conv=False,
        )
    scheduler = FlowMatchEulerDiscreteScheduler(
        shift=3.0,
        use_dynamic_shifting=True,
        base_shift=0.5,
        max_shift=1.15,
        base_image_seq_len=256,
        max_image_seq_len=4096,
        time_shift_type="exponential",
    )
    _freeze(text_encoder, transformer, vae)
    return Flux2Pipeline(
        scheduler=scheduler, vae=vae, text_encoder=text_encoder, tokenizer=processor, transformer=transformer
    )


def _tiny_qwen_image(seed: int):
    from diffusers import (
        AutoencoderKLQwenImage,
        FlowMatchEulerDiscreteScheduler,
        QwenImagePipeline,
        QwenImageTransformer2DModel,
    )
    from transformers import Qwen2_5_VLConfig, Qwen2_5_VLForConditionalGeneration

    tok = _qwen_tokenizer()
    width = 16
    config = Qwen2_5_VLConfig(
        text_config={
            "vocab_size": len(tok),
            "hidden_size": width,
            "intermediate_size": 32,
            "num_hidden_layers": 2,
            "num_attention_heads": 2,
            "num_key_value_heads": 1,
            "max_position_embeddings": 2048,
            # multimodal RoPE: the sections sum to head_dim / 2 = 4
            "rope_scaling": {"mrope_section": [1, 1, 2], "rope_type": "default", "type": "default"},
            "rope_theta": 1e6,
            "bos_token_id": None,
            "eos_token_id": tok.eos_token_id,
            "pad_token_id": tok.pad_token_id,
        },
        vision_config={
            "depth": 1,
            "hidden_size": 16,
            "intermediate_size": 32,
            "num_heads": 2,
            "out_hidden_size": width,
            "patch_size": 14,
            "spatial_merge_size": 2,
            "temporal_patch_size": 2,
            "window_size": 112,
            "fullatt_block_indexes": [0],
        },
        image_token_id=tok.convert_tokens_to_ids("<|image_pad|>"),
        video_token_id=tok.convert_tokens_to_ids("<|video_pad|>"),
        vision_start_token_id=tok.convert_tokens_to_ids("<|vision_start|>"),
        vision_end_token_id=tok.convert_tokens_to_ids("<|vision_end|>"),
    )
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        text_encoder = Qwen2_5_VLForConditionalGeneration(config)
        transformer = QwenImageTransformer2DModel(
            patch_size=2,
            in_channels=64,  # 16 latent channels x 2x2 patches
            out_channels=16,
            num_layers=1,
            attention_head_dim=16,
            num_attention_heads=2,
            joint_attention_dim=width,
            guidance_embeds=False,
            axes_dims_rope=(4, 6, 6),
        )
        vae = AutoencoderKLQwenImage(
            base_dim=8,
            z_dim=16,
            dim_mult=[1, 2, 4, 4],
            num_res_blocks=1,
            temperal_downsample=[False, True, True],
        )
    scheduler = FlowMatchEulerDiscreteScheduler(
        shift=1.0,
        shift_terminal=0.02,
        use_dynamic_shifting=True,
        base_shift=0.5,
        max_shift=0.9,
        base_image_seq_len=256,
        max_image_seq_len=8192,
        time_shift_type="exponential",
    )
    _freeze(text_encoder, transformer, vae)
    return QwenImagePipeline(
        scheduler=scheduler, vae=vae, text_encoder=text_encoder, tokenizer=tok, transformer=transformer
    )


def _tiny_sd3(seed: int):
    from diffusers import (
        AutoencoderKL,
        FlowMatchEulerDiscreteScheduler,
        SD3Transformer2DModel,
        StableDiffusion3Pipeline,
    )

    clip_tok = clip_tokenizer_from_open_clip_vocab()
    t5_tok = t5_byte_tokenizer()
    clip_widths = (16, 24)  # CLIP-L and CLIP-G (768 and 1280 in SD3.5)
    t5_width = 48  # the two CLIP embeddings (40 wide) are zero-padded to it, as 2048 to 4096 in SD3.5

    def clip(width: int, act: str):
        return tiny_clip_text_encoder(
            clip_tok, width, intermediate_size=2 * width, num_heads=2, hidden_act=act, with_projection=True
        )

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        text_encoder = clip(clip_widths[0], "quick_gelu")
        text_encoder_2 = clip(clip_widths[1], "gelu")
        text_encoder_3 = tiny_t5_encoder(t5_tok, t5_width, d_ff=64, num_heads=2)
        transformer = SD3Transformer2DModel(
            sample_size=32,
            patch_size=2,
            in_channels=16,
            num_layers=2,
            attention_head_dim=8,
            num_attention_heads=4,
            joint_attention_dim=t5_width,
            caption_projection_dim=32,
            pooled_projection_dim=sum(clip_widths),
            out_channels=16,
            pos_embed_max_size=32,
            qk_norm="rms_norm",
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
            scaling_factor=1.5305,
            shift_factor=0.0609,
            use_quant_conv=False,
            use_post_quant_conv=False,
        )
    scheduler = FlowMatchEulerDiscreteScheduler(shift=3.0)
    _freeze(text_encoder, text_encoder_2, text_encoder_3, transformer, vae)
    return StableDiffusion3Pipeline(
        transformer=transformer,
        scheduler=scheduler,
        vae=vae,
        text_encoder=text_encoder,
        tokenizer=clip_tok,
        text_encoder_2=text_encoder_2,
        tokenizer_2=clip_tok,
        text_encoder_3=text_encoder_3,
        tokenizer_3=t5_tok,
    )


def _freeze(*modules: torch.nn.Module) -> None:
    for module in modules:
        module.eval().requires_grad_(False)


def build_tiny_pipeline(kind: str, seed: int = 0):
    """A diffusers pipeline of ``kind`` with the real model's architecture at toy size and random weights.

    Convention:
        - ``flux2`` (``Flux2Pipeline``, as FLUX.2-dev): ``Flux2Transformer2DModel`` (128 input
          channels = 32 latent channels x 2x2, 1 double + 1 single block, 2 heads of 16, RoPE axes
          (4, 4, 4, 4), guidance-embedded); ``AutoencoderKLFlux2`` (32 latent channels, downscale 8,
          channels (8, 16, 16, 16)); a ``Mistral3ForConditionalGeneration`` text encoder (width 16,
          30 layers, a 1-layer Pixtral vision tower) and a ``PixtralProcessor``; the scheduler
          FLUX.2-dev's (``FlowMatchEulerDiscreteScheduler``, dynamic exponential shifting).
        - ``qwen_image`` (``QwenImagePipeline``, as Qwen-Image): ``QwenImageTransformer2DModel``
          (64 input channels = 16 x 2x2, 1 block, 2 heads of 16, text width 16);
          ``AutoencoderKLQwenImage`` (16 latent channels, base width 8, downscale 8); a
          ``Qwen2_5_VLForConditionalGeneration`` text encoder (width 16, 2 layers, multimodal RoPE)
          and a ``Qwen2Tokenizer``; the scheduler Qwen-Image's (``shift_terminal`` 0.02, dynamic
          exponential shifting).
        - ``sd3`` (``StableDiffusion3Pipeline``, as SD3.5-Large): ``SD3Transformer2DModel`` (16
          latent channels, patch 2, 2 layers, 4 heads of 8, RMS q/k norm); ``AutoencoderKL`` (16
          latent channels, downscale 8, SD3's scaling 1.5305 / shift 0.0609); two
          ``CLIPTextModelWithProjection`` (widths 16 and 24) on CLIP's vocabulary and a T5 encoder
          (width 48) on ByT5 bytes; ``FlowMatchEulerDiscreteScheduler(shift=3.0)``.
        - ``flux`` / ``flux_fill``: :func:`~snell_bench.models.tiny_flux.build_tiny_flux_pipeline`
          (``FluxPipeline`` / ``FluxFillPipeline``).
        - Weights are drawn from ``torch.manual_seed(seed)`` in a forked RNG (the global RNG is left
          as it was); the pipeline is on the CPU in float32, every module in eval mode.

    Args:
        kind: one of :data:`TINY_KINDS`.
        seed: seeds the random weights.

    Returns:
        The pipeline. ``save_pretrained`` writes a folder that
        ``<PipelineClass>.from_pretrained(folder, local_files_only=True)`` (and
        :func:`~snell_bench.models.external.load_pipeline`) loads back unchanged.

    Raises:
        ValueError: for an unknown ``kind``.
    """
    if kind in ("flux", "flux_fill"):
        return build_tiny_flux_pipeline(seed, fill=kind == "flux_fill")
    builders = {"flux2": _tiny_flux2, "qwen_image": _tiny_qwen_image, "sd3": _tiny_sd3}
    if kind not in builders:
        raise ValueError(f"unknown tiny pipeline kind {kind!r}; use one of {sorted(TINY_KINDS)}")
    return builders[kind](int(seed))
