"""The files that define a cell: its inputs written beside its results, so anyone can re-render or
re-score it, and a group's inputs kept between the passes and processes of a sweep.

- ``_inputs/`` of a group: ``I_minus.png``, ``depth.npy``, ``camera.json`` (with a photo's
  original size and resize), ``object.ply`` (:func:`save_scene_files`), ``reference.png``, ``mask.png``, ``unobserved.npy``, ``true.png``
  (:func:`save_reference_files`), hard-linked into each cell; the two sets can be written apart, by
  the process that computed each (:mod:`snell_bench.experiment.prefetch`).
- ``_inputs/inputs-<hash>.pkl``: the group's inputs as computed (:func:`keep_inputs`,
  :func:`read_inputs`), named by the hash of the settings they were computed with
  (:func:`inputs_file`), read back by the model-major order
  (:mod:`snell_bench.experiment.order`); worker processes hand stages 1-3 over the same way in
  ``sampling-<hash>.pkl``.
"""

from __future__ import annotations

import logging
import pickle
from dataclasses import replace
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from snell_bench.experiment.cells import Cell
from snell_bench.experiment.input_content import input_content
from snell_bench.experiment.plan import result_settings, settings_hash
from snell_bench.pipeline import CellInputs
from snell_bench.utils.io import atomic_write, atomic_write_bytes, save_npy, save_png, write_json
from snell_bench.utils.trust import read_signed, signed

log = logging.getLogger(__name__)

__all__ = [
    "save_inputs",
    "keeps_arrays",
    "save_scene_files",
    "save_reference_files",
    "inputs_settings",
    "inputs_file",
    "read_inputs",
    "keep_inputs",
]


def save_scene_files(inputs: CellInputs, folder: Path) -> dict[str, Path]:
    """Write ``I_minus.png``, ``depth.npy``, ``camera.json`` and ``object.ply`` of ``inputs`` into
    ``folder`` (atomically). ``camera.json`` holds the camera of I⁻ as used (``K``, ``width``,
    ``height``), the object's IOR, name and up direction, and for a photo what was done to it
    (``photo``: its size as stored, its EXIF orientation, ``scene.max_side`` and the size it was
    resized to: :func:`~snell_bench.scene.image_source.photo_info`). Returns ``{file name: path}``."""
    folder.mkdir(parents=True, exist_ok=True)
    obj, sc = inputs.obj, inputs.scene
    photo = {"photo": sc.info} if "original_size" in (sc.info or {}) else {}
    return {
        "I_minus.png": save_png(folder / "I_minus.png", sc.image),
        "depth.npy": save_npy(folder / "depth.npy", sc.depth.astype(np.float32)),
        "camera.json": write_json(
            folder / "camera.json",
            dict(
                sc.camera.to_dict(),
                ior=obj.ior,
                object=obj.name,
                up=obj.up.tolist() if obj.up is not None else None,
                **photo,
            ),
        ),
        "object.ply": atomic_write_bytes(folder / "object.ply", obj.mesh.export(file_type="ply")),
    }


def save_reference_files(ref, true_render, folder: Path, *, arrays: bool = False) -> dict[str, Path]:
    """Write what was rendered of a cell's references into ``folder`` (atomically): of the
    reference ``ref`` (a :class:`~snell_bench.render.ReferenceRender` or ``None``) ``reference.png``,
    ``mask.png``, ``unobserved.npy``, with ``arrays`` also the float ``reference.npy`` and
    ``metric_mask.npy``; of the true render ``true_render`` (``(H, W, 3)`` sRGB or ``None``)
    ``true.png``. Returns ``{file name: path}`` of the files a cell links (not the arrays, nor
    ``unobserved.npy``)."""
    folder.mkdir(parents=True, exist_ok=True)
    files = {}
    if ref is not None:
        files["reference.png"] = save_png(folder / "reference.png", ref.image)
        files["mask.png"] = save_png(folder / "mask.png", ref.mask.astype(np.float32))
        save_npy(folder / "unobserved.npy", ref.unobserved.astype(np.float16))
        if arrays:
            save_npy(folder / "reference.npy", np.asarray(ref.image, np.float32))
            save_npy(folder / "metric_mask.npy", np.asarray(ref.mask, bool))
    if true_render is not None:
        files["true.png"] = save_png(folder / "true.png", true_render)
    return files


def keeps_arrays(cfg: DictConfig) -> bool:
    """Whether a cell's inputs keep the float reference and metric mask beside the PNGs: in a grid
    with settings (``grid.axes``, ``grid.presets``), whose report compares the references of its
    reference-sample settings (:func:`~snell_bench.reports.tradeoff.reference_psnr_vs_max_spp`)."""
    return bool(OmegaConf.select(cfg, "grid.axes", default=None) or OmegaConf.select(cfg, "grid.presets", default=None))


def save_inputs(inputs: CellInputs, folder: Path, *, arrays: bool = False) -> dict[str, Path]:
    """Write the inputs that define a cell into ``folder`` (atomically): ``I_minus.png``,
    ``depth.npy``, ``camera.json``, ``object.ply`` (:func:`save_scene_files`), and where rendered
    ``reference.png``, ``mask.png``, ``unobserved.npy``, ``true.png`` (:func:`save_reference_files`);
    with ``arrays`` also the float ``reference.npy`` and ``metric_mask.npy``. Returns ``{file name:
    path}`` of the files a cell links (not the arrays)."""
    refs = save_reference_files(inputs.reference, inputs.true_render, folder, arrays=arrays)
    return {**save_scene_files(inputs, folder), **refs}


# ---------------------------------------------------------------------------- kept inputs
def inputs_settings(cfg: DictConfig) -> dict:
    """The settings a group's inputs are computed with: the cell's
    :func:`~snell_bench.experiment.plan.result_settings` without the method's keys, which stages
    1-5 do not read (every method of a group shares its inputs), nor ``grid.converged_spp`` (the
    converged references are kept apart, :mod:`~snell_bench.experiment.converged`); with the content
    of the input files (:func:`~snell_bench.experiment.input_content.input_content`), so inputs kept
    from a photo or mesh since changed are not read back."""
    settings = {**result_settings(cfg), **input_content(cfg)}
    return {k: v for k, v in settings.items() if not k.startswith(("method.", "grid."))}


def inputs_file(cell: Cell) -> Path:
    """Where the group inputs of ``cell`` are kept: ``<group>/_inputs/inputs-<hash>.pkl``, the
    hash of their :func:`inputs_settings`."""
    key = settings_hash(inputs_settings(cell.extra["inputs_config"]))
    return Path(cell.shares) / "_inputs" / f"inputs-{key}.pkl"


def read_inputs(path: Path) -> tuple[CellInputs, dict[str, Path]] | None:
    """The group inputs kept at ``path`` (:func:`keep_inputs`) and their files beside it, or
    ``None`` when there is no such file, it cannot be read (logged), or a file it lists is gone.
    The inputs have no model pool: give them the reader's (``inputs.pool = pool``)."""
    if not path.exists() and not path.is_symlink():
        return None
    payload, problem = read_signed(path)  # a pickle runs code: loaded only when this user signed it
    if problem is not None:
        log.warning("%s; computing the inputs again", problem)
        return None
    try:
        kept = pickle.loads(payload)  # noqa: S301 - signed by this user (utils.trust.signed)
        inputs, files = kept["inputs"], {name: path.parent / name for name in kept["files"]}
    except Exception as e:  # noqa: BLE001 - any unreadable pickle: computed again
        log.warning("%s cannot be read (%s: %s); computing the inputs again", path, type(e).__name__, e)
        return None
    return (inputs, files) if all(p.is_file() for p in files.values()) else None


def keep_inputs(inputs: CellInputs, files: dict[str, Path], path: Path) -> None:
    """Keep ``inputs`` (without their model pool) and the names of their ``files`` at ``path``
    (``<kind>-<hash>.pkl``, atomically), for :func:`read_inputs`; files of the same kind and other
    settings in that folder are removed."""
    kind = path.name.rsplit("-", 1)[0]
    for old in path.parent.glob(f"{kind}-*.pkl"):
        if old != path:
            old.unlink(missing_ok=True)
    kept = {"inputs": replace(inputs, pool=None), "files": sorted(files)}
    atomic_write(path, lambda f: f.write(signed(pickle.dumps(kept, protocol=5))), binary=True)
