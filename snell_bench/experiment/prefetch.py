"""Preparing the groups' inputs in worker processes while the generator samples (``grid.prefetch``,
``grid.workers``).

A grid on one node does two kinds of work: it prepares each (scene, variation, object) group's
inputs (stages 1-5 of :func:`~snell_bench.pipeline.prepare_inputs`: the scene, the placement, the
ray-traced warps, the Mitsuba reference and the true render: CPU work) and it samples each cell
(the generator: on a GPU, the GPU's work). One after the other, a grid takes the sum of the two;
with the preparation in worker processes it takes about as long as the slower of the two
(``benchmarks/bench_overlap.py`` measures both).

Convention:
    - Groups ahead (``grid.prefetch``): while this process samples the cells of one group,
      ``grid.workers`` worker processes prepare the next ``grid.prefetch`` groups of the sweep's
      order: first what their cells need to sample (stages 1-3: scene, placement, warps; handed
      over in ``_inputs/sampling-<hash>.pkl``, :func:`sampling_file`, read back with
      :func:`~snell_bench.experiment.files.read_inputs` and removed), then what they need to be
      scored (stages 4-5: the reference and the true render). A cell starts sampling as soon as
      its group's stages 1-3 are there and waits for the references only before it is scored
      (:meth:`Prefetcher.complete`), so the slower stages never hold the generator up. The files
      of ``_inputs/`` are written by the process that computed them
      (:mod:`snell_bench.experiment.files`). In the model-major order each group's complete
      inputs are then kept where that order keeps them
      (:func:`~snell_bench.experiment.files.inputs_file`).
    - ``null`` is automatic (:func:`auto_prefetch`): :data:`AUTO_AHEAD` groups when the generator
      samples on CUDA, else 0, because on a CPU-only machine the generator and the preparation
      compete for the same cores. 0: no worker process, every stage here, in order (the serial
      path).
    - A group not prepared ahead (the sweep's first, one whose stages need a model, every group
      once the workers broke) is prepared when its first cell needs it: stages 1-3 here, and its
      references in a worker while its cells sample.
    - Models stay in this process: a worker loads none (its pool refuses, :class:`NoModels`).
      Stages that need a model of the sweep's pool (``scene.source=generated``: the generator for
      I⁻ and the depth estimator; ``scene.source=image`` without ``scene.depth``: the depth
      estimator; ``segment.segmenter``: SAM 3 or a mask; :func:`needs_models`) run here, with the
      models already loaded on the sweep's device, one copy each: such a group is never prepared
      ahead; its stages 1-3 run here when it is needed, and only its references go to a worker.
      Workers are started with ``spawn`` (a fresh interpreter: no CUDA context or torch thread
      is forked).
    - Results: a worker runs the same functions on the same configs and seeds as this process
      would, so every file and score is the same as with ``grid.prefetch=0``, bit for bit where
      the serial path is itself reproducible (Mitsuba's JIT variants add a pixel's samples in any
      order when its samples are split between threads, see
      :mod:`snell_bench.render.variants`). The stage timings of ``metrics.json`` (``scene``,
      ``warps``, ``reference``, ``true_render``) are those measured where the stage ran.
    - Failures: a group whose preparation raises fails its cells with that error, as in the
      serial path, and the sweep goes on (a cell whose references fail fails with that error
      after it sampled). A worker that dies (killed, out of memory) breaks the workers
      (``BrokenProcessPool``): what they had not finished, and every later group, is prepared
      here, the sweep goes on, and ``summary.json`` says why (``prefetch.fallback``).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from collections.abc import Hashable, Sequence
from concurrent.futures import CancelledError, Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig

from snell_bench import pipeline
from snell_bench.config import Source
from snell_bench.experiment.cells import Cell
from snell_bench.experiment.files import (
    inputs_file,
    keep_inputs,
    keeps_arrays,
    read_inputs,
    save_reference_files,
    save_scene_files,
)
from snell_bench.pipeline import CellInputs, ModelPool
from snell_bench.utils.timing import Timer

log = logging.getLogger(__name__)

__all__ = ["AUTO_AHEAD", "NoModels", "Prefetcher", "auto_prefetch", "generator_on_cuda", "needs_models", "settings_of"]

#: Groups prepared ahead when ``grid.prefetch`` is ``null`` and the generator samples on CUDA: one
#: ready for the next group whatever the order of the preparation times, one in preparation.
AUTO_AHEAD = 2


# ---------------------------------------------------------------------------- settings
def generator_on_cuda(model_cfg: DictConfig) -> bool:
    """Whether the generator of ``model_cfg`` samples on a CUDA device that torch sees: not a CPU
    stand-in built from the scene (``model.from_scene``), and ``model.device`` unset, ``auto`` or
    ``cuda[:i]``."""
    if model_cfg.from_scene:
        return False
    device = model_cfg.get("device")
    device = "cuda" if device is None or str(device) == "auto" else str(device)
    return torch.device(device).type == "cuda" and torch.cuda.is_available()


def auto_prefetch(cfg: DictConfig) -> int:
    """The groups prepared ahead when ``grid.prefetch`` is ``null``: :data:`AUTO_AHEAD` when the
    generator samples on CUDA (:func:`generator_on_cuda`), so the CPU prepares while the GPU
    samples; 0 otherwise, where sampling and preparation share the CPU's cores and running them at
    once gains nothing."""
    return AUTO_AHEAD if generator_on_cuda(cfg.model) else 0


def settings_of(cfg: DictConfig) -> tuple[int, int]:
    """``(groups ahead, worker processes)`` of a run: ``grid.prefetch`` (``null``:
    :func:`auto_prefetch`) and ``grid.workers``.

    Raises:
        ValueError: a negative ``grid.prefetch`` or a ``grid.workers`` below 1.
    """
    ahead = cfg.grid.prefetch
    ahead = auto_prefetch(cfg) if ahead is None else ahead
    workers = cfg.grid.workers
    if isinstance(ahead, bool) or int(ahead) != ahead or ahead < 0:
        raise ValueError(
            f"grid.prefetch={ahead!r}: give the groups to prepare ahead, an integer >= 0 (or null: automatic)"
        )
    if isinstance(workers, bool) or int(workers) != workers or workers < 1:
        raise ValueError(f"grid.workers={workers!r}: give the worker processes, an integer >= 1")
    return int(ahead), int(workers)


def needs_models(cfg: DictConfig) -> bool:
    """Whether stages 1-2 of a group's config need a model of the pool: a generated I⁻ (the
    generator, the depth estimator), a photo without its depth (the depth estimator), or a
    segmenter for the surface (``segment.segmenter``)."""
    source = cfg.scene.source
    return (
        source is Source.generated
        or (source is Source.image and not cfg.scene.depth)
        or bool(cfg.segment.get("segmenter"))
    )


# ---------------------------------------------------------------------------- in a worker
class NoModels(ModelPool):
    """The model pool of a worker process: it loads no model (see the module's conventions)."""

    def get(self, kind: str, key: str, build, **kwargs: Any):
        raise RuntimeError(
            f"a worker process loads no model (asked for the {kind} model): the stages that need one run in the "
            "sweep's own process; this group should not have been prepared in a worker (grid.prefetch=0 avoids it)"
        )


def _start_worker(variant: str | None) -> None:
    """A worker's start: its warnings on stderr, named; the config resolvers registered; and the
    Mitsuba variant the sweep's process chose (when it chose one) used without probing again."""
    from snell_bench.config import register_configs
    from snell_bench.render.variants import VARIANT_ENV

    logging.basicConfig(
        level=logging.WARNING, format="%(levelname)s [prefetch worker %(process)d] %(name)s: %(message)s"
    )
    register_configs()
    if variant and not os.environ.get(VARIANT_ENV):
        os.environ[VARIANT_ENV] = variant


def _ready() -> int:
    """Started at once, so that the workers start (imports, torch, Mitsuba and its variant) while
    the sweep's process prepares its first group."""
    from snell_bench.render.variants import set_variant

    try:
        set_variant()
    except Exception:  # noqa: BLE001 - no Mitsuba, or a bad variant: the references will say why
        pass
    return os.getpid()


def prepare_sampling_inputs(cfg: DictConfig, path: str) -> tuple:
    """In a worker: stages 1-3 of one group (``cfg``: a cell's inputs config), what its cells need
    to sample: the scene's files written into ``_inputs/`` and the inputs kept at ``path`` (the
    hand-over file, :func:`sampling_file`).

    Returns:
        ``(scene, obj)``: what :func:`render_references` needs.
    """
    inputs = pipeline.prepare_inputs(cfg, references=False, pool=NoModels())
    target = Path(path)
    keep_inputs(inputs, save_scene_files(inputs, target.parent), target)
    return inputs.scene, inputs.obj


def render_references(cfg: DictConfig, folder: str, scene, obj) -> dict:
    """In a worker: stages 4-5 of one group after its stages 1-3 (the same calls as
    :func:`~snell_bench.pipeline.prepare_inputs` makes), their files written into ``folder``.

    Returns:
        ``{"reference", "reason", "true_render", "timings", "files"}``: the reference render (or
        ``None`` and the reason), the true render, their ``reference`` and ``true_render``
        seconds, and the names of the files a cell links.
    """
    t = Timer()
    with t("reference"):
        reference, reason = pipeline.render_reference(cfg, scene, obj)
    with t("true_render"):
        true = pipeline.render_true_scene(cfg, scene, obj)
    files = save_reference_files(reference, true, Path(folder), arrays=keeps_arrays(cfg))
    return {"reference": reference, "reason": reason, "true_render": true, "timings": t.seconds, "files": sorted(files)}


def sampling_file(cell: Cell) -> Path:
    """Where a worker hands over the stages 1-3 of ``cell``'s group: ``_inputs/sampling-<hash>.pkl``
    beside :func:`~snell_bench.experiment.files.inputs_file` (never read as complete inputs)."""
    path = inputs_file(cell)
    return path.with_name("sampling-" + path.name.removeprefix("inputs-"))


# ---------------------------------------------------------------------------- in the sweep
@dataclass
class _Group:
    """One group of the plan and what is known of its inputs."""

    cell: Cell  #: the first cell that needs it (its ``inputs_config`` prepares it)
    path: Path  #: where its complete inputs are kept (the model-major order's file)
    ahead: bool  #: may be prepared ahead in a worker (its stages need no model)
    cells: int = 0  #: its cells not finished yet
    sampling: Future | None = None  #: stages 1-3 in a worker, handed over in :func:`sampling_file`
    references: Future | None = None  #: stages 4-5 in a worker
    partial: CellInputs | None = None  #: stages 1-3 in memory, waiting for ``references``
    files: dict = field(default_factory=dict)  #: the files of ``partial``
    done: dict | None = None  #: what ``references`` gave
    kept: bool = False  #: complete and kept at ``path`` (model-major)


class Prefetcher:
    """The worker processes of one sweep and the groups they prepare (see the module docs).

    Args:
        pool: the sweep's models (groups prepared here use them; the inputs read back get it).
        ahead: groups prepared ahead of the one being sampled (``grid.prefetch`` resolved, >= 1).
        workers: worker processes (``grid.workers``).
        keep: keep each group's complete inputs (:func:`~snell_bench.experiment.files.keep_inputs`),
            which the model-major order reads once per cell; else the sweep keeps a group in memory
            while its cells run (group-major).
    """

    def __init__(self, pool: ModelPool, ahead: int, workers: int, *, keep: bool = False) -> None:
        self.pool = pool
        self.ahead = int(ahead)
        self.workers = int(workers)
        self.keep = keep
        self._groups: dict[Hashable, _Group] = {}
        self._order: list[Hashable] = []  #: the groups in the order their cells need them
        self._reached = -1  #: the furthest position of the order asked for
        self._executor: ProcessPoolExecutor | None = None
        self.fallback: str | None = None  #: why the workers stopped, when they broke
        self.counts = {"prepared_ahead": 0, "prepared_here": 0, "references_in_workers": 0, "references_here": 0}

    # ------------------------------------------------------------------------ the plan
    def plan(self, cells: Sequence[Cell], *, first: Sequence[Cell] = (), model_free_only: bool = False) -> None:
        """The groups of ``cells`` (the cells left to compute, in the order they run), ordered by
        first need, ``first`` (cells that need their group before, e.g. sampled ahead) first;
        with ``model_free_only`` only those whose stages need no model (the others are the inputs
        pass's). Starts the workers."""
        for cell in [*first, *cells]:
            cfg = cell.extra["inputs_config"]
            if cell.shares in self._groups or (model_free_only and needs_models(cfg)):
                continue
            self._groups[cell.shares] = _Group(cell, inputs_file(cell), ahead=not needs_models(cfg))
            self._order.append(cell.shares)
        for cell in cells:
            if cell.shares in self._groups:
                self._groups[cell.shares].cells += 1
        if self._groups and self._pool() is not None:
            for _ in range(self.workers):  # start them now: they import while this process plans and samples
                self._executor.submit(_ready)

    def prepares(self, cell: Cell) -> bool:
        """Whether the group of ``cell`` is in the plan."""
        return cell.shares in self._groups

    def _pool(self) -> ProcessPoolExecutor | None:
        if self._executor is None and self.fallback is None:
            from snell_bench.render.variants import probed_variant

            self._executor = ProcessPoolExecutor(
                max_workers=self.workers,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=_start_worker,
                initargs=(probed_variant(),),
            )
        return self._executor

    def _broke(self, e: BaseException) -> None:
        """The workers broke (one died): every group not yet read is prepared here from now on."""
        if self.fallback is None:
            self.fallback = f"{type(e).__name__}: {e}"
            log.warning("a worker process died (%s); the remaining groups are prepared in this process", self.fallback)
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    def _submit(self, fn, *args) -> Future | None:
        ex = self._pool()
        if ex is None:
            return None
        try:
            return ex.submit(fn, *args)
        except (BrokenProcessPool, RuntimeError) as e:  # broken, or shut down after breaking
            self._broke(e)
            return None

    @staticmethod
    def _then(first: Future, executor: ProcessPoolExecutor, fn, *args) -> Future:
        """The future of ``fn(*args, *first.result())`` in a worker, submitted once ``first``
        succeeded (from the executor's thread); ``first``'s error if it failed."""
        out: Future = Future()

        def copy(done: Future) -> None:
            if done.cancelled():
                out.set_exception(CancelledError())
            elif done.exception() is not None:
                out.set_exception(done.exception())
            else:
                out.set_result(done.result())

        def chain(done: Future) -> None:
            if done.cancelled() or done.exception() is not None:
                copy(done)
                return
            try:
                executor.submit(fn, *args, *done.result()).add_done_callback(copy)
            except (BrokenProcessPool, RuntimeError) as e:  # the workers stopped meanwhile
                out.set_exception(BrokenProcessPool(f"the workers stopped before {fn.__name__} ran ({e})"))

        first.add_done_callback(chain)
        return out

    def _advance(self, key: Hashable) -> None:
        """Submit stages 1-3 of the groups up to ``ahead`` positions past ``key`` that need no model,
        each followed by its stages 4-5."""
        self._reached = max(self._reached, self._order.index(key))
        for k in self._order[self._reached + 1 : self._reached + 1 + self.ahead]:
            g = self._groups[k]
            if not g.ahead or g.sampling is not None or g.partial is not None or g.cells <= 0 or g.path.is_file():
                continue
            cfg = g.cell.extra["inputs_config"]
            g.sampling = self._submit(prepare_sampling_inputs, cfg, str(sampling_file(g.cell)))
            if g.sampling is not None:
                g.references = self._then(g.sampling, self._executor, render_references, cfg, str(g.path.parent))
                self.counts["prepared_ahead"] += 1
                self.counts["references_in_workers"] += 1

    # ------------------------------------------------------------------------ a cell's inputs
    def inputs(self, cell: Cell) -> tuple[CellInputs, dict[str, Path]]:
        """The group inputs of ``cell`` for sampling, and their files in ``_inputs/``.

        Prepared ahead: waits for the worker's stages 1-3 and reads them back. Otherwise stages
        1-3 run here and a worker renders the references. Either way :meth:`complete` adds the
        references (stages 4-5). Raises the error of a preparation that failed (every cell of the
        group fails with it).
        """
        g = self._groups[cell.shares]
        if g.partial is not None:
            return g.partial, dict(g.files)
        if g.kept and (kept := read_inputs(g.path)) is not None:
            kept[0].pool = self.pool
            return kept
        if g.sampling is not None:
            self._advance(cell.shares)  # keep the workers busy while this group is waited for
            try:
                g.sampling.result()  # its error is the group's
            except (BrokenProcessPool, CancelledError) as e:
                self._broke(e)
                g.sampling = g.references = None
            else:
                handed = sampling_file(cell)
                kept = read_inputs(handed)
                handed.unlink(missing_ok=True)  # in memory from now on
                if kept is not None:
                    g.partial, g.files = kept
                    g.partial.pool = self.pool
                    return g.partial, dict(g.files)
                g.sampling = g.references = None  # removed meanwhile: prepared here
        if not g.kept and (kept := read_inputs(g.path)) is not None:  # kept by an earlier run
            kept[0].pool = self.pool
            g.kept = True
            self._advance(cell.shares)
            return kept
        cfg = cell.extra["inputs_config"]
        inputs = pipeline.prepare_inputs(cfg, references=False, pool=self.pool)
        self.counts["prepared_here"] += 1
        files = save_scene_files(inputs, g.path.parent)
        g.partial, g.files = inputs, files
        g.references = self._submit(render_references, cfg, str(g.path.parent), inputs.scene, inputs.obj)
        self.counts["references_in_workers" if g.references is not None else "references_here"] += 1
        if g.references is None:  # no workers: the references here too
            g.done = render_references(cfg, str(g.path.parent), inputs.scene, inputs.obj)
        self._advance(cell.shares)
        return inputs, dict(files)

    def complete(self, cell: Cell, inputs: CellInputs) -> dict[str, Path]:
        """The reference files of ``cell``'s group that :meth:`inputs` did not give (rendered by a
        worker while the cell sampled), ``inputs`` filled with the references and their timings;
        ``{}`` when :meth:`inputs` gave everything. Raises the references' error."""
        g = self._groups.get(cell.shares)
        if g is None or (g.references is None and g.done is None):
            return {}
        if g.done is None:
            try:
                g.done = g.references.result()  # its error is the group's
            except (BrokenProcessPool, CancelledError) as e:  # the workers broke: rendered here
                self._broke(e)
                self.counts["references_in_workers"] -= 1
                self.counts["references_here"] += 1
                g.done = render_references(cell.extra["inputs_config"], str(g.path.parent), inputs.scene, inputs.obj)
        d = g.done
        for x in {id(inputs): inputs, id(g.partial): g.partial}.values():
            if x is not None:
                x.reference, x.reference_reason, x.true_render = d["reference"], d["reason"], d["true_render"]
                x.timings = {**x.timings, **d["timings"]}
        refs = {name: g.path.parent / name for name in d["files"]}
        if self.keep and g.partial is not None:  # kept; the group's later cells read it back
            keep_inputs(g.partial, {**g.files, **refs}, g.path)
            g.partial, g.files, g.kept = None, {}, True
        return refs

    def release(self, cell: Cell) -> None:
        """A cell is finished (whatever its status): its group is dropped after its last cell."""
        g = self._groups.get(cell.shares)
        if g is not None:
            g.cells -= 1
            if g.cells <= 0:
                g.partial, g.files, g.done = None, {}, None

    # ------------------------------------------------------------------------ the end
    def close(self, *, wait: bool = True) -> None:
        """Stop the workers (``wait``: after the groups they are preparing) and remove the
        hand-over files not read (their cells were another process's, or the workers broke)."""
        if self._executor is not None:
            self._executor.shutdown(wait=wait, cancel_futures=True)
            self._executor = None
        if wait:
            for g in self._groups.values():
                sampling_file(g.cell).unlink(missing_ok=True)

    def summary(self) -> dict:
        """What ``summary.json`` records: ``ahead``, ``workers``, the groups whose stages 1-3 ran in
        a worker ahead of their cells or here, whose references ran in a worker or here, and why
        the workers stopped (``fallback``, ``None`` when they did not)."""
        return {"ahead": self.ahead, "workers": self.workers, **self.counts, "fallback": self.fallback}
