"""``job=plan``: what a grid will do on this machine, before doing it.

``python -m snell_bench job=plan +experiment=main model=flux_dev`` prints, and writes nothing:

- the grid's cells and groups (scene x variation x object), which are done and which are left,
  with the runner's own test of "done" (:mod:`snell_bench.experiment.cells`: the record says ``ok``
  or ``skipped``, the files it lists are unchanged, its settings hash equals the cell's now; a
  cell finished with other settings is *changed*; :mod:`~snell_bench.experiment.estimate_cells`);
- every model the cells need (the generator, FLUX Fill, the relighter and its LoRA, the pipeline
  baselines, the depth estimator, the segmenter, the metric backbones), whether its weights are on
  this machine (a folder or the Hugging Face cache, looked up with the models' own resolvers,
  never downloading) and, where not, the config key to set; whether a GPU is needed and present
  (:mod:`~snell_bench.experiment.estimate_models`);
- the time and GPU memory per cell and in total, from a ``benchmarks/bench_gpu.py --json`` file
  (``plan.bench``) or else the documented basis (docs/gpu.md, kept in
  ``snell_bench/conf/plan_basis/documented.yaml``), always labelled with where the figures come from;
  whether the models fit together, else the model-major order with offloading
  (:mod:`~snell_bench.experiment.estimate_format`, which also writes the text).

Convention:
    - Nothing is written: no folder, no file, no log (:mod:`snell_bench.config.preflight` keeps
      Hydra's run folder, its ``.hydra/`` copy and its log file away for ``job=plan``), and no
      weight is downloaded or loaded.
    - Cells are not composed one by one: each scene, object and method is composed once with the
      run's overrides (:class:`GridParts`), and a cell's settings are the union of its parts'.
    - Times are seconds per cell as ``(low, high)``; memory is in GB (10⁹ bytes) of bfloat16
      weights, the documented unit (``models.memory_gb`` is GiB and is converted). FLUX Fill and
      FLUX Kontext share FLUX.1-dev's text encoders and VAE: loaded together, those count once.
    - A basis is scaled to a cell's settings linearly: the synchronized sampler by its model
      calls weighted by their pixels (:func:`model_calls`), the pipelines by steps x pixels. The
      scaling is an approximation and is printed with every row.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from snell_bench.config import ConfigError, OnChange, check_grid_entries, compose
from snell_bench.experiment.cells import Cell, ChangedCell, SettingsChanged
from snell_bench.experiment.estimate_cells import RECORD, CellState, GridParts, cell_states, group_models
from snell_bench.experiment.estimate_format import (
    ACTIVATIONS_GB,
    GIB,
    DeviceInfo,
    MethodTime,
    Plan,
    activations_gb,
    format_plan,
    local_device,
    memory_plan,
)
from snell_bench.experiment.estimate_models import (
    FLUX_FILL,
    FLUX_GENERATOR,
    KONTEXT,
    NO_WEIGHTS,
    OTHER_GB,
    REAL_BUILDERS,
    describe_model,
    grid_models,
    metric_models,
)
from snell_bench.experiment.plan import check_reproducible
from snell_bench.methods import method_of
from snell_bench.methods.cost import (
    CPU_LABEL,
    README_BASIS,
    README_LABEL,
    Basis,
    Estimate,
    ModelNeed,
    device_of,
    diffusers_folder,
    example,
    find_weights,
    lookup,
    model_calls,
    relight_estimate,
    secs,
    together_gb,
)
from snell_bench.metrics.alignment import CLIP_DEFAULT

__all__ = [
    "Basis",
    "README_BASIS",
    "load_bench",
    "model_calls",
    "group_models",
    "GridParts",
    "CellState",
    "ModelNeed",
    "DeviceInfo",
    "local_device",
    "Estimate",
    "MethodTime",
    "Plan",
    "make_plan",
    "format_plan",
    "run_plan",
    # also here, from the modules that hold them
    "ACTIVATIONS_GB",
    "CLIP_DEFAULT",
    "CPU_LABEL",
    "FLUX_FILL",
    "FLUX_GENERATOR",
    "GIB",
    "KONTEXT",
    "NO_WEIGHTS",
    "OTHER_GB",
    "README_LABEL",
    "REAL_BUILDERS",
    "RECORD",
    "activations_gb",
    "cell_states",
    "describe_model",
    "device_of",
    "diffusers_folder",
    "estimate_cell",
    "example",
    "find_weights",
    "lookup",
    "memory_plan",
    "metric_models",
    "relight_estimate",
    "secs",
    "together_gb",
]


# ---------------------------------------------------------------------------- the basis of the estimates
_BENCH_KEYS = (
    "device",
    "settings.steps",
    "settings.height",
    "settings.width",
    "settings.pano_height",
    "pair.total_s",
    "pair.model_calls.main",
    "pair.model_calls.pano",
    "pair.peak_memory_gb",
    "t2i.total_s",
    "t2i.steps",
    "t2i.peak_memory_gb",
    "fill.total_s",
    "fill.steps",
    "fill.peak_memory_gb",
    "kontext.total_s",
    "kontext.steps",
    "kontext.candidates",
    "kontext.peak_memory_gb",
    "memory_gb.flux_dev",
    "memory_gb.fill",
    "memory_gb.kontext",
    "memory_gb.shared_text_vae",
)


def _bench_value_ok(key: str, node: Any) -> bool:
    """A bench file's value is usable: the device a name, a count an integer (``pano`` calls may be
    0), any other number finite and positive."""
    if key == "device":
        return isinstance(node, str) and bool(node)
    if key.endswith(("steps", "height", "width", "main", "pano", "candidates")):
        return isinstance(node, int) and not isinstance(node, bool) and node >= (0 if key.endswith("pano") else 1)
    return isinstance(node, (int, float)) and not isinstance(node, bool) and math.isfinite(node) and node > 0


def load_bench(path: str | os.PathLike) -> Basis:
    """The :class:`Basis` of a ``benchmarks/bench_gpu.py --json`` file (config key ``plan.bench``).

    Raises:
        FileNotFoundError, IsADirectoryError: naming ``plan.bench``, when the file is not there.
        ConfigError: naming ``plan.bench`` and every missing or unusable field at once (a number
            must be finite and positive, a count an integer), or a file that is not JSON.
    """
    from snell_bench.utils.paths import data_path

    file = data_path(str(path), "plan.bench", "bench_gpu.py JSON file")
    fix = "give the file `python benchmarks/bench_gpu.py --json` wrote, or plan.bench=null for the documented basis (docs/gpu.md)"
    try:
        data = json.loads(Path(file).read_text())
    except (OSError, ValueError) as e:
        raise ConfigError([f"plan.bench={str(path)!r} is not a JSON file ({type(e).__name__}: {e}); {fix}"]) from None
    if not isinstance(data, dict):
        raise ConfigError([f"plan.bench={str(path)!r} holds a {type(data).__name__}, not a JSON object; {fix}"])
    problems, v = [], {}
    for key in _BENCH_KEYS:
        node: Any = data
        for part in key.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        if not _bench_value_ok(key, node):
            problems.append(f"{key} {'missing' if node is None else f'{node!r} is not usable'}")
        v[key] = node
    if problems:
        raise ConfigError([f"plan.bench={str(path)!r}: {', '.join(problems)}; {fix}"])
    random = " with random weights" if data.get("random_weights") else ""
    kontext = v["kontext.total_s"] / v["kontext.candidates"]
    return Basis(
        label=f"measured: benchmarks/bench_gpu.py on {v['device']} ({data.get('dtype', '?')}{random}), {file}",
        measured=True,
        pair_s=(v["pair.total_s"],) * 2,
        pair_calls=(v["pair.model_calls.main"], v["pair.model_calls.pano"]),
        size=(v["settings.height"], v["settings.width"], v["settings.pano_height"]),
        t2i_s=(v["t2i.total_s"],) * 2,
        t2i_steps=v["t2i.steps"],
        fill_s=(v["fill.total_s"],) * 2,
        fill_steps=v["fill.steps"],
        kontext_s=(kontext, kontext),
        kontext_steps=v["kontext.steps"],
        memory_gb={k: float(v[f"memory_gb.{k}"]) for k in ("flux_dev", "fill", "kontext", "shared_text_vae")},
        peak_gb={k: float(v[f"{k}.peak_memory_gb"]) for k in ("pair", "t2i", "fill", "kontext")},
    )


# ---------------------------------------------------------------------------- time of a cell and of a method
def estimate_cell(scene_cfg: DictConfig, method_cfg: DictConfig, models: Sequence[ModelNeed], basis: Basis) -> Estimate:
    """Time and GPU memory of a cell of the scene of ``scene_cfg`` and the method of ``method_cfg``
    (their parts, :class:`GridParts`), the models it needs described in ``models``: what the
    method's kind says it costs (:meth:`snell_bench.methods.Method.cost`), with relighting added
    (:func:`~snell_bench.methods.cost.relight_estimate`)."""
    est = method_of(method_cfg).cost(scene_cfg, method_cfg, models, basis)
    return relight_estimate(est, scene_cfg, method_cfg, models, basis)


def _method_time(method: str, kind: str, rows: list[tuple[Estimate, int]]) -> MethodTime:
    if not rows:
        return MethodTime(method, kind, None, 0, None, 0.0, None, "none", "no cells")
    known = [(e, n) for e, n in rows if e.seconds is not None]
    first = rows[0][0]
    left = sum(n for _, n in rows)
    if len(known) < len(rows):
        return MethodTime(method, kind, None, left, None, first.weights_gb, first.peak_gb, first.basis, first.note)
    per = (min(e.seconds[0] for e, _ in known), max(e.seconds[1] for e, _ in known))
    total = (sum(e.seconds[0] * n for e, n in known), sum(e.seconds[1] * n for e, n in known))
    weights = max(e.weights_gb for e, _ in rows)
    peaks = [e.peak_gb for e, _ in rows if e.peak_gb is not None]
    return MethodTime(method, kind, per, left, total, weights, max(peaks) if peaks else None, first.basis, first.note)


def _method_times(
    g: DictConfig,
    parts: GridParts,
    cells: list[CellState],
    per_pair: dict[tuple[str, str], list[ModelNeed]],
    basis: Basis,
) -> list[MethodTime]:
    """Each method's time over the grid's scenes (:func:`estimate_cell` of each scene, weighted by
    its cells left)."""
    times = []
    for method in map(str, g.methods):
        rows = []
        for scene in map(str, g.scenes):
            est = estimate_cell(parts.scene(scene), parts.method(method), per_pair[(scene, method)], basis)
            rows.append((est, sum(1 for c in cells if c.scene == scene and c.method == method and not c.done)))
        times.append(_method_time(method, parts.method(method).method.kind, rows))
    return times


# ---------------------------------------------------------------------------- the plan
def _warnings(g: DictConfig, cells: list[CellState]) -> list[str]:
    """The grid would stop before any work: cells finished with other settings under
    ``grid.on_change=error``."""
    changed = [c for c in cells if c.state == "changed"]
    if not changed or g.on_change is not OnChange.error:
        return []
    err = SettingsChanged(
        [ChangedCell(Cell(c.name, c.folder, None, {}), c.diff) for c in changed],
        on_change_key="grid.on_change",
        recompute_key="grid.recompute",
    )
    return ["the grid would stop before any work: " + str(err).replace("\nNothing was run.", "")]


def make_plan(
    cfg: DictConfig,
    *,
    basis: Basis | None = None,
    device: DeviceInfo | None = None,
    compose_fn: Callable[[list[str]], DictConfig] = compose,
) -> Plan:
    """The plan of ``cfg``'s grid on this machine (see the module's docs); nothing is written.

    Args:
        cfg: the run's config (composed from ``cfg.overrides``, as ``python -m snell_bench`` does).
        basis: the time and memory basis (:func:`load_bench`); ``None``: ``plan.bench`` when set,
            else :data:`README_BASIS`.
        device: the CUDA device to plan for; ``None``: this machine's (:func:`local_device`).
        compose_fn: composes overrides (:func:`snell_bench.config.compose`).

    Raises:
        ConfigError: an unknown or repeated grid entry, or an unusable ``plan.bench``.
        ValueError: ``cfg`` differs from what its overrides compose.
    """
    if basis is None:
        bench = OmegaConf.select(cfg, "plan.bench")
        basis = README_BASIS if bench is None else load_bench(bench)
    device = local_device() if device is None else device
    check_reproducible(cfg)
    problems = check_grid_entries(cfg)
    if problems:
        raise ConfigError(problems)
    parts = GridParts(cfg, compose_fn)
    cells = cell_states(cfg, parts)
    g = cfg.grid
    per_pair, models = grid_models(cfg, parts, cells, basis)
    times = _method_times(g, parts, cells, per_pair, basis)
    left_models = {id(m) for m in models if m.cells_left} or {id(m) for m in models}
    memory = memory_plan([m for m in models if id(m) in left_models], cfg.models, device, basis)
    return Plan(
        experiment=cfg.experiment_name,
        root=Path(cfg.runs_dir) / cfg.experiment_name,
        model=cfg.model.name,
        recipe=cfg.recipe,
        scenes=len(g.scenes),
        variations=len(g.variations),
        objects=len(g.objects),
        methods=[str(m) for m in g.methods],
        cells=cells,
        models=models,
        device=device,
        times=times,
        basis=basis,
        memory=memory,
        warnings=_warnings(g, cells),
        compositions=parts.compositions,
    )


def run_plan(cfg: DictConfig) -> Plan:
    """``job=plan``: print the plan of ``cfg`` (:func:`make_plan`, :func:`format_plan`)."""
    plan = make_plan(cfg)
    print(format_plan(plan))
    return plan
