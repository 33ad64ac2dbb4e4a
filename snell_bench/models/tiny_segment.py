"""A tiny SAM 3 with random weights, built offline from configs in code (for tests).

It has SAM 3's architecture (ViT backbone with an FPN neck, CLIP text encoder, geometry encoder,
DETR encoder and decoder, mask decoder) at toy size, so every code path of
:class:`~snell_bench.models.segment.Sam3Segmenter` runs on a CPU in milliseconds
(:class:`~snell_bench.models.segment.TinySam3Segmenter`). Its masks mean nothing: the weights are
random.

Convention:
    - Built deterministically from ``seed`` inside :func:`torch.random.fork_rng`: the caller's global
      RNG state is left untouched, and two builds with the same seed have identical weights.
    - The model is in eval mode (modules built from configs start in train mode), on the CPU, float32.
    - No file is downloaded: the tokenizer is CLIP's, written from open_clip's shipped vocabulary
      (:func:`~snell_bench.models.tiny_text.clip_tokenizer_from_open_clip_vocab`).
    - transformers is imported only when a model is built.
"""

from __future__ import annotations

from typing import Any

from .tiny_text import clip_tokenizer_from_open_clip_vocab

__all__ = ["tiny_sam3", "tiny_sam3_config"]

#: The tiny SAM 3's input size (square, as SAM 3's 1008 x 1008) and ViT patch size (SAM 3's).
_TINY_IMAGE_SIZE = 56
_TINY_PATCH_SIZE = 14


def tiny_sam3_config(vocab_size: int) -> Any:
    """The ``Sam3Config`` of :func:`tiny_sam3` (its convention lists the sizes).

    Args:
        vocab_size: the text encoder's vocabulary (the tokenizer's length: CLIP's 49408).

    Returns:
        The config.
    """
    from transformers import Sam3Config
    from transformers.models.sam3.configuration_sam3 import (
        Sam3DETRDecoderConfig,
        Sam3DETREncoderConfig,
        Sam3GeometryEncoderConfig,
        Sam3MaskDecoderConfig,
        Sam3VisionConfig,
        Sam3ViTConfig,
    )

    width, heads, ff = 8, 2, 16
    tokens = _TINY_IMAGE_SIZE // _TINY_PATCH_SIZE
    return Sam3Config(
        vision_config=Sam3VisionConfig(
            backbone_config=Sam3ViTConfig(
                hidden_size=width,
                intermediate_size=ff,
                num_hidden_layers=2,
                num_attention_heads=heads,
                image_size=_TINY_IMAGE_SIZE,
                pretrain_image_size=_TINY_IMAGE_SIZE,
                patch_size=_TINY_PATCH_SIZE,
                window_size=2,
                global_attn_indexes=[1],
            ),
            fpn_hidden_size=width,
            scale_factors=[4.0, 2.0, 1.0, 0.5],
            backbone_feature_sizes=[[4 * tokens] * 2, [2 * tokens] * 2, [tokens] * 2],
        ),
        text_config={
            "vocab_size": vocab_size,
            "hidden_size": width,
            "intermediate_size": ff,
            "projection_dim": width,
            "num_hidden_layers": 1,
            "num_attention_heads": heads,
            "max_position_embeddings": 32,
            "hidden_act": "gelu",
        },
        geometry_encoder_config=Sam3GeometryEncoderConfig(
            hidden_size=width, num_layers=1, num_attention_heads=heads, intermediate_size=ff
        ),
        detr_encoder_config=Sam3DETREncoderConfig(
            hidden_size=width, num_layers=1, num_attention_heads=heads, intermediate_size=ff
        ),
        detr_decoder_config=Sam3DETRDecoderConfig(
            hidden_size=width, num_layers=1, num_queries=4, num_attention_heads=heads, intermediate_size=ff
        ),
        mask_decoder_config=Sam3MaskDecoderConfig(
            hidden_size=width, num_upsampling_stages=2, num_attention_heads=heads
        ),
    )


def tiny_sam3(seed: int = 0):
    """A ``Sam3Model`` with SAM 3's architecture at toy size and random weights, and its processor,
    built offline.

    Convention:
        - Vision: ViT with SAM 3's patch size 14 on a 56 x 56 input (4 x 4 tokens), width 8, 2 heads,
          2 layers (one windowed with window 2, one global), axial RoPE; FPN neck of width 8 at SAM 3's
          scales (4, 2, 1, 0.5).
        - Text: CLIP text encoder (width 8, 2 heads, 1 layer) over CLIP's 49408-token vocabulary and
          32 positions (SAM 3's), tokenised by the CLIP tokenizer written from open_clip's vocabulary
          (:func:`~snell_bench.models.tiny_text.clip_tokenizer_from_open_clip_vocab`).
        - Geometry encoder, DETR encoder and decoder: width 8, 2 heads, 1 layer, feed-forward 16;
          4 queries. Mask decoder: width 8 (``GroupNorm(8, width)`` makes 8 the least), 2 upsampling
          stages (SAM 3 uses 2 of its 3 with three FPN levels); instance masks at 16 x 16.
        - Processor: ``Sam3ImageProcessor`` resizing to 56 x 56 (ImageNet normalisation, as SAM 3)
          and the CLIP tokenizer.
        - Weights come from ``torch.manual_seed(seed)`` in a forked RNG (the caller's RNG state is
          untouched); the model is in eval mode, on the CPU, float32.

    Args:
        seed: seeds the random weights.

    Returns:
        ``(model, processor)``.
    """
    import torch
    from transformers import Sam3Model, Sam3Processor
    from transformers.models.sam3 import Sam3ImageProcessor

    tokenizer = clip_tokenizer_from_open_clip_vocab()
    tokens = _TINY_IMAGE_SIZE // _TINY_PATCH_SIZE
    config = tiny_sam3_config(len(tokenizer))
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = Sam3Model(config)
    model.eval().requires_grad_(False)
    processor = Sam3Processor(
        image_processor=Sam3ImageProcessor(
            size={"height": _TINY_IMAGE_SIZE, "width": _TINY_IMAGE_SIZE},
            mask_size={"height": 4 * tokens, "width": 4 * tokens},
        ),
        tokenizer=tokenizer,
    )
    return model, processor
