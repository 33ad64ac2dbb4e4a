"""Where FLUX.1's pipelines come from: weights in a local folder or the Hugging Face cache (never
downloaded), or FLUX.1's architecture at full size with random weights; and the device FLUX runs on.

Convention:
    - A weights location is a local folder with the diffusers layout (``model_index.json`` and the
      :data:`FLUX_COMPONENTS` sub-folders) or a Hugging Face id (``owner/name``) looked up in the
      local cache only; anything missing raises
      :class:`~snell_bench.models.errors.WeightsNotFoundError` naming the config key ``model.path``.
    - CUDA is the default device; a missing GPU raises
      :class:`~snell_bench.models.errors.DeviceNotAvailableError` naming ``model.device=cpu``.
    - Random-weight pipelines share their text encoders and VAE with one of another kind built in
      the same process with the same seed, device and dtype (:mod:`snell_bench.models.shared`).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import torch

from .devices import resolve_device as _resolve_device
from .errors import WeightsNotFoundError

__all__ = [
    "FLUX_COMPONENTS",
    "FLUX_DEV_ID",
    "random_flux_pipeline",
    "resolve_device",
    "resolve_weights_folder",
    "weights_help",
]

#: The Hugging Face id of FLUX.1-dev (gated: the licence must be accepted on the hub).
FLUX_DEV_ID = "black-forest-labs/FLUX.1-dev"
#: Sub-folders of a diffusers FLUX layout.
FLUX_COMPONENTS = ("scheduler", "text_encoder", "text_encoder_2", "tokenizer", "tokenizer_2", "transformer", "vae")

_REPO_ID = re.compile(r"^[A-Za-z0-9][\w.-]*/[\w.-]+$")


def weights_help(what: str) -> str:
    """The message of a :class:`~snell_bench.models.errors.WeightsNotFoundError` for FLUX weights.

    Args:
        what: what is missing (a folder, a cache entry, a failed load).

    Returns:
        The message: ``what``, the config key ``model.path`` and how to get the weights.
    """
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


def resolve_weights_folder(
    model_id_or_path: str | os.PathLike, *, local_files_only: bool = True, revision: str | None = None
) -> str:
    """The local folder of a diffusers FLUX pipeline, from a folder path or a Hugging Face id.

    Convention:
        - An existing folder must contain ``model_index.json``.
        - A hub id (``owner/name``, not an existing path) is looked up in the Hugging Face cache only
          (``HF_HOME`` / ``HF_HUB_CACHE`` are honoured); with ``local_files_only=False`` the id is
          returned unchanged and diffusers may download it.

    Args:
        model_id_or_path: a local folder or a Hugging Face id (config key ``model.path``).
        local_files_only: look a hub id up in the local cache only.
        revision: the hub revision to look up.

    Returns:
        The folder (or, with ``local_files_only=False``, possibly the hub id itself).

    Raises:
        WeightsNotFoundError: naming the config key ``model.path``, when the folder or the cached
            snapshot is missing or has no ``model_index.json``.
    """
    text = os.fspath(model_id_or_path)
    path = Path(text).expanduser()
    if path.is_dir():
        if not (path / "model_index.json").is_file():
            raise WeightsNotFoundError(weights_help(f"the folder {str(path)!r} has no model_index.json"))
        return str(path)
    if path.exists():
        raise WeightsNotFoundError(weights_help(f"{str(path)!r} is a file, not a diffusers folder"))
    if not _REPO_ID.match(text):
        raise WeightsNotFoundError(weights_help(f"no folder {text!r}"))
    if not local_files_only:
        return text
    from huggingface_hub import snapshot_download

    try:
        folder = snapshot_download(repo_id=text, revision=revision, local_files_only=True)
    except Exception as err:  # LocalEntryNotFoundError, HFValidationError, OSError, ...
        raise WeightsNotFoundError(
            weights_help(f"{text!r} is not in the Hugging Face cache ({type(err).__name__})")
        ) from err
    if not (Path(folder) / "model_index.json").is_file():
        raise WeightsNotFoundError(weights_help(f"the cached snapshot {folder!r} has no model_index.json"))
    return folder


def resolve_device(device: str | torch.device | None) -> torch.device:
    """The device FLUX runs on: ``None`` / ``"auto"`` / ``"cuda[:i]"`` need CUDA; ``"cpu"`` forces the CPU.

    Args:
        device: the requested device (config key ``model.device``).

    Returns:
        The device.

    Raises:
        DeviceNotAvailableError: naming the config key ``model.device``, when CUDA is asked for
            (explicitly or by default) and missing.
    """
    return _resolve_device(
        device,
        unavailable=(
            "FLUX.1-dev needs a CUDA GPU (its weights are ~34 GB in bfloat16) and none is available on this "
            "machine. Run on a machine with a GPU, or set the config key model.device=cpu to run it on the CPU "
            "anyway (float32, ~70 GB of RAM, minutes per model call). The tests use the tiny random model "
            "(model=tiny_flux) instead."
        ),
    )


def random_flux_pipeline(kind: str, *, device: torch.device, dtype: torch.dtype, seed: int = 0):
    """A FLUX.1 pipeline of ``kind`` (``dev``, ``fill``, ``kontext``) at full size with random
    weights (:mod:`snell_bench.models.flux_random`), on ``device`` in ``dtype``, sharing the text
    encoders and VAE of one of another kind built in this process with the same seed, device and
    dtype (:mod:`snell_bench.models.shared`).

    Args:
        kind: ``"dev"``, ``"fill"`` or ``"kontext"``.
        device: where the weights are made (``meta``: none are materialised).
        dtype: their dtype.
        seed: seeds the random weights.

    Returns:
        The pipeline (``random_weights`` set).
    """
    from . import shared
    from .flux_random import build_random_flux_pipeline

    identities = {c: shared.random_key(c, seed) for c in shared.SHARED_COMPONENTS}
    found = shared.shared_kwargs(identities, device, dtype)
    donor = None
    if len(found) == len(identities):
        donor = _Donor(found)
    pipe = build_random_flux_pipeline(kind, device=device, dtype=dtype, seed=seed, shared=donor)
    shared.register_components(pipe, identities, device, dtype)
    return pipe


class _Donor:
    """The shared text encoders and VAE, with the (file-less, rebuilt) tokenizers."""

    def __init__(self, modules: dict) -> None:
        from .tiny_text import clip_tokenizer_from_open_clip_vocab, t5_byte_tokenizer

        self.__dict__.update(modules)
        self.tokenizer = clip_tokenizer_from_open_clip_vocab()
        self.tokenizer_2 = t5_byte_tokenizer()
