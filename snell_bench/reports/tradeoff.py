"""The speed/accuracy sweep's numbers, a pure function of its run folder: one row per cell of a
setting (``grid.axes``, ``grid.presets``), the per-setting means, the Pareto front and the
reference convergence (written by :mod:`.writers`, plotted by :mod:`.figures`).

The cells of a setting are grid cells, ``<scene>-<variation>/<object>/<method>@<setting>/metrics.json``,
whose record names its ``setting`` (:mod:`snell_bench.experiment.sweep` describes the fields);
their inputs are under the group's ``_inputs/`` or ``_shared/<key>/_inputs/``. A record that is not
a cell's (:func:`~.records.load_record` against :data:`~.records.GRID_RECORD`) is left out with a
warning naming it and the problem, and listed in ``DataFrame.attrs["skipped_files"]``; a metric
recorded as NaN or ±inf is warned about and has no value ("not finite in the record").
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from snell_bench.config.grid import PRESET_AXIS
from snell_bench.metrics.registry import BUILTIN_METRICS
from snell_bench.utils.trust import UntrustedPath, safe_path

from .records import GRID_RECORD, load_record, non_finite
from .text import as_float

log = logging.getLogger(__name__)

__all__ = [
    "STAGES",
    "TOTAL_STAGES",
    "TOTAL_NOTE",
    "RECORD_METRICS",
    "CONVERGED_METRICS",
    "PRESET_AXIS",
    "SPP_KEY",
    "pareto_front",
    "complete_front",
    "collect_tradeoff",
    "reference_psnr_vs_max_spp",
    "tradeoff_table",
    "fidelity_column",
]

#: The key of the reference-convergence axis.
SPP_KEY = "reference.spp"

#: Stage times of ``timings_s``, in pipeline order; ``total`` sums :data:`TOTAL_STAGES`.
STAGES = ("scene", "warps", "reference", "true_render", "generator", "sampling", "metrics")
TOTAL_STAGES = ("warps", "sampling", "reference", "metrics")
TOTAL_NOTE = (
    "total = warps + sampling + reference + metrics; scene (making the input), true_render "
    "(procedural-only evaluation) and generator (building the model once) are not included"
)

#: The metrics a setting also scores against the converged reference (``<metric>_converged``,
#: :mod:`snell_bench.experiment.converged`).
CONVERGED_METRICS = ("psnr", "mae", "lpips")

#: The metrics a setting records: the built-in metrics of the reference and the true render (CLIP
#: and ImageReward, of the prompt, are not part of this sweep), then :data:`CONVERGED_METRICS`
#: against the converged reference; users' metrics (``metrics.extra``) follow where recorded.
RECORD_METRICS = tuple(m.name for m in BUILTIN_METRICS if "prompt" not in m.needs and "paper" in m.protocols) + tuple(
    f"{m}_converged" for m in CONVERGED_METRICS
)


# ---------------------------------------------------------------------------- reference convergence
def _load_records(root: Path, skipped: list | None = None) -> list[dict]:
    """Every record of a setting's cell below ``root`` (``<scene>-<variation>/<object>/<entry>/metrics.json``
    with a ``setting``), each with ``_dir`` (its folder relative to ``root``) and ``_group`` (its
    group's). A file that is not a cell's record is left out with a warning, and appended to
    ``skipped`` as ``(path relative to root, problem)``."""
    out = []
    for p in sorted(Path(root).glob("*/*/*/metrics.json")):
        rel = p.parent.relative_to(root)
        if any(part.startswith((".", "_")) for part in rel.parts):
            continue
        rec, problem = load_record(p, GRID_RECORD)
        if problem is not None:
            if skipped is not None:  # warned once, by the reader that reports it
                log.warning("%s is not a cell's record, left out of the report: %s", p, problem)
                skipped.append((p.relative_to(root).as_posix(), problem))
            continue
        if "setting" in rec:
            rec["_dir"], rec["_group"] = rel.as_posix(), rel.parent.as_posix()
            out.append(rec)
    return out


def _is_spp_record(rec: dict) -> bool:
    return rec.get("axis") not in (None, PRESET_AXIS) and set(rec.get("overrides") or {}) == {SPP_KEY}


def reference_psnr_vs_max_spp(
    root: str | os.PathLike, records: Sequence[dict] | None = None
) -> dict[str, float | None]:
    """How far each reference render of an spp axis is from the highest-spp one.

    For every axis whose settings vary only ``reference.spp``: the masked PSNR (grayscale,
    histogram-matched) of each setting's saved ``reference.npy`` against the highest-spp setting's
    of the same scene, over that setting's ``metric_mask.npy``.

    Args:
        root: the sweep's run folder.
        records: its records as read by ``_load_records`` (read from ``root`` if not given).

    Returns:
        ``{record folder relative to root: PSNR}`` for the ok settings of those axes; ``None`` for
        the highest-spp setting itself, where a file or the mask is missing, or where the PSNR is
        not finite.
    """
    from snell_bench.metrics import MetricUnavailable, masked_psnr

    root = Path(root)
    records = _load_records(root) if records is None else records
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        if r.get("status") == "ok" and _is_spp_record(r):
            groups.setdefault((r["_group"], r.get("method_name"), r["axis"]), []).append(r)
    out: dict[str, float | None] = {}

    def load(r, name):  # the record's inputs_dir must stay inside its group (utils.trust.safe_path)
        try:
            p = safe_path(root / r["_group"], f"{r.get('inputs_dir', '')}/{name}", "trade-off record's inputs_dir")
        except UntrustedPath as e:
            log.warning("%s; its reference PSNR is left out", e)
            return None
        return np.load(p, allow_pickle=False) if p.is_file() else None

    for recs in groups.values():
        best = max(recs, key=lambda r: float((r.get("overrides") or {})[SPP_KEY]))
        ref_max, mask = load(best, "reference.npy"), load(best, "metric_mask.npy")
        for r in recs:
            val = None
            if r is not best and ref_max is not None and mask is not None:
                ref = load(r, "reference.npy")
                if ref is not None and ref.shape == ref_max.shape:
                    try:
                        v = float(masked_psnr(ref, ref_max, mask))
                        val = v if math.isfinite(v) else None
                    except MetricUnavailable:
                        val = None
            out[r["_dir"]] = val
    return out


# ---------------------------------------------------------------------------- Pareto front
def complete_front(table: pd.DataFrame, cost: np.ndarray, score: np.ndarray) -> np.ndarray:
    """The settings on the Pareto front of those that succeeded on every scene, cheapest first.

    Args:
        table: a per-setting table (:func:`tradeoff_table`) with ``n`` and ``n_scenes``.
        cost: one value per row of ``table``.
        score: one value per row of ``table``.

    Returns:
        Row positions into ``table``, sorted by cost (stable); empty when no setting is complete.
    """
    complete = (table["n"] == table["n_scenes"]).to_numpy()
    front = np.flatnonzero(pareto_front(np.where(complete, cost, np.nan), np.where(complete, score, np.nan)))
    return front[np.argsort(np.asarray(cost, dtype=float)[front], kind="mergesort")]


def pareto_front(cost: Sequence[float], score: Sequence[float]) -> np.ndarray:
    """The points not dominated when minimising ``cost`` and maximising ``score``.

    Point ``j`` dominates ``i`` if ``cost[j] <= cost[i]`` and ``score[j] >= score[i]`` with at least
    one strict. Identical points do not dominate each other (all of them are on the front). A point
    with NaN cost or score is never on the front and dominates nothing.

    Args:
        cost: one value per point.
        score: one value per point.

    Returns:
        A boolean array, True for the points on the front.

    Raises:
        ValueError: ``cost`` and ``score`` differ in length.
    """
    c = np.asarray(cost, dtype=float).reshape(-1)
    s = np.asarray(score, dtype=float).reshape(-1)
    if c.shape != s.shape:
        raise ValueError(f"cost and score must have the same length, got {c.shape} and {s.shape}")
    front = np.zeros(c.shape, dtype=bool)
    valid = np.flatnonzero(~(np.isnan(c) | np.isnan(s)))
    if valid.size == 0:
        return front
    order = valid[np.lexsort((-s[valid], c[valid]))]  # cost ascending, score descending
    best_before = None  # highest score among strictly cheaper points
    k = 0
    while k < order.size:
        group = [order[k]]
        while k + len(group) < order.size and c[order[k + len(group)]] == c[order[k]]:
            group.append(order[k + len(group)])
        top = s[group[0]]
        for i in group:
            front[i] = s[i] == top and (best_before is None or s[i] > best_before)
        best_before = top if best_before is None else max(best_before, top)
        k += len(group)
    return front


# ---------------------------------------------------------------------------- tables
def _value_text(v) -> str | None:
    """An axis value for a CSV cell: scalars as text, compound values as JSON."""
    if v is None:
        return None
    return json.dumps(v, sort_keys=True) if isinstance(v, (dict, list)) else str(v)


def collect_tradeoff(root: str | os.PathLike) -> pd.DataFrame:
    """One row per scene x setting below ``root``.

    Args:
        root: the sweep's run folder.

    Returns:
        A DataFrame with the identity (scene, variation, setting, slug, order, axis, value,
        overrides, status, reason, model, inputs key), knobs (``knob.<name>``), stage times
        (``timings_s.<stage>``), sampler breakdown (``sampler_s.<part>``), model calls
        (``model_calls.<branch>``), the :data:`RECORD_METRICS` with their ``missing.<metric>``
        reasons, ``reference_psnr_vs_max_spp`` (recomputed from the saved references),
        ``converged_spp``, ``reference_self_noise_db`` (the setting's reference against its own
        noise-free limit, from its two halves; NaN without halves) and ``dir``; sorted by scene, then the setting's order in the sweep.
        Empty when there is no cell of a setting. With several methods a setting is
        ``<method>@<setting>``; ``group`` is the cell's scene/object group. ``attrs["skipped_files"]`` lists the files left out
        (not a setting's record) as ``(path relative to root, problem)``; a metric recorded as NaN or
        ±inf is NaN with ``missing.<metric>`` = "not finite in the record (inf)".
    """
    root = Path(root)
    skipped: list[tuple[str, str]] = []
    records = _load_records(root, skipped)
    conv = reference_psnr_vs_max_spp(root, records)
    rows = []
    for r in records:
        bad = non_finite(r.get("metrics"))
        for name, value in bad.items():
            path = root / r["_dir"] / "metrics.json"
            log.warning("setting %s: metric %s is %s in %s: not finite, shown as missing", r["_dir"], name, value, path)
        row = {
            "scene": r.get("scene"),
            "variation": r.get("variation"),
            "group": r["_group"],
            "method": r.get("method_name"),
            "setting": r.get("setting"),
            "slug": r.get("slug"),
            "order": r.get("order"),
            "axis": r.get("axis"),
            "value": _value_text(r.get("value")),
            "overrides": json.dumps(r.get("overrides") or {}, sort_keys=True),
            "status": r.get("status"),
            "reason": r.get("reason"),
            "model": r.get("model"),
            "inputs_key": r.get("inputs_key"),
            "inputs_reused_from": r.get("inputs_reused_from"),
        }
        for k, v in (r.get("knobs") or {}).items():
            row[f"knob.{k}"] = v
        for k in STAGES + ("total",):
            row[f"timings_s.{k}"] = as_float((r.get("timings_s") or {}).get(k))
        for k, v in (r.get("sampler_timings_s") or {}).items():
            row[f"sampler_s.{k}"] = as_float(v)
        for k, v in (r.get("model_calls") or {}).items():
            row[f"model_calls.{k}"] = v
        extra = [k for k in (r.get("metrics") or {}) if k not in RECORD_METRICS]  # users' metrics
        for k in (*RECORD_METRICS, *extra):
            row[k] = float("nan") if k in bad else as_float((r.get("metrics") or {}).get(k))
            row[f"missing.{k}"] = (
                f"not finite in the record ({bad[k]})" if k in bad else (r.get("missing") or {}).get(k)
            )
        row["reference_psnr_vs_max_spp"] = as_float(conv.get(r["_dir"], r.get("reference_psnr_vs_max_spp")))
        row["converged_spp"] = (r.get("converged_reference") or {}).get("spp")
        row["reference_self_noise_db"] = as_float((r.get("reference") or {}).get("self_noise_db"))
        row["dir"] = r["_dir"]
        rows.append(row)
    df = pd.DataFrame(rows)
    if not df.empty and df["method"].nunique() > 1:
        df["setting"] = df["method"].astype(str) + "@" + df["setting"].astype(str)
    if not df.empty:
        df["order"] = pd.to_numeric(df["order"], errors="coerce")
        df = df.sort_values(["scene", "order", "setting"], na_position="last", kind="mergesort").reset_index(drop=True)
    df.attrs["skipped_files"] = skipped
    return df


def tradeoff_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per-setting means over the scenes where the setting is ``ok``.

    Args:
        df: rows from :func:`collect_tradeoff`.

    Returns:
        One row per setting (index ``setting``, in sweep order): ``axis``, ``n`` (ok scenes),
        ``n_scenes``, the mean of every stage time, ``psnr``, ``psnr_true``, ``lpips``, ``mae``,
        the ``*_converged`` metrics, ``reference_psnr_vs_max_spp`` and ``reference_self_noise_db``
        (a mean in dB); ``lpips_missing`` (the
        reasons, when LPIPS has no value) and ``pareto``: on the front of (mean total time ↓, mean
        :func:`fidelity_column` ↑) among the settings that succeeded on every scene.

    Raises:
        FileNotFoundError: ``df`` is empty.
    """
    if df.empty:
        raise FileNotFoundError("no cells of a setting to tabulate")
    n_scenes = df["group"].nunique() if "group" in df else df["scene"].nunique()
    ok = df[df["status"] == "ok"]
    cols = [f"timings_s.{k}" for k in STAGES + ("total",)] + [
        "psnr",
        "psnr_true",
        "lpips",
        "mae",
        "psnr_converged",
        "mae_converged",
        "lpips_converged",
        "reference_psnr_vs_max_spp",
        "reference_self_noise_db",
    ]
    order = df.groupby("setting", sort=False)["order"].min().sort_values(kind="mergesort")
    rows = []
    for setting in order.index:
        g = ok[ok["setting"] == setting]
        first = df[df["setting"] == setting].iloc[0]
        row = {"setting": setting, "axis": first["axis"], "n": len(g), "n_scenes": n_scenes}
        for c in cols:
            row[c] = float(g[c].mean()) if c in g.columns and g[c].notna().any() else float("nan")
        reasons = sorted({str(v) for v in g.get("missing.lpips", pd.Series(dtype=object)).dropna()})
        row["lpips_missing"] = "; ".join(reasons) if reasons else None
        rows.append(row)
    table = pd.DataFrame(rows).set_index("setting")
    complete = table["n"] == n_scenes
    cost = table["timings_s.total"].where(complete)
    table["pareto"] = pareto_front(cost.to_numpy(), table[fidelity_column(table)].where(complete).to_numpy())
    return table


def fidelity_column(table: pd.DataFrame) -> str:
    """The fidelity the Pareto front uses.

    Args:
        table: from :func:`tradeoff_table`.

    Returns:
        ``"psnr_converged"`` (PSNR against the converged reference, which does not move with
        ``reference.spp``) where the sweep has it, else ``"psnr"`` (against each setting's own
        reference).
    """
    return "psnr_converged" if "psnr_converged" in table and table["psnr_converged"].notna().any() else "psnr"
