"""The device memory a model's weights will take, known before it loads, so the model pool makes
room for exactly that (:class:`~snell_bench.pipeline.pool.ModelPool`, ``size=``).

Convention:
    - Bytes of parameters and buffers in the dtype they load in; activations not included.
    - FLUX.1 models (``FluxGenerator.from_pretrained``, ``load_pipeline``,
      ``KontextRelighter.from_pretrained``): with ``random_init``, the modules built on ``meta``
      (free) and counted; otherwise the weight files of the local folder or cached snapshot. The
      components already loaded in this process with the same weights (shared text encoders and
      VAE, :mod:`snell_bench.models.shared`) are not counted again.
    - Anything else: ``None`` (unknown; the pool then assumes the whole budget).
"""

from __future__ import annotations

from typing import Any

import torch

__all__ = ["node_weights_bytes"]

_FLUX_TARGETS = {
    "snell_bench.models.flux.FluxGenerator.from_pretrained": ("model_id_or_path", "dev"),
    "snell_bench.models.external.load_pipeline": ("model_id", None),
    "snell_bench.relight.kontext.KontextRelighter.from_pretrained": ("model_id", "kontext"),
}


def node_weights_bytes(node: Any) -> int | None:
    """The bytes a model built from a resolved config node (a mapping with ``_target_``) will add
    to device memory, or ``None`` when unknown (see the module docs)."""
    from omegaconf import DictConfig, OmegaConf

    from . import shared
    from .devices import default_dtype, parse_dtype, resolve_device
    from .external import RANDOM_KINDS
    from .flux_random import build_random_flux_pipeline
    from .offload import folder_component_bytes, local_folder

    if isinstance(node, DictConfig):
        node = OmegaConf.to_container(node, resolve=True)
    if not isinstance(node, dict) or node.get("_target_") not in _FLUX_TARGETS:
        return None
    id_key, kind = _FLUX_TARGETS[node["_target_"]]
    if kind is None:
        kind = RANDOM_KINDS.get(str(node.get("pipeline")))
    try:
        device = resolve_device(node.get("device"), unavailable="")
    except Exception:  # noqa: BLE001 - no device here: the load itself says why
        return None
    random_init = bool(node.get("random_init", False))
    dtype = parse_dtype(node.get("dtype")) or (torch.bfloat16 if random_init else default_dtype(device))
    if random_init:
        if kind is None:
            return None
        seed = int(node.get("seed", 0))
        identities = {c: shared.random_key(c, seed) for c in shared.SHARED_COMPONENTS}
        live = shared.shared_kwargs(identities, device, dtype)
        pipe = build_random_flux_pipeline(kind, device="meta", dtype=dtype, seed=seed)
        parts = ["transformer", *(c for c in shared.SHARED_COMPONENTS if c not in live)]
        return sum(
            t.numel() * t.element_size()
            for c in parts
            for m in [getattr(pipe, c)]
            for t in (*m.parameters(), *m.buffers())
        )
    folder = local_folder(str(node.get(id_key)))
    if folder is None:
        return None
    sizes = folder_component_bytes(folder)
    live = shared.shared_kwargs(shared.folder_identities(folder), device, dtype)
    return sum(n for c, n in sizes.items() if c not in live)
