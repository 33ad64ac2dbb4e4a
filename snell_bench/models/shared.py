"""Modules that several pipelines load from identical weights, held once per process.

FLUX.1 Fill [dev] and FLUX.1 Kontext [dev] ship FLUX.1 [dev]'s text encoders (CLIP-L, T5-XXL) and
VAE unchanged: ~10 GB of each one's ~34 GB in bfloat16. A pipeline loaded after another one with the
same component weights takes the loaded module instead of reading and holding a second copy.

Convention:
    - A component's identity is the content of its weight files, not its name: in the Hugging Face
      cache a file is a link to ``blobs/<sha256>`` (the hub's content hash of a large file), which
      is read from the link; a file in a plain folder is hashed (SHA-256, once per process and
      file version). Random-weight components (:mod:`snell_bench.models.flux_random`) are
      identified by what drew them: ``("random", component, seed)``.
    - A module is shared only on the same device and in the same dtype (the key carries both).
    - The registry holds modules weakly: it never keeps one alive; a module lives as long as a
      pipeline (or a pool) holds it.
"""

from __future__ import annotations

import hashlib
import json
import os
import weakref
from collections.abc import Hashable, Iterable
from pathlib import Path
from typing import Any

import torch

__all__ = [
    "SHARED_COMPONENTS",
    "component_digest",
    "folder_identities",
    "shared_kwargs",
    "register_components",
    "random_key",
    "clear",
]

#: The pipeline components FLUX.1's variants share when their weights are the same.
SHARED_COMPONENTS = ("text_encoder", "text_encoder_2", "vae")
_WEIGHT_SUFFIXES = (".safetensors", ".bin")

_LIVE: weakref.WeakValueDictionary = weakref.WeakValueDictionary()
_HASHES: dict[tuple, str] = {}


def _file_digest(path: Path) -> str:
    real = Path(os.path.realpath(path))
    if real.parent.name == "blobs" and len(real.name) == 64:  # the hub's content hash of the file
        return real.name
    st = real.stat()
    key = (str(real), st.st_size, st.st_mtime_ns)
    if key not in _HASHES:
        h = hashlib.sha256()
        with open(real, "rb") as f:
            for block in iter(lambda: f.read(1 << 24), b""):
                h.update(block)
        _HASHES[key] = h.hexdigest()
    return _HASHES[key]


def component_digest(folder: str | os.PathLike, component: str) -> str | None:
    """A digest of the weight files of ``folder/component`` (names and contents), or ``None`` when
    it has none.

    Args:
        folder: a diffusers pipeline folder (a local folder or a cached snapshot).
        component: a sub-folder, e.g. ``"vae"``.
    """
    sub = Path(folder) / component
    if not sub.is_dir():
        return None
    files = sorted(p for p in sub.iterdir() if p.name.endswith(_WEIGHT_SUFFIXES))
    if not files:
        return None
    return hashlib.sha256(json.dumps([(p.name, _file_digest(p)) for p in files]).encode()).hexdigest()[:32]


def random_key(component: str, seed: int) -> tuple:
    """The identity of a random-weight component drawn from ``seed``."""
    return ("random", component, int(seed))


def _key(identity: Hashable, device: torch.device | str, dtype: torch.dtype) -> tuple:
    return (identity, str(torch.device(device)), str(dtype))


def shared_kwargs(
    identities: dict[str, Hashable | None], device: torch.device | str, dtype: torch.dtype
) -> dict[str, torch.nn.Module]:
    """The loaded modules with these identities (``{component: identity}``) on ``device`` in
    ``dtype``, as ``from_pretrained`` keyword arguments (components not loaded yet are left out)."""
    out = {}
    for name, identity in identities.items():
        if identity is None:
            continue
        module = _LIVE.get(_key(identity, device, dtype))
        if module is not None:
            out[name] = module
    return out


def register_components(
    pipe: Any, identities: dict[str, Hashable | None], device: torch.device | str, dtype: torch.dtype
) -> None:
    """Make ``pipe``'s components (``{component: identity}``) available to later loads."""
    for name, identity in identities.items():
        module = getattr(pipe, name, None)
        if identity is not None and isinstance(module, torch.nn.Module):
            _LIVE[_key(identity, device, dtype)] = module


def folder_identities(folder: str | os.PathLike, components: Iterable[str] = SHARED_COMPONENTS) -> dict:
    """``{component: component_digest(folder, component)}``."""
    return {c: component_digest(folder, c) for c in components}


def clear() -> None:
    """Forget every registered module (tests)."""
    _LIVE.clear()
