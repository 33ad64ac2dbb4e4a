"""The order a grid's cells run in, so that each model loads once per sweep.

Without a memory budget (``models.memory_gb: null``) every model stays loaded and cells run group
by group (scene x variation x object), each group's inputs computed once and dropped after its last
method. With a budget the models may not fit together, so the sweep runs *model-major*
(:class:`ModelMajor`):

1. the inputs pass: every group's inputs (stages 1-5) are computed with the models those stages
   need and kept in ``_inputs/inputs-<settings hash>.pkl``
   (:func:`~snell_bench.experiment.files.inputs_file`; generated I⁻ are generated first, into
   ``scene.cache_dir``); with a prefetcher (:mod:`snell_bench.experiment.prefetch`,
   ``grid.prefetch``) only the groups whose stages need a model: worker processes prepare the
   others ahead of the cells that need them, while the generator samples, and they are kept in
   the same file;
2. the sampling pass of relit cells: a cell that samples with one model and relights with another
   samples here, grouped by its sampling model, and keeps its un-relit result beside it
   (``.unrelit.pt``, hidden) until its turn;
3. the cells, ordered by the model they need last, starting with the one the sampling pass left
   loaded; each cell reads its group's inputs back from the pickle.

The kept inputs are named by the hash of the settings stages 1-5 read
(:func:`~snell_bench.experiment.files.inputs_settings`: the method's keys left out), so every
method of a group reads the same file.

The inputs read back are the very arrays the group computed
(:func:`~snell_bench.experiment.files.read_inputs`), so the results do not depend on the order
(``tests/pipeline/test_pool.py`` checks every file of a grid run both ways). Each model then loads
once, with two exceptions: a generator that makes I⁻ (``scene.source=generated``) and also samples
loads once for each, when the budget does not hold it beside the depth estimator; and relit cells
that sample with different models may reload one of them. A generator built from the scene (the
CPU stand-ins) is rebuilt per cell in this order: it is the group's, not the sweep's.
"""

from __future__ import annotations

import io
import logging
from pathlib import Path
from typing import TYPE_CHECKING

import torch
from omegaconf import DictConfig

from snell_bench.config import Source
from snell_bench.experiment.cells import Cell, claim
from snell_bench.experiment.files import inputs_file, keep_inputs, keeps_arrays, read_inputs, save_inputs
from snell_bench.methods import method_of
from snell_bench.pipeline import CellInputs, CellResult, ModelPool, prepare_inputs, sample_stage
from snell_bench.pipeline.cell import node_key
from snell_bench.pipeline.inputs import generate_i_minus
from snell_bench.utils.io import atomic_write
from snell_bench.utils.trust import read_signed, signed

if TYPE_CHECKING:
    from snell_bench.experiment.prefetch import Prefetcher

log = logging.getLogger(__name__)

__all__ = ["cell_models", "ModelMajor", "UNRELIT_FILE"]

UNRELIT_FILE = ".unrelit.pt"


def cell_models(c: DictConfig) -> list[tuple[str, str]]:
    """``(kind, key)`` of the shared models one cell's method loads (stages 6-7b), in the order it
    uses them: what its kind says (:meth:`snell_bench.methods.Method.models`; a generator built
    from the scene is the group's own and is not listed), then the relighter (``method.relight``)."""
    out = list(method_of(c).models(c))
    if c.method.relight and c.model.get("relighter"):
        out.append(("relighter", node_key(c.model.relighter)))
    return out


def _relit(cell: Cell) -> bool:
    return bool(cell.config.method.relight) and len(cell_models(cell.config)) > 1


class ModelMajor:
    """The model-major order of one sweep (see the module docs) and what its passes keep.

    Args:
        pool: the sweep's models.
        prefetch: worker processes that prepare the groups whose stages need no model
            (:class:`~snell_bench.experiment.prefetch.Prefetcher`, in keep mode), or ``None``: the
            inputs pass prepares every group here.
    """

    def __init__(
        self, pool: ModelPool, prefetch: Prefetcher | None = None, *, lock: str = "auto", lease_ttl_s: float = 120.0
    ) -> None:
        self.pool = pool
        self.prefetch = prefetch
        self.lock, self.lease_ttl_s = lock, lease_ttl_s
        self._unrelit: dict[Path, Path] = {}  #: cell folder -> the result this process sampled ahead

    # ------------------------------------------------------------------------ the order
    def order(self, cells: list[Cell]) -> list[Cell]:
        """``cells`` by the model each needs last, the sampling pass's last model first; stable."""
        first_use: list[tuple[str, str]] = []
        for cell in cells:
            for m in cell_models(cell.config):
                if m not in first_use:
                    first_use.append(m)
        sampling = self._sampling_models([c for c in cells if _relit(c)])
        if sampling:  # continue with the model the sampling pass leaves loaded
            first_use.remove(sampling[-1])
            first_use.insert(0, sampling[-1])
        rank = {m: i for i, m in enumerate(first_use)}
        return sorted(cells, key=lambda c: rank[cell_models(c.config)[-1]] if cell_models(c.config) else -1)

    @staticmethod
    def _sampling_models(relit: list[Cell]) -> list[tuple[str, str]]:
        out: list[tuple[str, str]] = []
        for cell in relit:
            m = cell_models(cell.config)[0]
            if m not in out:
                out.append(m)
        return out

    # ------------------------------------------------------------------------ inputs
    def inputs(self, cell: Cell) -> tuple[CellInputs, dict[str, Path]]:
        """The group inputs of ``cell`` and their files in ``_inputs/``: from the prefetcher when it
        prepares the group, else read back from the pickle its settings name
        (:func:`~snell_bench.experiment.files.read_inputs`), or computed with the pool's models and
        kept there (:func:`~snell_bench.experiment.files.keep_inputs`)."""
        if self.prefetch is not None and self.prefetch.prepares(cell):
            return self.prefetch.inputs(cell)
        path = inputs_file(cell)
        kept = read_inputs(path)
        if kept is not None:
            kept[0].pool = self.pool
            return kept
        inputs = prepare_inputs(cell.extra["inputs_config"], pool=self.pool)
        files = save_inputs(inputs, path.parent, arrays=keeps_arrays(cell.config))
        keep_inputs(inputs, files, path)
        return inputs, files

    def complete(self, cell: Cell, inputs: CellInputs) -> dict[str, Path]:
        """The reference files of ``cell``'s group that :meth:`inputs` did not give yet (the
        prefetcher's references rendered while the cell sampled), ``inputs`` filled with them."""
        return {} if self.prefetch is None else self.prefetch.complete(cell, inputs)

    # ------------------------------------------------------------------------ the passes
    def prepare(self, todo: list[Cell]) -> None:
        """Passes 1 and 2 on the cells left to compute. A failure is logged and left to its cells,
        which compute (and fail) on their own."""
        groups: dict = {}
        for cell in todo:
            groups.setdefault(cell.shares, cell)
        for cell in groups.values():  # generated I⁻ first: the generator before the depth estimator
            c = cell.extra["inputs_config"]
            if Source(c.scene.source) is Source.generated and c.scene.cache_dir and not c.model.from_scene:
                try:
                    generate_i_minus(c, self.pool)
                except Exception as e:  # noqa: BLE001
                    log.warning("generating I- of %s failed (%s); its cells will say why", cell.shares, e)
        relit = [c for c in todo if _relit(c)]
        ahead = [c for m in self._sampling_models(relit) for c in relit if cell_models(c.config)[0] == m]
        if self.prefetch is not None:  # the groups without models, in the order their cells need them
            self.prefetch.plan(todo, first=ahead, model_free_only=True)
        for cell in groups.values():
            if self.prefetch is not None and self.prefetch.prepares(cell):
                continue  # prepared by the workers ahead of its cells
            try:
                self.inputs(cell)
            except Exception as e:  # noqa: BLE001
                log.warning("inputs of %s failed (%s); its cells will say why", cell.shares, e)
        for cell in ahead:
            self._sample_ahead(cell)

    def _sample_ahead(self, cell: Cell) -> None:
        cell.folder.mkdir(parents=True, exist_ok=True)
        with claim(cell.folder, kind=self.lock, ttl_s=self.lease_ttl_s) as mine:
            if not mine:  # another process computes it
                return
            try:
                inputs, _ = self.inputs(cell)
                result = sample_stage(cell.config, inputs)
            except Exception as e:  # noqa: BLE001
                log.warning("sampling %s ahead of relighting failed (%s); the cell will say why", cell.name, e)
                return
            path = cell.folder / UNRELIT_FILE
            buf = io.BytesIO()
            torch.save(result, buf)
            atomic_write(path, lambda f: f.write(signed(buf.getvalue())), binary=True)  # read back signed only
            self._unrelit[cell.folder] = path

    def take_unrelit(self, cell: Cell) -> CellResult | None:
        """The result this process sampled ahead for ``cell`` in this sweep (removed once read), or
        None (then the cell samples itself)."""
        path = self._unrelit.pop(cell.folder, None)
        if path is None:
            return None
        try:
            payload, problem = read_signed(path)  # a pickle runs code: loaded only when this user signed it
            if problem is not None:
                raise ValueError(problem)
            return torch.load(io.BytesIO(payload), weights_only=False)
        except Exception as e:  # noqa: BLE001
            log.warning("%s cannot be read (%s); sampling again", path, e)
            return None
        finally:
            path.unlink(missing_ok=True)

    def close(self) -> None:
        """Remove what the sampling pass kept for cells that did not use it (another process
        finished them)."""
        for path in self._unrelit.values():
            path.unlink(missing_ok=True)
        self._unrelit.clear()
