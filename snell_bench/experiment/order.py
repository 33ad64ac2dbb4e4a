"""The order a grid's cells run in, so that each model loads once per sweep.

Without a memory budget (``models.memory_gb: null``) every model stays loaded and cells run group
by group (scene x variation x object), each group's inputs computed once and dropped after its last
method. With a budget the models may not fit together, so the sweep runs *model-major*:

1. the inputs pass: every group's inputs (stages 1-5) are computed, with the models those stages
   need, and written to ``_inputs/inputs.pkl``; for generated scenes all I⁻ are generated first
   (cached in ``scene.cache_dir``) so the generator and the depth estimator load once each;
2. the sampling pass of relit cells: a cell that samples with the generator and relights with the
   relighter samples here, while the generator is loaded, and keeps its un-relit result beside it
   (``.unrelit.pt``, a hidden file);
3. the cells, ordered by the model they need last (generator, relighter, fill, each pipeline
   baseline, in order of first use), the group inputs read back from ``_inputs/inputs.pkl``.

Read back, the inputs are the very arrays a group computes (pickled), so results do not depend on
the order.
"""

from __future__ import annotations

import dataclasses
import logging
import pickle
from pathlib import Path

import torch
from omegaconf import DictConfig

from snell_bench.config import MethodKind, Source
from snell_bench.experiment.cells import Cell
from snell_bench.pipeline import CellInputs, CellResult, ModelPool, prepare_inputs, sample_stage
from snell_bench.pipeline.cell import cell_seed, node_key
from snell_bench.pipeline.inputs import generator_of
from snell_bench.scene import sources
from snell_bench.utils.io import atomic_write

log = logging.getLogger(__name__)

__all__ = [
    "cell_models",
    "model_major",
    "load_or_compute_inputs",
    "prepare_model_major",
    "take_unrelit",
    "INPUTS_FILE",
    "UNRELIT_FILE",
]

INPUTS_FILE = "inputs.pkl"
UNRELIT_FILE = ".unrelit.pt"


def cell_models(c: DictConfig) -> list[tuple[str, str]]:
    """``(kind, key)`` of the shared models one cell's method loads (stages 6-7b), in the order it
    uses them; a generator built from the scene (``model.from_scene``) is the group's own and is
    not listed."""
    kind = MethodKind(c.method.kind)
    out = []
    if kind is MethodKind.external:
        out.append(("pipeline", str(c.method.model_id)))
    elif kind is MethodKind.inpaint and c.model.get("fill"):
        out.append(("fill", node_key(c.model.fill)))
    elif not c.model.from_scene:
        out.append(("generator", node_key(c.model)))
    if c.method.relight and c.model.get("relighter"):
        out.append(("relighter", node_key(c.model.relighter)))
    return out


def model_major(cells: list[Cell]) -> list[Cell]:
    """``cells`` ordered by the model each needs last (in order of first use); stable otherwise."""
    rank: dict[tuple[str, str], int] = {}
    for cell in cells:
        for m in cell_models(cell.config):
            rank.setdefault(m, len(rank))
    last = {id(c): (rank[cell_models(c.config)[-1]] if cell_models(c.config) else -1) for c in cells}
    return sorted(cells, key=lambda c: last[id(c)])


def _save(path: Path, inputs: CellInputs) -> None:
    atomic_write(path, lambda f: pickle.dump(dataclasses.replace(inputs, pool=None), f, protocol=5), binary=True)


def load_or_compute_inputs(cell: Cell, pool: ModelPool) -> tuple[CellInputs, bool]:
    """The group inputs of ``cell`` read back from ``_inputs/inputs.pkl``, or computed with the
    pool's models and written there; and whether they were computed."""
    path = Path(cell.shares) / "_inputs" / INPUTS_FILE
    try:
        with open(path, "rb") as f:
            inputs = pickle.load(f)
        inputs.pool = pool
        return inputs, False
    except (OSError, EOFError, pickle.UnpicklingError, AttributeError) as e:
        if path.exists():
            log.warning("%s cannot be read (%s); computing the inputs again", path, e)
    inputs = prepare_inputs(cell.extra["inputs_config"], pool=pool)
    path.parent.mkdir(parents=True, exist_ok=True)
    _save(path, inputs)
    return inputs, True


def _pregenerate(cells: list[Cell], pool: ModelPool) -> None:
    """Generate the I⁻ of every generated scene first (into ``scene.cache_dir``), so the generator
    is loaded once before the depth estimator."""
    for cell in cells:
        c = cell.extra["inputs_config"]
        if Source(c.scene.source) is not Source.generated or not c.scene.cache_dir or c.model.from_scene:
            continue
        sc = c.scene
        sources.generated_image(
            lambda c=c: generator_of(c, pool)[0],
            str(sc.prompt_minus),
            int(sc.height),
            int(sc.width),
            steps=int(sc.steps),
            seed=cell_seed(c),
            schedule=str(sc.schedule),
            cache_dir=sc.cache_dir,
            model_key=node_key(c.model),
        )


def prepare_model_major(todo: list[Cell], pool: ModelPool) -> None:
    """Passes 1 and 2 of the module docs on the cells left to compute. A failure is logged and
    left to the cell, which computes (and fails) on its own."""
    groups = {}
    for cell in todo:
        groups.setdefault(cell.shares, cell)
    try:
        _pregenerate(list(groups.values()), pool)
    except Exception as e:  # noqa: BLE001 - the cells of that scene fail with the reason
        log.warning("generating I- ahead failed (%s); each cell generates its own", e)
    for cell in groups.values():
        try:
            load_or_compute_inputs(cell, pool)
        except Exception as e:  # noqa: BLE001
            log.warning("inputs of %s failed (%s); its cells will say why", cell.shares, e)
    relit = [c for c in todo if c.config.method.relight]
    for cell in relit:
        try:
            inputs, _ = load_or_compute_inputs(cell, pool)
            result = sample_stage(cell.config, inputs)
        except Exception as e:  # noqa: BLE001
            log.warning("sampling %s ahead of relighting failed (%s); the cell will say why", cell.name, e)
            continue
        cell.folder.mkdir(parents=True, exist_ok=True)
        atomic_write(cell.folder / UNRELIT_FILE, lambda f, r=result: torch.save(r, f), binary=True)


def take_unrelit(cell: Cell) -> CellResult | None:
    """The sampling result pass 2 kept for ``cell`` (removed once read), or None."""
    path = cell.folder / UNRELIT_FILE
    if not path.is_file():
        return None
    try:
        result = torch.load(path, weights_only=False)
    finally:
        path.unlink(missing_ok=True)
    return result
