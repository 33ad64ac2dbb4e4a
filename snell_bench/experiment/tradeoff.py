"""The speed/accuracy sweep (``job=tradeoff``): the cost knobs varied one at a time.

Settings:
    For every scene of ``tradeoff.scenes`` (with ``tradeoff.variation``, ``tradeoff.object`` and
    ``tradeoff.method``) one image is generated and scored per *setting*, and every stage is timed:

    - ``baseline``: the run's config as is (``conf/experiment/tradeoff.yaml`` picks the balanced
      preset);
    - one setting per (axis, value) of ``tradeoff.axes`` (those named by ``tradeoff.only``, or all),
      labelled ``<axis>=<value>`` (``steps=8``, ``resolution=320x176``). A value equal to the base
      value runs like any other (it shares the baseline's inputs, see *Reuse*);
    - one setting per preset of ``tradeoff.presets``, labelled ``preset:<name>``: the override
      ``preset=<name>`` (the preset replaces the experiment's choice, as on the command line).

    A setting's config is composed with Hydra from the run's overrides, the scene, object and
    method choices, ``warps.cache_dir=null`` (warps are traced, never read from a cache) and the
    setting's own overrides, last, so they win (:mod:`snell_bench.experiment.plan`).

Axes (``tradeoff.axes``):
    Hydra's override grammar, one entry per axis::

        steps: sampler.steps=4,8,12,20,28                 # a sweep override: one setting per value
        resolution:                                       # knobs that change together
          320x176: [scene.width=320, scene.height=176, scene.supersample=1]
          1280x720-ss2: [scene.width=1280, scene.height=720, scene.supersample=2]

    A value's label is the value as written in the override. Every override is checked by
    composing it before any folder is written: an unknown key, a value of the wrong type, or a
    duplicate label raise ``ValueError`` naming the axis. On the command line choose axes with
    ``tradeoff.only=[steps,levels]``.

Stages and times (``timings_s``, seconds of wall time):
    ``scene``, ``warps``, ``reference``, ``true_render`` (the inputs,
    :func:`snell_bench.pipeline.prepare_inputs`), ``generator`` (building the model, once per
    inputs and model config), ``sampling`` and ``metrics`` (:func:`snell_bench.pipeline.run_method`).
    ``total = warps + sampling + reference + metrics``: what producing and scoring one image costs
    once the scene exists. ``sampler_timings_s`` is the sampler's own breakdown. Before the sweep a
    tiny warm-up cell runs (imports, Mitsuba's variant probe, first-call costs), so that the first
    setting is not charged for them.

Reuse:
    The inputs depend only on the resolved ``scene``, ``object``, ``warps``, ``reference``,
    ``model``, ``depth``, ``segment`` (a generated or estimated scene) and
    ``seed`` subtrees; their SHA-256 (16 hex digits) is the *inputs key*. Within one process
    settings with the same key and scene share those inputs and their measured times
    (``inputs_reused_from`` names the setting that measured them). A resumed sweep recomputes
    the inputs it needs.

Layout of an experiment ``E`` under ``runs/``::

    runs/E/<scene>-<variation>/_shared/<inputs key>/_inputs/   I⁻, depth, camera, object,
        reference.png/.npy, mask.png, metric_mask.npy, true.png, timings.json
    runs/E/<scene>-<variation>/_shared/converged-<key>/         the converged reference
    runs/E/<scene>-<variation>/<setting slug>/                 image.png, config.yaml, result.json

    A slug is the label with every character outside ``[A-Za-z0-9._=+-]`` replaced by ``-``
    (``preset:fast`` -> ``preset-fast``). The cell loop (:mod:`snell_bench.experiment.cells`)
    writes ``result.json`` last; finished settings are skipped on a re-run unless
    ``tradeoff.recompute=true``; a failing setting records ``status: failed`` and the sweep goes on.

Reference convergence and the converged reference:
    For an axis that varies only ``reference.spp``, ``reference_psnr_vs_max_spp`` is the masked PSNR
    of each setting's reference against the highest-spp one of that axis (computed after each
    scene and again by the report). With ``tradeoff.converged_spp`` (default 1058) each setting is
    also scored against a converged reference of its scene, object and resolution, rendered once
    and shared (``psnr_converged``, ``mae_converged``, ``lpips_converged``): fidelity that does
    not move with ``reference.spp``; the Pareto front uses it. The report
    (:func:`~snell_bench.reports.build_tradeoff_report`) is a pure function of the run
    folder.
"""

from __future__ import annotations

import logging
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import DictConfig, ListConfig, OmegaConf

from snell_bench import pipeline
from snell_bench.config import ConfigError, check_tradeoff_entries
from snell_bench.config.grid import axis_settings
from snell_bench.experiment.cells import Cell, Hooks, Policy, SharedCache, failures_verdict, run_cells
from snell_bench.experiment.files import save_inputs
from snell_bench.experiment.memory import check_memory
from snell_bench.experiment.plan import (
    check_names,
    check_reproducible,
    compose_cell,
    object_dir_name,
    object_overrides,
)
from snell_bench.metrics.registry import builtin_metric
from snell_bench.pipeline.cell import plain
from snell_bench.reports import (  # noqa: F401  (re-exported)
    CONVERGED_METRICS,
    PRESET_AXIS,
    RECORD_METRICS,
    SPP_KEY,
    STAGES,
    TOTAL_NOTE,
    TOTAL_STAGES,
    TRADEOFF_RECORD,
    build_tradeoff_report,
    collect_tradeoff,
    pareto_front,
    reference_psnr_vs_max_spp,
    stdout_table,
    summary_line,
    tradeoff_table,
    update_spp_records,
)
from snell_bench.utils.io import json_hash, save_npy, write_json

log = logging.getLogger(__name__)

__all__ = [
    "KNOBS",
    "SHARED_SUBTREES",
    "Setting",
    "build_settings",
    "inputs_key",
    "converged_key",
    "resolved_knobs",
    "run_tradeoff",
    "plan_tradeoff",
]

#: Knob name -> config key, recorded resolved in every ``result.json`` (``knobs``).
KNOBS: dict[str, str] = {
    "steps": "sampler.steps",
    "tt_repeats_main": "sampler.tt_repeats_main",
    "tt_repeats_pano": "sampler.tt_repeats_pano",
    "levels": "sampler.levels",
    "max_bounces": "warps.max_bounces",
    "width": "scene.width",
    "height": "scene.height",
    "supersample": "scene.supersample",
    "pano_height": "warps.pano_height",
    "spp": "reference.spp",
}

#: The config subtrees the shared inputs (scene, warps, references) depend on.
SHARED_SUBTREES = ("scene", "object", "warps", "reference", "seed", "model", "depth", "segment")

BASELINE = "baseline"
_SLUG_RE = re.compile(r"[^A-Za-z0-9._=+-]")
#: Tiny sizes of the warm-up cell.
_WARM_UP = [
    "scene.width=64",
    "scene.height=32",
    "scene.supersample=1",
    "warps.pano_height=32",
    "reference.spp=1",
    "reference.true_spp=1",
    "sampler.steps=2",
    "sampler.levels=2",
]


# ---------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class Setting:
    """One point of the sweep: a label and the overrides it adds to the run's."""

    label: str
    #: Axis name; ``None`` for the baseline, ``"preset"`` for presets.
    axis: str | None = None
    #: The axis value (its label for knobs that change together, the preset's name).
    value: Any = None
    #: Hydra override strings.
    overrides: tuple = ()

    @property
    def slug(self) -> str:
        """The setting's folder name."""
        return _SLUG_RE.sub("-", str(self.label))

    def override_values(self) -> dict:
        """``{key: value}`` of the overrides (values typed as Hydra parses them)."""
        return {o.key_or_group: o.value() for o in OverridesParser.create().parse_overrides(list(self.overrides))}


def _plain(v: Any) -> Any:
    return OmegaConf.to_container(v, resolve=True, enum_to_str=True) if isinstance(v, ListConfig) else plain(v)


def _axis_settings(name: str, spec: Any) -> list[Setting]:
    """The settings of one axis (format: the module docs; parsed by
    :func:`snell_bench.config.grid.axis_settings`, which the config checks use too)."""
    spec = _plain(spec)
    if name in (BASELINE, PRESET_AXIS):
        raise ValueError(f"tradeoff.axes.{name}: {name!r} is reserved; rename the axis")
    out = []
    for label, overrides in axis_settings(name, spec):
        value = label.split("=", 1)[1]  # "steps=8" -> 8 (typed as Hydra types it); a mapping's label as is
        out.append(Setting(label, name, _typed(value) if isinstance(spec, str) else value, tuple(overrides)))
    return out


def _typed(text: str) -> Any:
    """A sweep value as Hydra types it (``"8"`` -> 8)."""
    return OverridesParser.create().parse_override(f"x={text}").value()


def build_settings(cfg: DictConfig) -> list[Setting]:
    """``baseline``, the axes' settings in order, then the presets; labels and slugs unique."""
    t = cfg.tradeoff
    axes = _plain(t.axes) or {}
    only = list(t.only) if t.only is not None else list(axes)
    unknown = [a for a in only if a not in axes]
    if unknown:
        raise ValueError(f"tradeoff.only: unknown axes {unknown}; choose from {list(axes)}")
    settings = [Setting(BASELINE)]
    for name in only:
        settings += _axis_settings(str(name), axes[name])
    if list(t.presets):
        check_names("preset", list(t.presets), "tradeoff.presets")
    settings += [Setting(f"{PRESET_AXIS}:{p}", PRESET_AXIS, str(p), (f"preset={p}",)) for p in t.presets]
    for what, names in (("label", [s.label for s in settings]), ("folder name", [s.slug for s in settings])):
        dup = sorted(k for k, n in Counter(names).items() if n > 1)
        if dup:
            raise ValueError(f"tradeoff: duplicate setting {what}(s) {dup}; give the axis distinct values or labels")
    return settings


def inputs_key(c: DictConfig) -> str:
    """SHA-256 (16 hex digits) of the resolved subtrees the shared inputs depend on."""
    payload = {k: _plain(c[k]) for k in SHARED_SUBTREES}
    return json_hash(payload)


def converged_key(c: DictConfig, spp: int) -> str:
    """What a converged reference depends on: the scene (and what makes a generated one: model, depth,
    segment), the object, the background mesh's cut, the reference settings with ``spp`` replaced,
    and the seed."""
    ref = dict(_plain(c.reference), spp=int(spp))
    return json_hash(
        {
            "model": _plain(c.model),
            "depth": _plain(c.depth),
            "segment": _plain(c.segment),
            "scene": _plain(c.scene),
            "object": _plain(c.object),
            "edge_threshold": float(c.warps.edge_threshold),
            "reference": ref,
            "seed": int(c.seed),
        }
    )


def resolved_knobs(c: DictConfig) -> dict:
    """The :data:`KNOBS` as resolved in a setting's config."""
    return {name: _plain(OmegaConf.select(c, key, default=None)) for name, key in KNOBS.items()}


def _compose_setting(cfg: DictConfig, st: Setting, scene_overrides: list[str]) -> DictConfig:
    try:
        return compose_cell(cfg, [*scene_overrides, "warps.cache_dir=null", *st.overrides])
    except Exception as e:  # hydra's errors: an unknown key, a value of the wrong type
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(f"tradeoff setting {st.label!r} ({list(st.overrides)}): {first}") from None


def plan_tradeoff(cfg: DictConfig) -> list[Cell]:
    """Every (scene, setting) of ``cfg.tradeoff``, composed and checked before any work."""
    t = cfg.tradeoff
    check_reproducible(cfg)
    problems = check_tradeoff_entries(cfg)
    if problems:
        raise ConfigError(problems)
    scenes = [str(s) for s in t.scenes]
    settings = build_settings(cfg)
    root = Path(cfg.runs_dir) / str(cfg.experiment_name)
    cells = []
    for scene in scenes:
        sdir = root / f"{scene}-{int(t.variation)}"
        chosen = [
            f"scene={scene}",
            f"scene.variation={int(t.variation)}",
            *object_overrides(str(t.object)),
            f"method={t.method}",
        ]
        for order, st in enumerate(settings):
            c = _compose_setting(cfg, st, chosen)
            key = inputs_key(c)
            record = {
                "experiment": str(cfg.experiment_name),
                "scene": scene,
                "variation": int(t.variation),
                "object": object_dir_name(str(t.object)),
                "method": str(t.method),
                "model": str(c.model.name),
                "scene_source": str(c.scene.source),
                **pipeline.scene_pipeline_record(c),
                "seed": int(c.seed),
                "setting": st.label,
                "slug": st.slug,
                "order": order,
                "axis": st.axis,
                "value": st.value,
                "overrides": st.override_values(),
                "knobs": resolved_knobs(c),
                "inputs_key": key,
                "inputs_dir": f"_shared/{key}/_inputs",
                "inputs_reused_from": None,
                "timings_note": TOTAL_NOTE,
            }
            cells.append(
                Cell(name=f"{scene}/{st.label}", folder=sdir / st.slug, config=c, record=record, shares=(scene, key))
            )
    return cells


# ---------------------------------------------------------------------------- the sweep
def _r(x: float) -> float:
    return round(float(x), 4)


@dataclass
class _Converged:
    image: np.ndarray  # (H, W, 3) sRGB
    mask: np.ndarray  # (H, W) bool
    spp: int
    key: str


@dataclass
class _Sweep:
    """State shared by the settings of one run."""

    scorers: dict
    converged_spp: int | None
    pool: pipeline.ModelPool = field(default_factory=pipeline.ModelPool)
    converged: dict = field(default_factory=dict)


def _inputs(cell: Cell, shared: SharedCache, pool: pipeline.ModelPool) -> pipeline.CellInputs:
    def compute():
        inputs = pipeline.prepare_inputs(cell.config, pool=pool)
        d = cell.folder.parent / "_shared" / cell.record["inputs_key"] / "_inputs"
        save_inputs(inputs, d, arrays=True)
        inputs.timings = {k: _r(v) for k, v in inputs.timings.items()}
        write_json(d / "timings.json", {"timings_s": inputs.timings, "computed_by": cell.record["setting"]})
        return inputs

    return shared.get(cell.shares, compute, by=cell.record["setting"])


def _converged_reference(cell: Cell, inputs: pipeline.CellInputs, sweep: _Sweep) -> _Converged | None:
    """The converged reference of a setting's inputs: cached, read from its files (resume), or
    rendered and saved under ``_shared/converged-<key>/``."""
    c, spp = cell.config, int(sweep.converged_spp)
    key = converged_key(c, spp)
    if key not in sweep.converged:
        d = cell.folder.parent / "_shared" / f"converged-{key}"
        if (d / "reference.npy").is_file() and (d / "metric_mask.npy").is_file():
            conv = _Converged(np.load(d / "reference.npy"), np.load(d / "metric_mask.npy"), spp, key)
        else:
            ref, reason = pipeline.render_reference(c, inputs.scene, inputs.obj, spp=spp)
            if ref is None:
                return None
            d.mkdir(parents=True, exist_ok=True)
            conv = _Converged(np.asarray(ref.image, np.float32), np.asarray(ref.mask, bool), spp, key)
            save_npy(d / "reference.npy", conv.image)
            save_npy(d / "metric_mask.npy", conv.mask)
        sweep.converged[key] = conv
    return sweep.converged[key]


def _run_setting(cell: Cell, shared: SharedCache, sweep: _Sweep) -> dict:
    """Sampling and metrics of one setting on its (possibly shared) inputs: the record's fields."""
    c = cell.config
    reused = cell.shares in shared.computed_by
    inputs = _inputs(cell, shared, sweep.pool)
    converged = None
    if sweep.converged_spp and c.reference.enabled:
        converged = _converged_reference(cell, inputs, sweep)
    res = pipeline.run_method(c, inputs, scorers=sweep.scorers, image_path=cell.folder / "image.png")
    t = {**inputs.timings, "generator": 0.0, **{k: _r(v) for k, v in res.timings.items()}}
    scored = res.scores
    if converged is not None:  # an evaluation on top: not part of the setting's cost
        conv = pipeline.score(c, inputs, res.image, sweep.scorers, reference=converged)
        for k in CONVERGED_METRICS:
            scored["metrics"][f"{k}_converged"] = conv["metrics"].get(k)
            if conv["metrics"].get(k) is None:
                scored["missing"][f"{k}_converged"] = conv["missing"].get(k, "no value")
    else:
        why = (
            "tradeoff.converged_spp=null (no converged reference)"
            if not sweep.converged_spp
            else f"no converged reference: {inputs.reference_reason}"
        )
        for k in CONVERGED_METRICS:
            scored["missing"][f"{k}_converged"] = why
    t["total"] = _r(sum(t[k] for k in TOTAL_STAGES))
    # users' metrics (metrics.extra) after the sweep's own
    names = RECORD_METRICS + tuple(
        k for k in scored["metrics"] if k not in RECORD_METRICS and builtin_metric(k) is None
    )
    metrics = {k: scored["metrics"].get(k) for k in names}
    missing = {k: v for k, v in scored["missing"].items() if k in names}
    if inputs.true_render is None and "psnr_true" not in missing:
        missing["psnr_true"] = (
            "no true render (reference.true_render=false, the renderer is unavailable, or the scene source is "
            "not procedural)"
        )
    for k in names:
        if metrics[k] is None and k not in missing:
            missing[k] = "no value"
    return {
        "inputs_reused_from": shared.computed_by[cell.shares] if reused else None,
        "converged_reference": None if converged is None else {"spp": converged.spp, "key": converged.key},
        "reference": None if inputs.reference is None else inputs.reference.summary(),
        "timings_s": {k: t.get(k) for k in STAGES + ("total",)},
        "sampler_timings_s": res.stats.get("sampler_timings_s", {}),
        "model_calls": res.stats.get("model_calls", {}),
        "decisions": res.stats.get("decisions", {}),
        "metrics": metrics,
        "missing": missing,
        "protocol": scored.get("protocol"),
    }


def _warm_up(cfg: DictConfig, cell: Cell) -> None:
    """Run one tiny cell (imports, Mitsuba's variant probe, first-call costs) and discard it."""
    try:
        c = compose_cell(cfg, [*cell.config.overrides[len(cfg.overrides) :], *_WARM_UP])
        pipeline.run_method(c, pipeline.prepare_inputs(c))  # nothing is written: warps.cache_dir=null
    except Exception as e:  # noqa: BLE001 - the sweep itself reports real failures
        log.info(
            "warm-up cell failed (%s: %s); timings of the first setting include first-call costs", type(e).__name__, e
        )


def run_tradeoff(cfg: DictConfig) -> dict:
    """Run the sweep of ``cfg.tradeoff`` and build its report; returns a summary, whose
    ``exit_status`` is 3 when settings failed, unless ``tradeoff.allow_failures=true``
    (:func:`~snell_bench.experiment.cells.failures_verdict`)."""
    t = cfg.tradeoff
    exp = str(cfg.experiment_name)
    root = Path(cfg.runs_dir) / exp
    cells = plan_tradeoff(cfg)  # everything that can be checked is checked before any folder is written
    check_memory(cells)  # each setting's peak host memory (scene.width, warps.pano_height, ...)
    n_settings = len(cells) // len(t.scenes)
    print(f"tradeoff {exp}: {len(t.scenes)} scene(s) x {n_settings} settings = {len(cells)} runs -> {root}")
    if t.recompute or any(not (c.folder / "result.json").is_file() for c in cells):
        _warm_up(cfg, cells[0])
    metrics_cfg = OmegaConf.merge(cfg.metrics, {"clip_weights": None, "image_reward_python": None})
    pool = pipeline.ModelPool(cfg.models.memory_gb, offload=bool(cfg.models.offload))
    sweep = _Sweep(scorers=pipeline.scorers_of(metrics_cfg, pool), converged_spp=t.converged_spp, pool=pool)
    last_of_scene = {c.record["scene"]: c for c in cells}

    def after(cell: Cell) -> None:
        if last_of_scene[cell.record["scene"]] is cell:
            update_spp_records(cell.folder.parent)

    summary = run_cells(
        cells,
        lambda c, s: _run_setting(c, s, sweep),
        root=root,
        policy=Policy.of(t, "tradeoff"),
        record_name="result.json",
        schema=TRADEOFF_RECORD,
        desc=f"tradeoff {exp}",
        hooks=Hooks(after=after),
    )
    for scene in last_of_scene:  # scenes whose last settings were already done
        update_spp_records(root / f"{scene}-{int(t.variation)}")
    allow = bool(OmegaConf.select(cfg, "tradeoff.allow_failures", default=False))
    exit_status, meaning = failures_verdict(summary["failed"], allow, "tradeoff.allow_failures")
    summary = {
        "experiment": exp,
        "runs": summary.pop("cells"),
        **summary,
        "models": pool.summary(),
        "exit_status": exit_status,
    }
    write_json(root / "summary.json", summary)
    print(
        f"{exp}: {summary['ok']} ok, {summary['cached']} already done, {summary['skipped']} skipped, "
        f"{summary['failed']} failed{meaning}"
    )
    for where, reason in summary["failures"]:
        print(f"  FAILED {where}: {reason}")
    out = Path(cfg.reports_dir) / exp
    paths = build_tradeoff_report(root, out)
    summary["reports"] = [str(p) for p in paths]
    print(summary_line(out, paths))
    print(stdout_table(tradeoff_table(collect_tradeoff(root))))
    return summary
