"""Where a diffusers pipeline's weights are, how large they are, and how the pipeline runs on a
device they may not fit (:func:`offload_mode`).

Convention:
    - A model is a local folder or a Hugging Face id in the local cache (:func:`local_folder`); the
      cache is only read, never filled.
    - Sizes are the bytes of the weight files (``.safetensors``, ``.bin``) of each component
      sub-folder: the weights' size in device memory when loaded in the dtype they are stored in.
    - A budget is bytes of device memory the weights may take; ``None`` is no limit.
"""

from __future__ import annotations

from pathlib import Path

import torch

__all__ = ["OFFLOAD_MODES", "device_budget", "folder_component_bytes", "local_folder", "offload_mode"]

#: Offload modes of :func:`offload_mode`, in the order they trade speed for memory.
OFFLOAD_MODES = ("none", "model", "sequential")


def offload_mode(component_bytes: dict[str, int], budget_bytes: int | None) -> str:
    """How a pipeline runs on a device with ``budget_bytes`` for weights.

    Convention: ``none`` (every component on the device: their sum fits), ``model`` (diffusers'
    ``enable_model_cpu_offload``: one component on the device at a time, the largest fits; each
    moves in once per call), ``sequential`` (``enable_sequential_cpu_offload``: layer by layer,
    when even the largest component does not fit; slow). ``budget_bytes=None``: no limit.

    Args:
        component_bytes: bytes of each component's weights (``{"transformer": ..., ...}``).
        budget_bytes: the device memory the weights may take.

    Returns:
        One of :data:`OFFLOAD_MODES`.

    Examples:
        >>> gb = 10**9
        >>> flux2 = {"transformer": 64 * gb, "text_encoder": 48 * gb, "vae": gb // 5}
        >>> offload_mode(flux2, 139 * gb), offload_mode(flux2, 80 * gb), offload_mode(flux2, 40 * gb)
        ('none', 'model', 'sequential')
    """
    if budget_bytes is None or sum(component_bytes.values()) <= budget_bytes:
        return "none"
    return "model" if max(component_bytes.values(), default=0) <= budget_bytes else "sequential"


def folder_component_bytes(folder: str | Path) -> dict[str, int]:
    """Bytes of the weight files of each component sub-folder of a diffusers folder (the weights'
    size in device memory when loaded in the dtype they are stored in).

    Args:
        folder: a diffusers folder.

    Returns:
        ``{sub-folder name: bytes}``, in name order, for the sub-folders that hold weight files.
    """
    out = {}
    for sub in sorted(Path(folder).iterdir()):
        if sub.is_dir():
            n = sum(p.stat().st_size for p in sub.iterdir() if p.name.endswith((".safetensors", ".bin")))
            if n:
                out[sub.name] = n
    return out


def local_folder(model_id: str) -> str | None:
    """The folder of a local path or of a Hugging Face id in the cache, or ``None``.

    Args:
        model_id: a local folder or a Hugging Face id.

    Returns:
        The folder, or ``None`` when it is neither a folder nor in the Hugging Face cache.
    """
    path = Path(model_id).expanduser()
    if path.is_dir():
        return str(path)
    try:
        from huggingface_hub import snapshot_download

        return snapshot_download(repo_id=model_id, local_files_only=True)
    except Exception:  # noqa: BLE001 - not cached: from_pretrained says why
        return None


def device_budget(dev: torch.device, memory_gb: float | None) -> int | None:
    """The bytes of weights a pipeline may hold on ``dev``: ``memory_gb`` GiB, else (CUDA) 90 % of
    the device's memory, else no limit.

    Args:
        dev: the device the pipeline runs on.
        memory_gb: the device memory (GiB) the weights may take (config key ``models.memory_gb``),
            or ``None``.

    Returns:
        The budget in bytes, or ``None`` for no limit.
    """
    if memory_gb is not None:
        return int(float(memory_gb) * 2**30)
    if dev.type == "cuda":
        return int(0.9 * torch.cuda.get_device_properties(dev).total_memory)
    return None
