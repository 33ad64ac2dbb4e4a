"""The files that define a cell: its inputs written beside its results, so anyone can re-render or
re-score it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from snell_bench.pipeline import CellInputs

__all__ = ["save_inputs"]


def save_inputs(inputs: CellInputs, folder: Path, *, arrays: bool = False) -> dict[str, Path]:
    """Write the inputs that define a cell into ``folder`` (atomically): ``I_minus.png``,
    ``depth.npy``, ``camera.json``, ``object.ply``, and where rendered ``reference.png``,
    ``mask.png``, ``unobserved.npy``, ``true.png``; with ``arrays`` also the float
    ``reference.npy`` and ``metric_mask.npy``. Returns ``{file name: path}`` of the files a cell
    links (not the arrays)."""
    from snell_bench.utils.io import atomic_write_bytes, save_npy, save_png, write_json

    folder.mkdir(parents=True, exist_ok=True)
    obj, sc = inputs.obj, inputs.scene
    files = {
        "I_minus.png": save_png(folder / "I_minus.png", sc.image),
        "depth.npy": save_npy(folder / "depth.npy", sc.depth.astype(np.float32)),
        "camera.json": write_json(
            folder / "camera.json",
            dict(sc.camera.to_dict(), ior=obj.ior, object=obj.name, up=obj.up.tolist() if obj.up is not None else None),
        ),
        "object.ply": atomic_write_bytes(folder / "object.ply", obj.mesh.export(file_type="ply")),
    }
    ref = inputs.reference
    if ref is not None:
        files["reference.png"] = save_png(folder / "reference.png", ref.image)
        files["mask.png"] = save_png(folder / "mask.png", ref.mask.astype(np.float32))
        save_npy(folder / "unobserved.npy", ref.unobserved.astype(np.float16))
        if arrays:
            save_npy(folder / "reference.npy", np.asarray(ref.image, np.float32))
            save_npy(folder / "metric_mask.npy", np.asarray(ref.mask, bool))
    if inputs.true_render is not None:
        files["true.png"] = save_png(folder / "true.png", inputs.true_render)
    return files
