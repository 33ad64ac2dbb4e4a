"""The experiment grid (``job=grid``): cells = (scene, variation, object, method), and with
``grid.axes`` / ``grid.presets`` each method at every named override set (the speed/accuracy
sweep, :mod:`snell_bench.experiment.sweep`).

Layout of an experiment ``E`` under ``runs/``::

    runs/E/<scene>-<variation>/<object>/_inputs/     I⁻, depth, camera, object, references
    runs/E/<scene>-<variation>/<object>/<method>/    image.png reference.png mask.png metrics.json
                                                     config.yaml I_minus.png depth.npy camera.json object.ply
                                                     panorama.png (methods with the panorama branch)
    runs/E/<scene>-<variation>/<object>/<method>@<setting>/    a cell of a setting (grid.axes)
    runs/E/<scene>-<variation>/<object>/_shared/               inputs of settings that change them,
                                                               converged references (grid.converged_spp)

- ``metrics.json`` holds the scores, the timings, the warps' statistics, the ``recipe`` and the
  metrics ``protocol`` of the cell's config and, under ``reference``,
  the reference's variant, sampler, sample counts, window and self-noise
  (:meth:`~snell_bench.render.reference.ReferenceRender.summary`; ``self_noise_db`` is about the
  highest masked PSNR an image can score against that reference).

- Each cell's config is composed with Hydra from the run's overrides and the cell's choices
  (:mod:`snell_bench.experiment.plan`); every cell is composed, and every name checked, before
  any work.
- Everything a (scene, variation, object) needs, I⁻, depth, warps (content-hashed cache), the
  reference renders, is computed once (:func:`snell_bench.pipeline.prepare_inputs`) and shared
  by every method of that group; the files are hard-linked into each cell.
- Every model comes from one :class:`~snell_bench.pipeline.ModelPool` per sweep, so each loads
  once; with a memory budget (``models.memory_gb``) the cells run model-major
  (:mod:`snell_bench.experiment.order`). ``summary.json`` lists every load (``models``).
- With ``grid.prefetch`` (automatic: on when the generator samples on CUDA) worker processes
  prepare the next groups' inputs while the generator samples, and render a group's references
  while its cells sample (:mod:`snell_bench.experiment.prefetch`); the results are the same.
  ``summary.json`` says what ran where (``prefetch``).
- The loop (:func:`snell_bench.experiment.cells.run_cells`) writes every file atomically and
  ``metrics.json`` last, so a cell with a ``metrics.json`` is complete. Re-running skips complete
  cells (``grid.recompute=true`` redoes them); a failing cell records its error (``status:
  failed``) and the sweep goes on; a method that cannot run here is ``skipped`` with the reason.
- Several processes (Hydra multirun with the joblib or submitit launchers) can share one
  experiment folder: ``grid.shards=N`` with ``-m`` runs N jobs (a Slurm job array with
  ``hydra/launcher=slurm``), each computing whole groups of its shard (:func:`shard_cells`) and
  writing its summary under ``jobs/<job id>/``; a job that Slurm requeues (preemption, time limit)
  skips its finished cells and computes the rest. Cells are claimed with a lock, so processes
  given overlapping parts still compute each cell once.
- With ``tracker=mlflow | tensorboard | wandb`` each cell this process computes is also logged
  as one run, after its record is written (:mod:`snell_bench.experiment.tracking`); a tracker that
  cannot start stops the run before any work, one that fails on a cell only warns.
  ``summary.json`` says how many runs were logged, where, and the time it took (``tracker``).
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Callable
from pathlib import Path

import submitit
from omegaconf import DictConfig, OmegaConf
from submitit.slurm.slurm import SlurmJobEnvironment

from snell_bench import pipeline
from snell_bench.config import ConfigError, check_grid_entries, compose
from snell_bench.config.grid import CellId
from snell_bench.config.schema import GridConfig
from snell_bench.experiment.cells import Cell, Hooks, Policy, SharedCache, failures_verdict, run_cells
from snell_bench.experiment.converged import ConvergedReferences
from snell_bench.experiment.estimate_cells import GridParts
from snell_bench.experiment.files import keeps_arrays, save_inputs
from snell_bench.experiment.memory import check_memory
from snell_bench.experiment.order import ModelMajor
from snell_bench.experiment.plan import (
    ABSENT,
    check_reproducible,
    compose_cell,
    result_settings,
)
from snell_bench.experiment.prefetch import Prefetcher, settings_of
from snell_bench.experiment.sweep import inputs_key, setting_record, share_folder, warm_up, with_total
from snell_bench.experiment.tracking import log_cell, make_tracker
from snell_bench.kit.schema import kit_id
from snell_bench.methods import method_of
from snell_bench.metrics.registry import metrics_for
from snell_bench.pipeline import (
    ModelPool,
    apply_method,
    initial_noise_record,
    scene_pipeline_record,
    scorers_of,
)
from snell_bench.reports.collect import recipe_and_protocol
from snell_bench.reports.records import GRID_RECORD, files_problem
from snell_bench.utils.io import link_or_copy, save_png, write_json, write_text
from snell_bench.utils.tensors import bchw_to_hwc
from snell_bench.utils.trust import load_yaml, read_json

log = logging.getLogger(__name__)

__all__ = [
    "run_grid",
    "plan_grid",
    "check_same_settings",
    "shard_cells",
    "job_id",
    "group_of",
    "stale_cell",
]

#: The panorama branch's image in a cell's folder (methods with the panorama branch).
PANORAMA_FILE = "panorama.png"

#: Warp statistics recorded per cell.
WARP_STATS = ("roi", "traced_primary_rays", "far_background")


def plan_grid(cfg: DictConfig) -> list[Cell]:
    """Every cell of ``cfg.grid``, composed and checked (raises ``ValueError`` before any work)."""
    g = cfg.grid
    check_reproducible(cfg)
    problems = check_grid_entries(cfg)  # names known, no repeats, variations and materials usable
    if problems:
        raise ConfigError(problems)
    root = Path(cfg.runs_dir) / cfg.experiment_name
    cells, problems, first_key = [], [], {}
    for order, cell in enumerate(CellId.grid(g)):
        try:
            raw = compose_cell(cfg, cell.overrides(), method=False)
        except ConfigError:
            raise
        except Exception as e:  # Hydra's: a setting's unknown key or a value of the wrong type
            if cell.setting is None:
                raise
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            problems.append(f"grid setting {cell.setting.label!r} ({list(cell.setting.overrides)}): {first}")
            continue
        c = apply_method(raw)
        try:
            method = method_of(c)  # the kind (or _target_) loads, its params fit
            problems += [f"cell {cell.name}: {p}" for p in method.check(c, cell.group)]
            metrics_for(c.metrics.protocol, c.metrics.extra)  # users' metrics load
        except ValueError as e:
            problems.append(f"cell {cell.name}: {e}")
            continue
        record = {
            "experiment": cfg.experiment_name,
            "scene": cell.scene,
            "variation": cell.variation,
            "object": cell.object_dir,
            "object_spec": cell.object,
            "method": cell.entry,
            "method_label": method.row_label(c) + ("" if cell.setting is None else f" ({cell.setting.label})"),
            "method_kind": c.method.kind,
            "model": c.model.name,
            "scene_source": str(c.scene.source),
            **scene_pipeline_record(c),
            **({"random_weights": True} if bool(c.model.get("random_init", False)) else {}),
            **recipe_and_protocol(c),
        }
        folder = cell.folder(root)
        share = folder.parent
        if cell.setting is not None:  # the settings that change the inputs share their own
            key = inputs_key(raw)
            share = share_folder(folder.parent, key, first_key)
            record.update(setting_record(cell, c, order, key, share, folder.parent))
        cells.append(Cell(cell.name, folder, c, record, shares=share, extra={"inputs_config": raw, "id": cell}))
    if problems:
        raise ConfigError(list(dict.fromkeys(problems)))
    return cells


def _group_inputs(
    cell: Cell, shared: SharedCache, pool: ModelPool, prefetch: Prefetcher | None = None
) -> tuple[pipeline.CellInputs, dict]:
    """The group's inputs and their files in ``_inputs/`` (traced with the run's warps settings; a
    method with its own gets its own warps in :func:`~snell_bench.pipeline.run_method`), from the
    ``prefetch`` workers when there are (its references may still be rendering:
    :meth:`~snell_bench.experiment.prefetch.Prefetcher.complete`)."""

    def compute():
        if prefetch is not None:
            return prefetch.inputs(cell)
        inputs = pipeline.prepare_inputs(cell.extra["inputs_config"], pool=pool)
        return inputs, save_inputs(inputs, cell.shares / "_inputs", arrays=keeps_arrays(cell.config))

    return shared.get(cell.shares, compute)


def run_cell(
    cell: Cell,
    shared: SharedCache,
    scorers,
    pool: ModelPool,
    order: ModelMajor | None = None,
    prefetch: Prefetcher | None = None,
    converged: ConvergedReferences | None = None,
) -> dict:
    """One grid cell: shared inputs linked into its folder, the method run and scored, with the
    models of the sweep's pool; in model-major ``order`` the inputs are read back and a relit
    cell finishes the result sampled ahead. References that a ``prefetch`` worker renders while
    the cell samples are waited for only before it is scored; with ``converged`` the image is
    also scored against the converged reference (:mod:`~snell_bench.experiment.converged`)."""
    if order is None:
        inputs, files = _group_inputs(cell, shared, pool, prefetch)
        sampled = None
    else:
        inputs, files = order.inputs(cell)
        sampled = order.take_unrelit(cell)
    inputs.group = group_of(cell)
    for name, path in files.items():
        link_or_copy(path, cell.folder / name)
    if sampled is None:
        sampled = pipeline.sample_stage(cell.config, inputs)
    source = order if order is not None else prefetch
    if source is not None:  # the references rendered meanwhile
        for name, path in source.complete(cell, inputs).items():
            link_or_copy(path, cell.folder / name)
    image_path = cell.folder / "image.png"
    res = pipeline.finish_method(cell.config, inputs, sampled, scorers=scorers, image_path=image_path)
    if res.panorama is not None:  # listed in the record's files with the image: resume checks it
        save_png(cell.folder / PANORAMA_FILE, bchw_to_hwc(res.panorama))
    scores, timings = res.scores, {k: round(v, 3) for k, v in {**inputs.timings, **res.timings}.items()}
    if converged is not None:  # an evaluation on top: not part of the cell's cost
        conv = converged.score(cell.config, inputs, res.image, scorers, cell.folder.parent)
        scores = {**scores, "metrics": {**scores["metrics"], **conv.pop("metrics")}}
        scores = {**scores, "missing": {**scores["missing"], **conv.pop("missing")}, **conv}
    return {
        **({"scene_info": inputs.scene.info} if inputs.scene.info else {}),
        **initial_noise_record(inputs.scene.info, res.stats.get("decisions")),
        **scores,
        # the reference's settings and self-noise: the ceiling of the cell's masked PSNR
        **({"reference": inputs.reference.summary()} if inputs.reference is not None else {}),
        "timings_s": timings if "setting" not in cell.record else with_total(timings),
        **res.stats,
        "warps": {k: res.warps.stats[k] for k in WARP_STATS if k in res.warps.stats},
    }


def identity_defaults() -> Callable[[str, int, str, str], dict]:
    """The settings a cell's identity alone composes (no run overrides), by ``(scene, variation,
    object spec, method)``: :meth:`~snell_bench.experiment.estimate_cells.GridParts.settings` of
    the config without overrides (one composition per scene, object and method, not per cell)."""
    return GridParts(compose([])).settings


def _without_setting(mine: dict, recorded: DictConfig, rec: dict) -> dict:
    """A setting's cell's settings without the keys its setting changes: those where the cell's
    recorded config differs from what its recorded overrides compose without the setting's own
    (the last ``setting_overrides``), i.e. from the same run's baseline of that cell."""
    own = [str(o) for o in rec["setting_overrides"]]
    overrides = [str(o) for o in recorded.get("overrides") or []]
    if own and overrides[-len(own) :] != own:
        raise ValueError(f"the recorded overrides do not end with the setting's {own}")
    baseline = result_settings(apply_method(compose(overrides[: len(overrides) - len(own)])))
    return {k: (v if baseline.get(k, ABSENT) == v else _OWN) for k, v in mine.items()}


#: A key a cell's setting changes (:func:`_without_setting`): never compared.
_OWN = "<the setting's own>"


def check_same_settings(root: Path, *, on_change_key: str = "grid.on_change") -> None:
    """Raise ``ValueError`` if the finished cells under ``root`` were computed with different
    settings, so that no report averages them.

    A cell's own settings are its recorded ``config.yaml``; the run's are where it differs from
    what the cell's identity alone (scene, variation, object, method) composes. Every cell must
    agree on every key any run changed, but for the keys a cell's setting (``grid.axes``,
    ``grid.presets``) changes."""
    defaults = identity_defaults()
    stored: dict[str, dict] = {}
    changed: set[str] = set()
    for path in sorted(root.rglob("metrics.json")):
        try:
            rec, problem = read_json(path)  # bounded, as every reader of a run folder
            if problem is not None or rec.get("status") != "ok" or files_problem(path.parent, rec) is not None:
                continue  # not a finished cell (the runner's rule): computed again, not compared
            name, sep, ior = str(rec["object"]).partition("-ior")
            spec = rec.get("object_spec") or (f"{name}:{ior}" if sep else name)
            saved, problem = load_yaml(path.parent / "config.yaml")
            if problem is not None:
                log.warning("not comparing %s: its config.yaml %s", path.parent, problem)
                continue
            recorded = OmegaConf.create(saved)
            mine = result_settings(recorded)
            method = str(rec.get("method_name", rec["method"]))
            base = defaults(str(rec["scene"]), int(rec["variation"]), str(spec), method)
            if "setting" in rec:  # the keys its named override set changes are its own: not compared
                mine = _without_setting(mine, recorded, rec)
        except Exception as e:  # noqa: BLE001 - a cell of an older layout or a removed entry: not compared
            log.debug("not comparing %s: %s", path.parent, e)
            continue
        cell = str(path.parent.relative_to(root))
        stored[cell] = mine
        changed |= {k for k, v in mine.items() if v != _OWN and base.get(k, ABSENT) != v}
    conflicts = []
    for key in sorted(changed):
        by_value: dict[str, list[str]] = {}
        for cell, mine in stored.items():
            if mine.get(key) == _OWN:
                continue
            by_value.setdefault(repr(mine.get(key, ABSENT)), []).append(cell)
        if len(by_value) > 1:
            parts = [
                f"{v} in {len(c)} cell{'s' if len(c) > 1 else ''} ({', '.join(c[:2])}{', ...' if len(c) > 2 else ''})"
                for v, c in by_value.items()
            ]
            conflicts.append(f"  {key}: " + "; ".join(parts))
    if conflicts:
        raise ValueError(
            f"the cells under {root} were computed with different settings, so a report would average them:\n"
            + "\n".join(conflicts[:12])
            + f"\nRun the grid again with one set of settings and {on_change_key}=recompute (or grid.recompute=true), "
            "or keep each set under its own experiment_name"
        )


def shard_cells(cells: list[Cell], shards: int, shard: int) -> list[Cell]:
    """The cells of shard ``shard`` of ``shards``: whole groups (a group's cells share its inputs,
    and a grid with settings its converged references, so each group is computed by one job; a
    group is its :attr:`~snell_bench.config.grid.CellId.group`, else what its cells share), dealt in
    the plan's order to the shard with the fewest cells so far (ties: the lowest index): balanced,
    deterministic, and the same in every job and in ``job=status``.

    Examples:
        >>> cs = [Cell(f"g{i // 2}/m{i % 2}", Path("."), None, {}, shares=f"g{i // 2}") for i in range(6)]
        >>> [c.name for c in shard_cells(cs, 2, 1)]
        ['g1/m0', 'g1/m1']
    """
    groups: dict = {}
    for c in cells:
        key = c.extra["id"].group if "id" in c.extra else c.shares if c.shares is not None else c.name
        groups.setdefault(key, []).append(c)
    load = [0] * shards
    mine: list[Cell] = []
    for members in groups.values():
        k = min(range(shards), key=lambda i: (load[i], i))
        load[k] += len(members)
        if k == shard:
            mine += members
    return mine


def group_of(cell: Cell) -> str:
    """The id of a grid cell's group, ``<scene>-<variation>/<object>`` (:attr:`~snell_bench.config.grid.CellId.group`)."""
    if "id" in cell.extra:
        return cell.extra["id"].group
    r = cell.record
    return kit_id(str(r["scene"]), int(r["variation"]), str(r["object"]))


def stale_cell(cell: Cell, record: dict) -> str | None:
    """Why a finished grid cell no longer holds though its files and settings are unchanged: its
    method's word (:meth:`snell_bench.methods.Method.stale`, e.g. a submitted image changed)."""
    return method_of(cell.config).stale(cell.config, record, cell.folder, group_of(cell))


def job_id() -> str:
    """This job's identity, as submitit names it (:class:`submitit.JobEnvironment`): ``<array
    job>_<task>`` (or the job id) under Slurm, stable when Slurm requeues it, whether submitit
    launched the job or a hand-written ``sbatch`` did; submitit's local job id under its local
    executor; ``<host>-<pid>`` elsewhere."""
    try:
        return str(submitit.JobEnvironment().job_id)
    except RuntimeError:  # not launched by submitit
        pass
    if os.environ.get("SLURM_JOB_ID"):
        return str(SlurmJobEnvironment().job_id)
    return f"{socket.gethostname()}-{os.getpid()}"


def _remove_handovers(cells: list[Cell]) -> None:
    """Remove the hand-over files (``_inputs/sampling-*.pkl``) an interrupted run of these groups
    left: this job alone prepares them (its shard), so none is in use."""
    for folder in {c.shares for c in cells if c.shares is not None}:
        for path in Path(folder, "_inputs").glob("sampling-*.pkl"):
            log.info("removing %s, left by an interrupted run", path)
            path.unlink(missing_ok=True)


def _count_start(folder: Path) -> int:
    """This job's starts so far, this one included (``starts`` in its jobs folder: a job requeued
    after preemption or a time limit keeps its id and counts up; Slurm's own
    ``SLURM_RESTART_COUNT`` does not reach every job step)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "starts"
    try:
        n = int(path.read_text().split()[0]) + 1
    except (OSError, ValueError, IndexError):
        n = 1
    write_text(path, f"{n}\n")
    return n


def run_grid(cfg: DictConfig) -> dict:
    """Run the grid of ``cfg`` (see the module docs), then build its report (``grid.report``; one the
    system refuses to write is one ERROR line: :func:`~snell_bench.experiment.report_job.grid_report`).

    The summary (also ``summary.json``) holds ``exit_status``: 3 when cells this run computed
    failed, unless ``grid.allow_failures=true`` (:func:`~snell_bench.experiment.cells.failures_verdict`);
    the printed summary line says it.

    With ``grid.shard`` set, this job runs its shard's groups (:func:`shard_cells`), writes its
    summary to ``runs/<experiment>/jobs/<job id>/summary.json`` (:func:`job_id`) instead of the
    experiment's, and builds the report only when every cell of the grid has its record (the
    last job to finish does; ``job=report`` any time)."""
    exp = cfg.experiment_name
    root = Path(cfg.runs_dir) / exp
    every = plan_grid(cfg)
    check_memory(every)  # each distinct cell's peak host memory, and its photo, before any work
    g: GridConfig = OmegaConf.to_object(cfg.grid)
    cells = every if g.shard is None else shard_cells(every, g.shards, g.shard)
    n_groups = len(g.scenes) * len(g.variations) * len(g.objects)
    print(f"experiment {exp}: {n_groups} scene/object groups x {len(g.methods)} methods = {len(every)} cells -> {root}")
    summary_root, job = root, None
    if g.shard is not None:
        summary_root = root / "jobs" / job_id()
        print(
            f"shard {g.shard} of {g.shards} (job {job_id()}): {len({c.shares for c in cells})} groups, {len(cells)} cells"
        )
        _remove_handovers(cells)
        starts = _count_start(summary_root)
        restarts = max(starts - 1, int(os.environ.get("SLURM_RESTART_COUNT", 0) or 0))
        job = {"id": job_id(), "shard": g.shard, "shards": g.shards, "host": socket.gethostname(), "restarts": restarts}
    summary = _compute(cfg, g, cells, summary_root)
    exit_status, meaning = failures_verdict(summary["failed"], g.allow_failures, "grid.allow_failures")
    summary = {"experiment": exp, **summary, "exit_status": exit_status, **({"job": job} if job else {})}
    write_json(summary_root / "summary.json", summary)
    _print_summary(exp, summary, meaning)
    if g.report and g.shard is not None and not all((c.folder / "metrics.json").is_file() for c in every):
        print(f"report: left to the last job of the grid (or run job=report experiment_name={exp})")
    elif g.report:
        from snell_bench.experiment.report_job import grid_report

        check_same_settings(root)
        summary["reports"] = grid_report(root, Path(cfg.reports_dir) / exp, exp)  # an OSError: one ERROR line
    return summary


def _compute(cfg: DictConfig, g: GridConfig, cells: list[Cell], summary_root: Path) -> dict:
    """Compute ``cells`` (group-major, or model-major when the models may not fit together), with
    the prefetch workers and the tracker: :func:`run_cells`' summary with the order, prefetch,
    models and tracker."""
    tracker = make_tracker(cfg)  # before any work: a tracker that cannot start stops the run here
    ahead, workers = settings_of(cfg)
    pool = ModelPool(cfg.models.memory_gb, offload=cfg.models.offload)
    scorers = scorers_of(cfg.metrics, pool)
    model_major = pool.budget is not None  # the models may not fit together
    prefetch = Prefetcher(pool, ahead, workers, keep=model_major) if ahead > 0 else None
    order = ModelMajor(pool, prefetch, lock=g.lock, lease_ttl_s=g.lease_ttl_s) if model_major else None
    converged = ConvergedReferences(g.converged_spp) if g.converged_spp else None
    if g.warm_up and cells and (g.recompute or any(not (c.folder / "metrics.json").is_file() for c in cells)):
        warm_up(cfg, cells[0].extra["id"].overrides())
    finished = False
    try:
        summary = run_cells(
            cells if order is None else order.order(cells),
            lambda c, s: run_cell(c, s, scorers, pool, order, prefetch, converged),
            root=summary_root,
            policy=Policy.of(cfg.grid, "grid"),
            schema=GRID_RECORD,
            desc=cfg.experiment_name,
            hooks=Hooks(
                before=order.prepare if order is not None else (prefetch.plan if prefetch is not None else None),
                after=None if prefetch is None else prefetch.release,
                recorded=None if tracker is None else lambda c, record: log_cell(tracker, c, record),
                stale=stale_cell,
            ),
        )
        finished = True
    finally:
        if order is not None:
            order.close()
        if prefetch is not None:
            prefetch.close(wait=finished)
        if tracker is not None:
            tracker.close()
    summary["order"] = "group-major" if order is None else "model-major"
    summary["prefetch"] = prefetch.summary() if prefetch is not None else {"ahead": 0, "workers": 0}
    summary["models"] = pool.summary()
    if tracker is not None:
        summary["tracker"] = tracker.summary()
    return summary


def _print_summary(exp: str, summary: dict, meaning: str) -> None:
    print(
        f"{exp}: {summary['ok']} ok, {summary['cached']} already done, {summary['skipped']} skipped, "
        + (f"{summary['degenerate']} degenerate, " if summary.get("degenerate") else "")
        + f"{summary['failed']} failed{meaning}"
        + (f", {summary['busy']} left to another process" if summary["busy"] else "")
    )
    for cdir, reason in summary["failures"]:
        print(f"  FAILED {cdir}: {reason}")
    if "tracker" in summary:
        t = summary["tracker"]
        print(
            f"tracker {t['name']}: {t['runs']} runs logged to {t['where']}"
            + (f", {t['failures']} cells could not be logged (see the warnings)" if t["failures"] else "")
        )
