"""Tiny random-weight text encoders and their tokenizers, built offline (for the tiny pipelines in tests).

The tokenizers are the real ones (OpenAI CLIP's byte-level BPE vocabulary, ByT5's bytes), so prompts
are split into tokens exactly as with the released models; the encoders have the real architectures
(CLIP's text transformer, T5's encoder) at toy width with random weights, so their embeddings mean
nothing.

Convention:
    - No file is downloaded. The CLIP tokenizer is a ``CLIPTokenizer`` written from open_clip's shipped
      BPE vocabulary (``bpe_simple_vocab_16e6.txt.gz``) into ``$SNELL_BENCH_CACHE/clip_bpe_tokenizer``
      (default ``~/.cache/snell_bench``; a temporary folder if that is not writable), once per machine;
      the T5 tokenizer is the file-less byte-level ``ByT5Tokenizer``.
    - The encoders draw their weights from torch's global RNG, in construction order: a caller that
      wants a reproducible model seeds it (``torch.manual_seed`` inside :func:`torch.random.fork_rng`,
      so the caller's own RNG state is left untouched) and builds its modules in a fixed order.
    - The encoders come back as constructed (train mode, gradients on); callers freeze them with
      ``.eval().requires_grad_(False)``.
    - transformers is imported only when an encoder or tokenizer is built.
"""

from __future__ import annotations

import functools
import gzip
import importlib.util
import json
import os
import tempfile
from pathlib import Path
from typing import Any

from snell_bench.utils.io import write_text

__all__ = [
    "CLIP_VOCAB_SIZE",
    "clip_tokenizer_from_open_clip_vocab",
    "t5_byte_tokenizer",
    "tiny_clip_text_encoder",
    "tiny_t5_encoder",
]

#: CLIP's BPE vocabulary: 256 byte symbols, 256 end-of-word byte symbols, 48894 merges, 2 specials.
CLIP_VOCAB_SIZE = 49408
_CLIP_NUM_MERGES = CLIP_VOCAB_SIZE - 256 - 256 - 2
_CLIP_BOS, _CLIP_EOS = "<|startoftext|>", "<|endoftext|>"
#: CLIP's context length (tokens, start and end of text included).
_CLIP_MAX_LENGTH = 77
_TOKENIZER_FOLDER_NAME = "clip_bpe_tokenizer"


# ---------------------------------------------------------------------------------------- tokenizers


def _open_clip_bpe_path() -> Path:
    spec = importlib.util.find_spec("open_clip")  # locates the package without importing it
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError("open_clip_torch is not installed: it ships the CLIP BPE vocabulary for the tiny models")
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
    assert len(vocab) == CLIP_VOCAB_SIZE, len(vocab)
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
    """A ``CLIPTokenizer`` equal to OpenAI CLIP's (:data:`CLIP_VOCAB_SIZE` tokens, 77 positions),
    built without a download (memoized: tokenizers are not modified by encoding, so one instance is
    shared)."""
    from transformers import CLIPTokenizer

    return CLIPTokenizer.from_pretrained(str(_clip_tokenizer_folder()), model_max_length=_CLIP_MAX_LENGTH)


def t5_byte_tokenizer():
    """T5's tokenizer side without a vocabulary file: the byte-level ``ByT5Tokenizer`` (384 tokens:
    3 specials, 256 bytes, 125 extra ids)."""
    from transformers import ByT5Tokenizer

    return ByT5Tokenizer()


# ---------------------------------------------------------------------------------------- encoders


def tiny_clip_text_encoder(
    tokenizer: Any,
    width: int,
    *,
    intermediate_size: int,
    num_heads: int,
    hidden_act: str = "quick_gelu",
    with_projection: bool = False,
):
    """CLIP's text transformer at toy width with random weights.

    Convention:
        - ``CLIPTextConfig``: ``hidden_size = projection_dim = width``, 2 layers, ``num_heads`` heads,
          77 positions, the vocabulary size and the start, end and padding ids of ``tokenizer``.
        - ``CLIPTextModel`` (last hidden state ``(B, 77, width)`` and pooled output ``(B, width)``, as
          FLUX reads it) or, with ``with_projection``, ``CLIPTextModelWithProjection`` (projected text
          embedding ``(B, width)``, as SD3 reads it).
        - Weights from torch's global RNG (see the module's convention).

    Args:
        tokenizer: a CLIP tokenizer (:func:`clip_tokenizer_from_open_clip_vocab`).
        width: the hidden and projection width.
        intermediate_size: the MLP width.
        num_heads: attention heads per layer (a divisor of ``width``).
        hidden_act: the MLP activation (``"quick_gelu"`` as CLIP-L, ``"gelu"`` as OpenCLIP bigG).
        with_projection: build ``CLIPTextModelWithProjection`` instead of ``CLIPTextModel``.

    Returns:
        The encoder, on the CPU in float32.
    """
    from transformers import CLIPTextConfig, CLIPTextModel, CLIPTextModelWithProjection

    config = CLIPTextConfig(
        vocab_size=len(tokenizer),
        hidden_size=width,
        intermediate_size=intermediate_size,
        projection_dim=width,
        num_hidden_layers=2,
        num_attention_heads=num_heads,
        max_position_embeddings=_CLIP_MAX_LENGTH,
        hidden_act=hidden_act,
        bos_token_id=tokenizer.bos_token_id,
        eos_token_id=tokenizer.eos_token_id,
        pad_token_id=tokenizer.pad_token_id,
    )
    return (CLIPTextModelWithProjection if with_projection else CLIPTextModel)(config)


def tiny_t5_encoder(tokenizer: Any, d_model: int, *, d_ff: int, num_heads: int):
    """T5's encoder (``T5EncoderModel``) at toy width with random weights.

    Convention:
        - ``T5Config``: ``d_model``, 2 layers of ``num_heads`` heads of width 8 (``d_kv``), gated-GELU
          feed-forward of width ``d_ff`` (as T5 v1.1 / T5-XXL), 8 relative-position buckets up to
          distance 32, no dropout, the vocabulary
          size and the padding and end ids of ``tokenizer``.
        - Output: last hidden state ``(B, L, d_model)``.
        - Weights from torch's global RNG (see the module's convention).

    Args:
        tokenizer: a T5 tokenizer (:func:`t5_byte_tokenizer`).
        d_model: the hidden width.
        d_ff: the feed-forward width.
        num_heads: attention heads per layer.

    Returns:
        The encoder, on the CPU in float32.
    """
    from transformers import T5Config, T5EncoderModel

    return T5EncoderModel(
        T5Config(
            vocab_size=len(tokenizer),
            d_model=d_model,
            d_kv=8,
            d_ff=d_ff,
            num_layers=2,
            num_heads=num_heads,
            relative_attention_num_buckets=8,
            relative_attention_max_distance=32,
            feed_forward_proj="gated-gelu",
            dropout_rate=0.0,
            is_encoder_decoder=False,
            pad_token_id=tokenizer.pad_token_id,
            eos_token_id=tokenizer.eos_token_id,
        )
    )
