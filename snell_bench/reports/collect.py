"""Reading a run directory: one row per cell folder, from its ``metrics.json`` alone; and what the
cells are (the provenance line) and what is missing in them (the notes).

A run directory holds one folder per cell, ``<scene>-<variation>/<object>/<method>/``; folders whose
name starts with "." or "_" (e.g. the shared ``_inputs``) are not cells. A ``metrics.json`` that is
not a cell record (:func:`~.records.load_record`: not UTF-8, not JSON, not an object, or against
:data:`~.records.GRID_RECORD`) is no cell: it is left out with a warning naming it and the problem,
and listed in ``DataFrame.attrs["skipped_files"]`` (the reports' "files skipped" section).
"""

from __future__ import annotations

import logging
import math
import os
import re
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

import pandas as pd

from snell_bench.utils.trust import load_yaml

from .records import GRID_RECORD, files_problem, load_record, non_finite
from .spec import METRICS, MODEL_DESCRIPTIONS, metric_spec
from .text import as_float, is_missing, reason

log = logging.getLogger(__name__)

__all__ = [
    "collect",
    "SKIPPED_FILES",
    "skipped_files",
    "not_finite_reason",
    "BASE_COLUMNS",
    "recipe_and_protocol",
    "RECORDED_METRICS",
    "recorded_metrics",
    "provenance_line",
    "cell_notes",
    "reference_noise_note",
]

BASE_COLUMNS = (
    "experiment",
    "scene",
    "variation",
    "object",
    "method",
    "method_label",
    "status",
    "reason",
    "model",
    "scene_source",
    "recipe",
    "protocol",
)
"""The identity columns of :func:`collect`, first and in this order."""

RECORDED_METRICS = "metrics"
"""The key of ``DataFrame.attrs`` listing the metric columns of :func:`collect`, in order: the
built-in metrics the cells record, then the others (users' metrics, ``metrics.extra``) as first
recorded."""

SKIPPED_FILES = "skipped_files"
"""The key of ``DataFrame.attrs`` listing the record files left out: ``[(path relative to the run
directory, problem), ...]``."""

_CELL_DIR_RE = re.compile(r"^(?P<scene>.+)-(?P<variation>\d+)$")
_FLAT_GROUPS = ("decisions", "warps", "reference", "model_calls")  # nested records flattened to dotted columns
_OWN_GROUPS = ("metrics", "missing", "timings_s")  # flattened with their own conversions


#: The status of a cell built with random weights (``model.random_init``): its timings are real, its
#: pixels mean nothing, so no table, figure or average takes it.
RANDOM_WEIGHTS = "random_weights"
_RANDOM_REASON = (
    "built with random weights (model.random_init=true): real cost, meaningless pixels; left out of every table "
    "and figure (run with the real weights to score it)"
)


def _cell_from_path(rel: Path) -> dict:
    """Scene, variation, object and method from ``<scene>-<variation>/<object>/<method>``."""
    parts = rel.parts
    out: dict = {}
    if len(parts) >= 3:
        m = _CELL_DIR_RE.match(parts[-3])
        if m:
            out.update(scene=m["scene"], variation=int(m["variation"]))
        out.update(object=parts[-2], method=parts[-1])
    return out


def _is_cell_dir(rel: Path) -> bool:
    """Whether a folder below the run directory has the layout of a cell."""
    parts = rel.parts
    return (
        len(parts) >= 3
        and not any(p.startswith((".", "_")) for p in parts)
        and _CELL_DIR_RE.match(parts[-3]) is not None
    )


def recipe_and_protocol(cfg) -> dict:
    """Which recipe and metrics protocol a cell's config records.

    Args:
        cfg: a cell's composed config (a mapping or a ``DictConfig``, as in its ``config.yaml``).

    Returns:
        ``{"recipe": ..., "protocol": ...}``: the recipe is the config's ``recipe`` key (a name, or
        a node with a ``name``), else the last ``recipe=NAME`` among its recorded ``overrides``,
        else None; the protocol is ``metrics.protocol``, else None.
    """

    def get(node, key):
        try:
            return node.get(key) if node is not None else None
        except (AttributeError, TypeError):
            return None

    recipe = get(cfg, "recipe")
    if recipe is not None and not isinstance(recipe, str):
        recipe = get(recipe, "name")
    if recipe is None:
        for o in get(cfg, "overrides") or ():
            key, sep, value = str(o).lstrip("+~").partition("=")
            if sep and key == "recipe":
                recipe = value
    protocol = get(get(cfg, "metrics"), "protocol")
    return {
        "recipe": None if recipe is None else str(recipe),
        "protocol": None if protocol is None else str(protocol),
    }


def _recorded_config(folder: Path) -> dict:
    """Recipe and protocol from a cell's ``config.yaml`` (both None where it is missing or
    unreadable; read bounded, :func:`~snell_bench.utils.trust.load_yaml`)."""
    cfg, problem = load_yaml(folder / "config.yaml")
    if problem is not None and (folder / "config.yaml").exists():
        log.warning("%s: its config.yaml %s; its recipe and protocol are unknown", folder, problem)
    return recipe_and_protocol(cfg if isinstance(cfg, dict) else None)


def _checked_record(path: Path, rel: Path, run_dir: Path, skipped: list) -> dict | None:
    """A cell's record as the report reads it: ``None`` (and an entry in ``skipped``) when it is
    not a record; ``failed`` when its files are not those it finished with (the runner's own rule,
    :func:`~snell_bench.reports.records.files_problem`: the grid computes such a cell again)."""
    rec, problem = load_record(path, GRID_RECORD)
    if problem is not None:
        log.warning("%s is not a cell record, left out of the report: %s", path, problem)
        skipped.append((path.relative_to(run_dir).as_posix(), problem))
        return None
    rec = without_non_finite(rec, rel.as_posix(), path)
    unfinished = files_problem(path.parent, rec) if rec.get("status") in ("ok", "skipped", "degenerate") else None
    if unfinished is not None:
        log.warning("%s: %s; not scored (the grid computes it again)", path.parent, unfinished)
        rec = {**rec, "status": "failed", "reason": f"not finished: {unfinished}"}
    if "recipe" not in rec or "protocol" not in rec:  # a cell recorded before the record held them
        rec = {**_recorded_config(path.parent), **rec}
    if rec.get("random_weights") and rec.get("status") == "ok":
        rec = {**rec, "status": RANDOM_WEIGHTS, "reason": _RANDOM_REASON}
    return rec


def _row_from_record(rec: dict, rel: Path) -> dict:
    """The columns of one record except the flattened :data:`_FLAT_GROUPS`."""
    row = {k: rec.get(k) for k in BASE_COLUMNS}
    for k, v in _cell_from_path(rel).items():
        if row.get(k) is None:
            row[k] = v
    for k, v in rec.items():
        if k not in row and k not in _OWN_GROUPS and not isinstance(v, (dict, list)):
            row[k] = v
    for k, v in (rec.get("metrics") or {}).items():
        row[k] = as_float(v)
    for k, v in (rec.get("missing") or {}).items():
        row[f"missing.{k}"] = None if v is None else str(v)
    for k, v in (rec.get("timings_s") or {}).items():
        row[f"timings_s.{k}"] = as_float(v)
    return row


def _flat_groups(records: list[dict]) -> pd.DataFrame:
    """What the cells modelled, one dotted column per leaf (``decisions.panorama.used``); lists are
    not table values, so a column holding one is left out."""
    flat = pd.json_normalize(
        [{g: rec[g] for g in _FLAT_GROUPS if isinstance(rec.get(g), dict)} for rec in records], sep="."
    )
    has_list = [c for c in flat.columns if flat[c].map(lambda v: isinstance(v, list)).any()]
    return flat.drop(columns=has_list)


def recorded_metrics(df: pd.DataFrame) -> list[str]:
    """The metric columns of ``df`` (:func:`collect`), in order: ``attrs["metrics"]`` where
    :func:`collect` set it, else the built-in metrics and the installed users' metrics among its
    columns.

    Args:
        df: the rows.

    Returns:
        Metric names (record keys), each a column of ``df``.
    """
    names = df.attrs.get(RECORDED_METRICS)
    if names is None:  # a frame that lost its attrs: the built-in metrics and the installed users' ones
        names = [m for m in METRICS if m in df.columns]
        names += [c for c in df.columns if c not in METRICS and metric_spec(str(c)).source != "unknown"]
    return [m for m in names if m in df.columns]


def skipped_files(df: pd.DataFrame) -> list[tuple[str, str]]:
    """The record files left out of ``df`` (:func:`collect`, :func:`~.tradeoff.collect_tradeoff`).

    Args:
        df: the rows.

    Returns:
        ``[(path relative to the run directory, problem), ...]``; empty when none was.
    """
    return [tuple(x) for x in df.attrs.get(SKIPPED_FILES, [])]


def not_finite_reason(value: float) -> str:
    """Why a metric recorded as ``value`` (NaN or ±inf) has no value in the reports.

    Examples:
        >>> not_finite_reason(float("inf"))
        'not finite in the record (inf)'
    """
    return f"not finite in the record ({value})"


def without_non_finite(rec: dict, where: str, path: Path) -> dict:
    """``rec`` with every non-finite metric (NaN, ±inf) set to null and its reason in ``missing``
    (:func:`not_finite_reason`), each warned about, naming the cell ``where`` and the file."""
    bad = non_finite(rec.get("metrics"))
    if not bad:
        return rec
    for name, value in bad.items():
        log.warning("cell %s: metric %s is %s in %s: not finite, shown as missing", where, name, value, path)
    return {
        **rec,
        "metrics": {**rec["metrics"], **dict.fromkeys(bad)},
        "missing": {**(rec.get("missing") or {}), **{k: not_finite_reason(v) for k, v in bad.items()}},
    }


def collect(run_dir: str | os.PathLike) -> pd.DataFrame:
    """One row per cell below ``run_dir``.

    Every ``metrics.json`` below ``run_dir`` that is a cell record (:data:`~.records.GRID_RECORD`)
    gives a row; a cell built with random weights has the status :data:`RANDOM_WEIGHTS` (never
    ``ok``, so no table takes it). A ``metrics.json`` that is not a cell record gives no row: it is
    warned about (its path and what is wrong) and listed in ``attrs["skipped_files"]``
    (:func:`skipped_files`). A cell folder with a ``config.yaml`` and no ``metrics.json`` gives a
    row with status ``"failed"`` and the reason, with scene, variation, object and method taken
    from the path. A metric recorded as NaN or ±inf is warned about (the cell and the metric) and
    has no value, with the reason ``missing.<metric>`` = "not finite in the record (inf)".

    Args:
        run_dir: the experiment's run directory.

    Returns:
        A DataFrame with the columns :data:`BASE_COLUMNS` (``experiment``, ``scene``,
        ``variation``, ``object``, ``method``, ``method_label``, ``status``, ``reason``, ``model``,
        ``scene_source``); one column per metric (``psnr``, ``lpips``, ...; NaN where null); the
        reason a metric is missing as ``missing.<metric>``; stage timings as
        ``timings_s.<stage>``; what the cell modelled as ``decisions.<...>`` and ``warps.<...>``;
        the generator calls per branch as ``model_calls.main`` and ``model_calls.pano``;
        the reference's settings and self-noise as ``reference.<...>`` (``reference.self_noise_db``);
        other scalar fields of the record under their own name; and ``cell_dir``, the cell's
        folder relative to ``run_dir``. Rows are sorted by scene, variation, object, method and
        folder. Empty (with the identity columns) when there is no cell. ``attrs["skipped_files"]``
        lists the files left out as ``(path relative to run_dir, problem)``.
    """
    run_dir = Path(run_dir)
    records, rels, seen, skipped = [], [], set(), []
    for path in sorted(run_dir.rglob("metrics.json")):
        rel = path.parent.relative_to(run_dir)
        if any(p.startswith((".", "_")) for p in rel.parts):
            continue
        seen.add(path.parent)
        rec = _checked_record(path, rel, run_dir, skipped)
        if rec is None:
            continue
        records.append(rec)
        rels.append(rel)
    for path in sorted(run_dir.rglob("config.yaml")):
        rel = path.parent.relative_to(run_dir)
        if path.parent in seen or not _is_cell_dir(rel):
            continue
        records.append(
            {
                "status": "failed",
                "reason": "incomplete cell: config.yaml but no metrics.json",
                **_recorded_config(path.parent),
            }
        )
        rels.append(rel)
    if not records:
        empty = pd.DataFrame({c: pd.Series(dtype=object) for c in BASE_COLUMNS + ("cell_dir",)})
        empty.attrs[SKIPPED_FILES] = skipped
        return empty
    df = pd.DataFrame([_row_from_record(rec, rel) for rec, rel in zip(records, rels)])
    flat = _flat_groups(records)
    df = pd.concat([df.drop(columns=[c for c in flat.columns if c in df.columns]), flat], axis=1)
    df["cell_dir"] = [rel.as_posix() for rel in rels]
    df["variation"] = pd.to_numeric(df["variation"], errors="coerce").astype("Int64")
    df["status"] = df["status"].fillna("failed")
    keys = ["scene", "variation", "object", "method", "cell_dir"]
    df = df.sort_values(keys, na_position="last", kind="mergesort").reset_index(drop=True)
    fixed = [c for c in BASE_COLUMNS if c in df.columns]
    seen = list(dict.fromkeys(k for rec in records for k in (rec.get("metrics") or {})))
    metric_cols = [m for m in METRICS if m in seen] + [m for m in seen if m not in METRICS]
    other = sorted(c for c in df.columns if c not in fixed and c not in metric_cols and c != "cell_dir")
    df = df[fixed + metric_cols + other + ["cell_dir"]]
    df.attrs[SKIPPED_FILES] = skipped
    df.attrs[RECORDED_METRICS] = metric_cols
    return df


# --------------------------------------------------------------------------------------------
# Provenance and notes
# --------------------------------------------------------------------------------------------


def _str_values(s: pd.Series) -> Counter:
    return Counter("unknown" if is_missing(v) else str(v) for v in s)


def provenance_line(df: pd.DataFrame) -> str:
    """Which model and scene source produced these cells, and how many there are.

    Args:
        df: cells from ``collect``.

    Returns:
        E.g. ``"model: analytic (CPU stand-in for FLUX) · scenes: procedural · recipe: paper ·
        metrics protocol: paper · 12 cells (10 ok, 1 failed, 1 skipped)"``; with several models,
        sources, recipes or protocols each is listed with its cell count. The recipe and the
        protocol are left out where no cell records them (cells without a ``config.yaml``).
        Record files left out (:func:`skipped_files`) are counted last: ``" · 2 files skipped
        (not cell records)"``.
    """

    def describe(counts: Counter, described: bool) -> str:
        def one(name):
            d = MODEL_DESCRIPTIONS.get(name) if described else None
            return f"{name} ({d})" if d else name

        if len(counts) == 1:
            return one(next(iter(counts)))
        return ", ".join(f"{one(k)} ×{counts[k]}" for k in sorted(counts))

    models = _str_values(df["model"]) if len(df) else Counter()
    sources = _str_values(df["scene_source"]) if len(df) else Counter()
    status = Counter(str(s) for s in df["status"]) if len(df) else Counter()
    parts = []
    if models:
        parts.append(("model: " if len(models) == 1 else "models: ") + describe(models, True))
    if sources:
        parts.append("scenes: " + describe(sources, False))
    flags = df["generator_on_procedural"] if "generator_on_procedural" in df.columns else pd.Series(dtype=object)
    on_procedural = int(flags.map(lambda v: v is True).sum())
    if on_procedural:
        parts.append(
            f"{on_procedural} cell{'s' if on_procedural != 1 else ''} with a text-to-image generator on procedural "
            "scenes (scene.source=procedural), not the paper's scene pipeline (I⁻ generated from p⁻)"
        )
    for col, label in (("recipe", "recipe"), ("protocol", "metrics protocol")):
        if col in df.columns and len(df) and df[col].map(lambda v: not is_missing(v)).any():
            parts.append(f"{label}: " + describe(_str_values(df[col]), False))
    order = ["ok", "failed", "skipped"] + sorted(set(status) - {"ok", "failed", "skipped"})
    breakdown = ", ".join(f"{status[k]} {k}" for k in order if status.get(k) or k == "ok")
    n = len(df)
    parts.append(f"{n} cell{'s' if n != 1 else ''} ({breakdown})")
    bad = len(skipped_files(df))
    if bad:
        parts.append(f"{bad} file{'s' if bad != 1 else ''} skipped (not cell records)")
    return " · ".join(parts)


def _cell_name(r) -> str:
    var = r["variation"]
    var = "?" if var is None or pd.isna(var) else str(int(var))
    return f"{r['scene']}-{var} / {r['object']} / {r['method']}"


def cell_notes(df: pd.DataFrame, metrics: Iterable[str] = ()) -> list[str]:
    """Footnote lines: no cell and no missing value is dropped silently.

    Args:
        df: cells from ``collect``.
        metrics: the metrics whose missing values are reported.

    Returns:
        Every cell not ``ok`` with its reason, then, for each of ``metrics``, the ``ok`` cells
        without a value, grouped by the reason recorded in ``missing.<metric>``, with the count per
        method (``"LPIPS: no value in any of the 7 ok cells (...) — no VGG weights: ..."`` for a
        metric missing in every cell: its column is all "—"). Reasons are put on one line
        (whitespace collapsed), never shortened.
    """
    notes = []
    for _, r in df[df["status"] != "ok"].iterrows():
        notes.append(f"{r['status']}: {_cell_name(r)} — {reason(r.get('reason'))}")
    ok = df[df["status"] == "ok"]
    for m in metrics:
        if m not in ok.columns:
            if len(ok):
                notes.append(f"{metric_spec(m).label}: not recorded in any of the {len(ok)} ok cells")
            continue
        miss = ok[ok[m].isna()]
        if miss.empty:
            continue
        col = f"missing.{m}"
        reasons = miss[col] if col in miss.columns else pd.Series([None] * len(miss), index=miss.index)
        groups: dict[str, Counter] = {}
        for meth, why in zip(miss["method"], reasons):
            groups.setdefault(reason(why), Counter())[str(meth)] += 1
        for why in sorted(groups):
            per = groups[why]
            k = sum(per.values())
            by = ", ".join(f"{meth} ×{per[meth]}" for meth in sorted(per))
            where = f"any of the {len(ok)} ok cells" if k == len(ok) else f"{k} of {len(ok)} ok cells"
            notes.append(f"{metric_spec(m).label}: no value in {where} ({by}) — {why}")
    return notes


def reference_noise_note(df: pd.DataFrame) -> str | None:
    """A note line on the references' self-noise, the ceiling of every masked PSNR in ``df``.

    Args:
        df: cells from ``collect``.

    Returns:
        E.g. ``"reference self-noise: mean 47.6 dB (min 45.1 dB) over 2 references, about the
        highest PSNR an image can score against them"``: over the distinct references (scene,
        variation, object) of the ``ok`` cells that record a finite ``reference.self_noise_db``;
        None when none does.
    """
    col = "reference.self_noise_db"
    if col not in df.columns or df.empty:
        return None
    ok = df[(df["status"] == "ok") & df[col].map(lambda v: not is_missing(v))].copy()
    ok[col] = ok[col].astype(float)
    ok = ok[ok[col].map(math.isfinite)]
    if ok.empty:
        return None
    per_ref = ok.groupby(["scene", "variation", "object"], dropna=False)[col].first()
    n = len(per_ref)
    return (
        f"reference self-noise: mean {per_ref.mean():.1f} dB (min {per_ref.min():.1f} dB) over {n} "
        f"reference{'s' if n != 1 else ''}, about the highest PSNR an image can score against "
        f"{'them' if n != 1 else 'it'}"
    )
