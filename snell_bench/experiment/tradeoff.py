"""The speed/accuracy sweep (``job=tradeoff``): the cost knobs varied one at a time.

Settings
--------
For every scene of ``tradeoff.scenes`` (with ``tradeoff.variation``, ``tradeoff.object`` and
``tradeoff.method``) one image is generated and scored per *setting*, and every stage is timed:

- ``baseline``: the composed config as is (``conf/experiment/tradeoff.yaml`` picks the balanced
  preset);
- one setting per (axis, value) of ``tradeoff.axes``, labelled ``<axis>=<value label>``
  (``steps=8``, ``resolution=320x180``): the base with that knob changed. A value equal to the base
  value is run like any other (it shares the baseline's inputs, see *Reuse*);
- one setting per preset of ``tradeoff.presets``, labelled ``preset:<name>``: the base with the
  knobs of ``conf/preset/<name>.yaml`` (the file loaded with OmegaConf, ``defaults`` removed).

A setting's config is ``cell_config(OmegaConf.merge(base, overrides), scene, variation, object,
method)`` with ``warps.cache_dir = null`` (warps are traced, never read from a cache).

Format of ``tradeoff.axes``
---------------------------
A mapping from axis name to one of::

    steps: {key: sampler.steps, values: [4, 8, 12, 20, 28]}            # one knob
    resolution:                                                        # several knobs at once
      values:
        - {scene.width: 320, scene.height: 180}
        - {scene.width: 1280, scene.height: 720, scene.supersample: 2}
      labels: [320x180, 1280x720-ss2]                                   # optional

Keys are dotted paths into the composed config; YAML and Hydra's override grammar both keep a
dotted key inside a mapping as one key (``{scene.width: 320}`` is the key ``"scene.width"``).
Without ``labels``, a value's label is the value itself (``8``), or for a compound value its values
joined by ``x`` in the order given (``320x180``). Every key must name a leaf of the base config;
an unknown key, a key naming a whole node, a value of the wrong type, or duplicate labels raise
``ValueError`` (naming the axis, the key and the fix) before any folder is written.

On the command line Hydra *merges* a mapping into the existing one: ``'tradeoff.axes={steps:
{key: sampler.steps, values: [20]}}'`` replaces the ``steps`` axis and keeps the others; drop an
axis with ``~tradeoff.axes.<name>``.

Stages and times (``timings_s``, seconds of wall time)
------------------------------------------------------
- ``scene``: I⁻, its depth and the placed object; ``warps``: ray tracing; ``reference``: the
  Mitsuba reference the metrics compare against; ``true_render``: the procedural scene rendered
  with the object (the second reference); these four come from :func:`prepare_shared`.
- ``generator``: building the model (for the analytic backend, its prior from the scene's true
  panorama), once per (inputs, model config); ``sampling``: :func:`generate_image` with that model
  built; ``metrics``: :func:`score`.
- ``total = warps + sampling + reference + metrics``: what producing and scoring one image costs
  once the scene exists. ``scene`` (making the input), ``true_render`` (an evaluation that only
  procedural scenes allow) and ``generator`` (loading a model once) are left out.
- ``sampler_timings_s`` is the sampler's own breakdown (setup, model, codec, warp_blend, step).
- Before the sweep a tiny warm-up cell runs (Mitsuba's variant probe, imports, first-call costs),
  so that the first setting is not charged for them.

Reuse
-----
The inputs (scene, warps, reference, true render) depend only on the resolved ``scene``,
``object``, ``warps``, ``reference`` and ``seed`` subtrees; their SHA-256 (first 16 hex digits) is
the *inputs key*. Within one process a setting whose key another setting already computed for the
same scene reuses those inputs and their measured times, so reused stages carry identical numbers
(``inputs_reused_from`` names the setting that measured them). Sampling and metrics always run.
A resumed sweep recomputes (and re-measures) the inputs it needs.

Layout of an experiment ``E`` under ``runs/``::

    runs/E/<scene>-<variation>/_shared/<inputs key>/_inputs/   I⁻, depth, camera, object,
        reference.png/.npy, mask.png, metric_mask.npy, true.png, timings.json
    runs/E/<scene>-<variation>/<setting slug>/                 image.png, config.yaml, result.json

A slug is the label with every character outside ``[A-Za-z0-9._=+-]`` replaced by ``-``
(``preset:fast`` -> ``preset-fast``). ``result.json`` is written atomically and last; a setting
whose ``result.json`` has ``status: ok`` is complete and skipped on a re-run unless
``tradeoff.recompute=true``. A failing setting records ``status: failed`` with the reason, and the
sweep goes on. Everything is deterministic for a given ``seed``.

Reference convergence
---------------------
For an axis whose every value sets only ``reference.spp``, ``reference_psnr_vs_max_spp`` is the
masked PSNR (:func:`snell_bench.metrics.masked_psnr`, the protocol's defaults: grayscale,
histogram-matched) of each setting's reference against the highest-spp reference of that axis for
the same scene, over the metric mask of the highest-spp reference. It is computed from the saved
float references (``reference.npy``), after each scene of the sweep (written into ``result.json``)
and again by the report, so a finished folder alone gives it. The highest-spp setting itself has
``null`` (it is the comparison reference).

Converged reference
-------------------
A setting's own reference (``reference.spp`` samples) is noisy, and its noise lowers the PSNR of
every image scored against it, so PSNR against it moves with ``reference.spp`` even when the image
does not. With ``tradeoff.converged_spp`` (default 64) each setting is also scored against a
converged reference of its scene, object and resolution (rendered once, shared by every setting
with the same ``converged_key``, saved under ``_shared/converged-<key>/`` and reused on resume):
``psnr_converged``, ``mae_converged``, ``lpips_converged``. It is an evaluation on top, not part of
the setting's cost, and the Pareto front uses it (:func:`fidelity_column`).

Report
------
:func:`build_tradeoff_report` (a pure function of a run folder) writes ``tradeoff.csv`` (one row
per scene x setting), ``tradeoff.md`` (per setting, means over the scenes where it succeeded; the
Pareto front of (mean total time, mean PSNR against the converged reference)) and ``pareto.png``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import re
import tempfile
import time
import traceback
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import pandas as pd
from omegaconf import DictConfig, ListConfig, OmegaConf
from tqdm.auto import tqdm

from snell_bench.experiment.runner import (
    Scorers,
    Shared,
    Skip,
    _atomic_write_bytes,
    _save_npy,
    cell_config,
    generate_image,
    load_group,
    object_dir_name,
    parse_object_spec,
    prepare_shared,
    score,
    write_json,
)

from snell_bench.experiment.tradeoff_report import (  # noqa: F401  (re-exported)
    PRESET_AXIS,
    RECORD_METRICS,
    SPP_KEY,
    STAGES,
    TOTAL_NOTE,
    TOTAL_STAGES,
    build_tradeoff_report,
    collect_tradeoff,
    pareto_front,
    reference_psnr_vs_max_spp,
    stdout_table,
    tradeoff_table,
    update_spp_records,
)

log = logging.getLogger(__name__)

__all__ = [
    "KNOBS",
    "SHARED_SUBTREES",
    "SPP_KEY",
    "STAGES",
    "Setting",
    "parse_axes",
    "preset_settings",
    "build_settings",
    "setting_config",
    "inputs_key",
    "resolved_knobs",
    "run_tradeoff",
    "pareto_front",
    "collect_tradeoff",
    "reference_psnr_vs_max_spp",
    "tradeoff_table",
    "tradeoff_markdown",
    "pareto_figure",
    "build_tradeoff_report",
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
SHARED_SUBTREES = ("scene", "object", "warps", "reference", "seed")

BASELINE = "baseline"
_SLUG_RE = re.compile(r"[^A-Za-z0-9._=+-]")
_MISSING_KEY = object()


# ---------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class Setting:
    """One point of the sweep: a label and the dotted-key overrides it applies to the base."""

    label: str
    #: Axis name; ``None`` for the baseline, ``"preset"`` for presets.
    axis: str | None = None
    #: The axis value as given (a scalar, or a mapping for a compound axis; the preset's name).
    value: Any = None
    #: Flat ``{dotted key: value}``.
    overrides: dict = field(default_factory=dict)

    @property
    def slug(self) -> str:
        """The setting's folder name."""
        return slugify(self.label)

    @property
    def is_preset(self) -> bool:
        return self.axis == PRESET_AXIS


def slugify(label: str) -> str:
    """A folder name for a label: characters outside ``[A-Za-z0-9._=+-]`` become ``-``."""
    return _SLUG_RE.sub("-", str(label))


def _plain(v: Any) -> Any:
    """OmegaConf containers -> Python containers (other values unchanged)."""
    if isinstance(v, (DictConfig, ListConfig)):
        return OmegaConf.to_container(v, resolve=True)
    return v


def _value_label(v: Any) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return format(v, "g")
    return str(v)


def _check_key(base: DictConfig, key: Any, where: str) -> None:
    """Raise ``ValueError`` unless ``key`` is a dotted path to a leaf of ``base``."""
    if not isinstance(key, str) or not key:
        raise ValueError(f"{where}: the key {key!r} is not a dotted config key; write e.g. sampler.steps")
    node = OmegaConf.select(base, key, default=_MISSING_KEY, throw_on_missing=False)
    if node is _MISSING_KEY:
        head = key.split(".")[0]
        hint = f"; {head!r} has the keys {sorted(base[head].keys())}" if isinstance(base.get(head), DictConfig) else ""
        raise ValueError(
            f"{where}: unknown config key {key!r} (not in the base config){hint}. Fix the key, e.g. sampler.steps, "
            "warps.max_bounces, scene.width"
        )
    if isinstance(node, DictConfig):
        raise ValueError(
            f"{where}: the key {key!r} names a whole config node ({sorted(node.keys())}); give one of its leaves, "
            f"e.g. {key}.{next(iter(node.keys()), 'name')}"
        )


def parse_axes(axes: Mapping, base: DictConfig) -> list[Setting]:
    """One :class:`Setting` per (axis, value) of ``tradeoff.axes`` (format: the module docstring).

    Every key is checked against ``base``; errors name the axis, the key and the fix."""
    axes = _plain(axes) or {}
    if not isinstance(axes, Mapping):
        raise ValueError(f"tradeoff.axes must be a mapping axis name -> {{key, values}}, got {axes!r}")
    out = []
    for name, spec in axes.items():
        where = f"tradeoff.axes.{name}"
        if name in (BASELINE, PRESET_AXIS):
            raise ValueError(f"{where}: {name!r} is reserved; rename the axis")
        if not isinstance(spec, Mapping) or "values" not in spec:
            raise ValueError(
                f"{where}: expected {{key: <dotted key>, values: [...]}} or {{values: [{{<dotted key>: v, ...}}]}}, "
                f"got {spec!r}"
            )
        unknown = set(spec) - {"key", "values", "labels"}
        if unknown:
            raise ValueError(f"{where}: unknown field(s) {sorted(unknown)}; an axis has key, values and labels")
        values = spec["values"]
        if not isinstance(values, list) or not values:
            raise ValueError(f"{where}.values must be a non-empty list, got {values!r}")
        labels = spec.get("labels")
        if labels is not None and (not isinstance(labels, list) or len(labels) != len(values)):
            raise ValueError(f"{where}.labels must be a list with one label per value ({len(values)}), got {labels!r}")
        key = spec.get("key")
        if key is not None:
            _check_key(base, key, where)
        for i, v in enumerate(values):
            if key is not None:
                if isinstance(v, (Mapping, list)):
                    raise ValueError(
                        f"{where}: value {v!r} of key {key!r} must be a scalar; for a compound value drop 'key' and "
                        "give mappings {<dotted key>: value}"
                    )
                overrides = {key: v}
                label = _value_label(v)
            else:
                if not isinstance(v, Mapping) or not v:
                    raise ValueError(
                        f"{where}: value {v!r} needs a 'key' for the axis, or must be a mapping {{<dotted key>: value}}"
                    )
                for k in v:
                    _check_key(base, k, where)
                overrides = dict(v)
                label = "x".join(_value_label(x) for x in v.values())
            if labels is not None:
                label = str(labels[i])
            out.append(Setting(label=f"{name}={label}", axis=str(name), value=v, overrides=overrides))
    return out


def flatten(node: Mapping, prefix: str = "") -> dict:
    """Nested mapping -> ``{dotted key: leaf}`` (lists are leaves)."""
    out = {}
    for k, v in node.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping) and v:
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def nest(flat: Mapping) -> dict:
    """``{dotted key: value}`` -> nested dict (the inverse of :func:`flatten`)."""
    out: dict = {}
    for key, v in flat.items():
        d = out
        parts = str(key).split(".")
        for p in parts[:-1]:
            d = d.setdefault(p, {})
        d[parts[-1]] = v
    return out


def preset_settings(names: Iterable[str], base: DictConfig) -> list[Setting]:
    """One setting per preset (``conf/preset/<name>.yaml`` without its defaults, flattened)."""
    out = []
    for name in names:
        try:
            node = load_group("preset", str(name))
        except ValueError as e:
            raise ValueError(f"tradeoff.presets: {e}") from None
        flat = flatten(OmegaConf.to_container(node, resolve=True))
        for k in flat:
            _check_key(base, k, f"tradeoff.presets ({name}: conf/preset/{name}.yaml)")
        out.append(Setting(label=f"{PRESET_AXIS}:{name}", axis=PRESET_AXIS, value=str(name), overrides=flat))
    return out


def build_settings(cfg: DictConfig) -> list[Setting]:
    """``baseline``, the axes' settings in order, then the presets; labels and slugs unique."""
    settings = [Setting(BASELINE)] + parse_axes(cfg.tradeoff.axes, cfg) + preset_settings(cfg.tradeoff.presets, cfg)
    for what, names in (("label", [s.label for s in settings]), ("folder name", [s.slug for s in settings])):
        dup = sorted(k for k, n in Counter(names).items() if n > 1)
        if dup:
            raise ValueError(f"tradeoff: duplicate setting {what}(s) {dup}; give the axis distinct values or labels")
    for s in settings:
        if s.slug.startswith((".", "_")):
            raise ValueError(
                f"tradeoff: setting {s.label!r} would be a hidden folder; do not start labels with '.' or '_'"
            )
    return settings


def setting_config(base: DictConfig, setting: Setting, scene: str, variation: int, obj_spec: str,
                   method: str) -> DictConfig:
    """The config of one (scene, setting): the overrides merged into the base, then
    :func:`cell_config`, with warps never read from a cache. Raises ``ValueError`` when a value
    does not fit its key, or when the scene, object or method files override one of the keys."""
    try:
        merged = OmegaConf.merge(base, nest(setting.overrides))
    except Exception as e:  # omegaconf ValidationError: a value of the wrong type
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(
            f"tradeoff setting {setting.label!r}: {first}; fix the value of {sorted(setting.overrides)}"
        ) from None
    c = cell_config(merged, scene, variation, obj_spec, method)
    c.warps.cache_dir = None
    for k, v in setting.overrides.items():
        got = _plain(OmegaConf.select(c, k))
        if got != _plain(v):
            raise ValueError(
                f"tradeoff setting {setting.label!r}: {k} resolves to {got!r}, not {v!r}, for scene {scene!r}, "
                f"object {obj_spec!r}, method {method!r} (their files set it); vary another key or change those files"
            )
    return c


def inputs_key(c: DictConfig) -> str:
    """SHA-256 (16 hex digits) of the resolved subtrees the shared inputs depend on."""
    payload = {k: _plain(c[k]) for k in SHARED_SUBTREES}
    text = json.dumps(payload, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _model_key(c: DictConfig) -> str:
    return hashlib.sha256(json.dumps(_plain(c.model), sort_keys=True, default=str).encode()).hexdigest()[:16]


def resolved_knobs(c: DictConfig) -> dict:
    """The :data:`KNOBS` as resolved in a setting's config."""
    return {name: _plain(OmegaConf.select(c, key, default=None)) for name, key in KNOBS.items()}


# ---------------------------------------------------------------------------- the sweep
def _result_ok(path: Path) -> bool:
    try:
        return json.loads(path.read_text()).get("status") == "ok"
    except (OSError, ValueError, AttributeError):
        return False


def _r(x: float) -> float:
    return round(float(x), 4)


@dataclass
class _Inputs:
    """Shared inputs of one inputs key, with their measured times and who measured them."""

    shared: Shared
    timings: dict
    computed_by: str
    folder: Path
    generators: dict = field(default_factory=dict)  # model key -> (generator, build seconds)


def _compute_inputs(c: DictConfig, folder: Path, label: str) -> _Inputs:
    shared = prepare_shared(c, folder)
    d = folder / "_inputs"
    if shared.reference is not None:
        _save_npy(d / "reference.npy", np.asarray(shared.reference, np.float32))
    if shared.metric_mask is not None:
        _save_npy(d / "metric_mask.npy", np.asarray(shared.metric_mask, bool))
    timings = {k: _r(v) for k, v in shared.timings.items()}
    write_json(d / "timings.json", {"timings_s": timings, "computed_by": label})
    return _Inputs(shared, timings, label, folder)


def _needs_generator(c: DictConfig) -> bool:
    kind = str(c.method.kind)
    return kind in ("snellcaster", "t2i") or (kind == "inpaint" and str(c.model.name) == "analytic")


def _generator(entry: _Inputs, c: DictConfig) -> tuple[Any, float]:
    from snell_bench.experiment.inputs import make_generator

    key = _model_key(c)
    if key not in entry.generators:
        t0 = time.perf_counter()
        gen = make_generator(c.model, entry.shared.inputs, entry.shared.warps)
        entry.generators[key] = (gen, _r(time.perf_counter() - t0))
    return entry.generators[key]


def _sweep_metrics_config(mcfg: DictConfig) -> DictConfig:
    """The metrics config for the sweep: LPIPS as configured; CLIP and ImageReward not built."""
    m = OmegaConf.create(_plain(mcfg))
    m.clip_weights = None
    m.image_reward_python = None
    return m


@dataclass
class _Converged:
    image: np.ndarray  # (H, W, 3) sRGB
    mask: np.ndarray  # (H, W) bool
    spp: int
    key: str


def converged_key(c: DictConfig, spp: int) -> str:
    """What a converged reference depends on: the scene, the object, the background mesh's cut, the
    reference settings with ``spp`` replaced, and the seed."""
    ref = dict(_plain(c.reference))
    ref["spp"] = int(spp)
    blob = json.dumps({"scene": _plain(c.scene), "object": _plain(c.object),
                       "edge_threshold": float(c.warps.edge_threshold), "reference": ref, "seed": int(c.seed)},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _converged_reference(c: DictConfig, entry: _Inputs, spp: int, shared_dir: Path, cache: dict) -> _Converged:
    """The converged reference of a setting's inputs, from ``cache``, from its saved files (resume),
    or rendered (and saved under ``_shared/converged-<key>/``)."""
    key = converged_key(c, spp)
    if key in cache:
        return cache[key]
    d = shared_dir / f"converged-{key}"
    if (d / "reference.npy").is_file() and (d / "metric_mask.npy").is_file():
        conv = _Converged(np.load(d / "reference.npy"), np.load(d / "metric_mask.npy"), spp, key)
    else:
        from snell_bench.render.mitsuba_ref import render_reference

        sh = entry.shared
        ref = render_reference(sh.inputs.image, sh.inputs.depth, sh.inputs.camera, sh.obj, spp=int(spp),
                               edge_threshold=float(c.warps.edge_threshold), seed=int(c.seed),
                               unobserved_threshold=float(c.reference.unobserved_threshold))
        d.mkdir(parents=True, exist_ok=True)
        _save_npy(d / "reference.npy", np.asarray(ref.image, np.float32))
        _save_npy(d / "metric_mask.npy", np.asarray(ref.mask, bool))
        conv = _Converged(np.asarray(ref.image, np.float32), np.asarray(ref.mask, bool), spp, key)
    cache[key] = conv
    return conv


def _run_setting(c: DictConfig, setting: Setting, entry: _Inputs, scorers: Scorers, sdir: Path,
                 converged: _Converged | None = None) -> dict:
    """Sampling and metrics of one setting on its (possibly shared) inputs; the record's fields."""
    shared = entry.shared
    t = dict(entry.timings)
    gen_cache: dict = {}
    t["generator"] = 0.0
    if _needs_generator(c):
        gen, t["generator"] = _generator(entry, c)
        gen_cache[(c.model.name, id(shared))] = gen  # the key generate_image looks up
    t0 = time.perf_counter()
    img, stats = generate_image(c, shared, gen_cache)
    t["sampling"] = _r(time.perf_counter() - t0)
    from snell_bench.experiment.preview import save_png

    save_png(sdir / "image.png", img[0].permute(1, 2, 0).numpy())
    t0 = time.perf_counter()
    prompt = str(c.scene.prompt).replace("{object}", str(c.object.noun))
    scored = score(img, shared, prompt, scorers, sdir / "image.png")
    t["metrics"] = _r(time.perf_counter() - t0)
    if converged is not None:  # an evaluation on top: not part of the setting's cost
        from snell_bench.metrics import score_all

        conv = score_all(img[0].permute(1, 2, 0).numpy(), converged.image, converged.mask, prompt,
                         lpips=scorers.lpips)
        for k in ("psnr", "mae", "lpips"):
            scored["metrics"][f"{k}_converged"] = conv["metrics"].get(k)
            if conv["metrics"].get(k) is None:
                scored["missing"][f"{k}_converged"] = scorers.reasons.get(k) or conv["missing"].get(k, "no value")
    else:
        for k in ("psnr", "mae", "lpips"):
            scored["missing"][f"{k}_converged"] = "tradeoff.converged_spp=null (no converged reference)"
    t["total"] = _r(sum(t[k] for k in TOTAL_STAGES))
    metrics = {k: scored["metrics"].get(k) for k in RECORD_METRICS}
    missing = {k: v for k, v in scored["missing"].items() if k in RECORD_METRICS}
    if shared.true_render is None and "psnr_true" not in missing:
        missing["psnr_true"] = (
            "no true render (reference.true_render=false, the renderer is unavailable, or the scene source is "
            "not procedural)"
        )
    for k in RECORD_METRICS:
        if metrics[k] is None and k not in missing:
            missing[k] = "no value"
    return {
        "converged_reference": None if converged is None else {"spp": converged.spp, "key": converged.key},
        "timings_s": {k: t.get(k) for k in STAGES + ("total",)},
        "sampler_timings_s": stats.get("sampler_timings_s", {}),
        "model_calls": stats.get("model_calls", {}),
        "decisions": stats.get("decisions", {}),
        "metrics": metrics,
        "missing": missing,
    }


def _warm_up(c: DictConfig) -> None:
    """Run one tiny cell (imports, Mitsuba's variant probe, first-call costs) and discard it."""
    w = OmegaConf.create(OmegaConf.to_container(c, resolve=False))
    OmegaConf.set_struct(w, False)
    w.scene.width, w.scene.height, w.scene.supersample = 64, 32, 1
    w.warps.pano_height = 32
    w.reference.spp, w.reference.true_spp = 1, 1
    w.sampler.steps, w.sampler.levels = 2, 2
    with tempfile.TemporaryDirectory(prefix="tradeoff-warmup-") as d:
        try:
            shared = prepare_shared(w, Path(d))
            generate_image(w, shared, {})
        except Exception as e:  # the sweep itself reports real failures
            log.info("warm-up cell failed (%s: %s); timings of the first setting include first-call costs",
                     type(e).__name__, e)


def run_tradeoff(cfg: DictConfig) -> dict:
    """Run the sweep of ``cfg.tradeoff`` and build its report; returns a summary."""
    t = cfg.tradeoff
    exp = str(cfg.experiment_name)
    root = Path(cfg.runs_dir) / exp
    variation = int(t.variation)
    obj_spec, method = str(t.object), str(t.method)
    scenes = [str(s) for s in t.scenes]
    if not scenes:
        raise ValueError("tradeoff.scenes is empty; give at least one scene, e.g. tradeoff.scenes=[living_room]")
    # everything that can be checked is checked before any folder is written
    for s in scenes:
        load_group("scene", s)
    load_group("object", parse_object_spec(obj_spec)[0])
    load_group("method", method)
    settings = build_settings(cfg)
    plan = []  # (scene, setting, config, inputs key, folder)
    for scene in scenes:
        sdir = root / f"{scene}-{variation}"
        for st in settings:
            c = setting_config(cfg, st, scene, variation, obj_spec, method)
            plan.append((scene, st, c, inputs_key(c), sdir / st.slug))
    todo = [i for i, p in enumerate(plan) if t.recompute or not _result_ok(p[4] / "result.json")]
    uses = Counter((plan[i][0], plan[i][3]) for i in todo)
    last_todo_of_scene = {plan[i][0]: i for i in todo}

    root.mkdir(parents=True, exist_ok=True)
    print(f"tradeoff {exp}: {len(scenes)} scene(s) x {len(settings)} settings = {len(plan)} runs "
          f"({len(plan) - len(todo)} already done) -> {root}")
    if todo:
        _warm_up(plan[todo[0]][2])
    scorers = Scorers(_sweep_metrics_config(cfg.metrics))
    counts = Counter({"ok": 0, "failed": 0, "skipped": 0, "cached": len(plan) - len(todo)})
    failures = []
    cache: dict[tuple[str, str], _Inputs] = {}
    conv_cache: dict[str, _Converged] = {}
    bar = tqdm(total=len(plan), desc=f"tradeoff {exp}", unit="setting", initial=counts["cached"])
    for idx in todo:
        scene, st, c, key, sdir = plan[idx]
        bar.set_postfix_str(f"{scene} {st.label}")
        sdir.mkdir(parents=True, exist_ok=True)
        record = {
            "experiment": exp, "scene": scene, "variation": variation, "object": object_dir_name(obj_spec),
            "method": method, "model": str(c.model.name), "scene_source": str(c.scene.source), "seed": int(c.seed),
            "setting": st.label, "slug": st.slug, "order": settings.index(st), "axis": st.axis,
            "value": _plain(st.value), "overrides": {k: _plain(v) for k, v in st.overrides.items()},
            "knobs": resolved_knobs(c), "inputs_key": key,
            "inputs_dir": f"_shared/{key}/_inputs", "inputs_reused_from": None,
            "status": "ok", "reason": None, "timings_note": TOTAL_NOTE,
        }
        try:
            entry = cache.get((scene, key))
            if entry is None:
                entry = _compute_inputs(c, sdir.parent / "_shared" / key, st.label)
                cache[(scene, key)] = entry
            else:
                record["inputs_reused_from"] = entry.computed_by
            converged = None
            if t.get("converged_spp") and c.reference.enabled:
                converged = _converged_reference(c, entry, int(t.converged_spp), sdir.parent / "_shared", conv_cache)
            record.update(_run_setting(c, st, entry, scorers, sdir, converged))
        except Skip as e:
            record.update(status="skipped", reason=str(e))
        except KeyboardInterrupt:
            raise
        except Exception as e:
            record.update(status="failed", reason=f"{type(e).__name__}: {e}", traceback=traceback.format_exc())
            failures.append((f"{scene}/{st.label}", record["reason"]))
            log.error("setting %s of %s failed: %s", st.label, scene, record["reason"])
        finally:
            uses[(scene, key)] -= 1
            if uses[(scene, key)] <= 0:
                cache.pop((scene, key), None)  # no later setting needs these inputs
        c.output_dir = str(sdir)
        _atomic_write_bytes(sdir / "config.yaml", OmegaConf.to_yaml(c, resolve=True).encode())
        write_json(sdir / "result.json", record)  # last: marks the setting complete
        counts[record["status"]] += 1
        bar.update(1)
        if last_todo_of_scene[scene] == idx:
            update_spp_records(root / f"{scene}-{variation}")
    bar.close()
    summary = {"experiment": exp, "runs": len(plan), **counts, "failures": failures}
    write_json(root / "summary.json", summary)
    print(f"{exp}: {counts['ok']} ok, {counts['cached']} already done, {counts['skipped']} skipped, "
          f"{counts['failed']} failed")
    for where, reason in failures:
        print(f"  FAILED {where}: {reason}")
    out = Path(cfg.reports_dir) / exp
    paths = build_tradeoff_report(root, out)
    summary["reports"] = [str(p) for p in paths]
    print(f"reports: {out} ({len(paths)} files)")
    print(stdout_table(tradeoff_table(collect_tradeoff(root))))
    return summary


