"""The speed/accuracy sweep's report: a pure function of a sweep's run folder (see
:mod:`snell_bench.experiment.tradeoff` for the layout and the meaning of every field)."""

from __future__ import annotations

import json
import math
import os
import re
from collections import Counter
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from snell_bench.utils.io import atomic_write_bytes as _atomic_write_bytes
from snell_bench.utils.io import write_json

__all__ = [
    "STAGES",
    "TOTAL_STAGES",
    "TOTAL_NOTE",
    "RECORD_METRICS",
    "PRESET_AXIS",
    "SPP_KEY",
    "pareto_front",
    "collect_tradeoff",
    "reference_psnr_vs_max_spp",
    "update_spp_records",
    "tradeoff_table",
    "tradeoff_markdown",
    "stdout_table",
    "fidelity_column",
    "pareto_figure",
    "build_tradeoff_report",
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

#: The metrics a setting records (CLIP and ImageReward are not part of this sweep).
RECORD_METRICS = ("psnr", "mae", "lpips", "psnr_true", "psnr_converged", "mae_converged", "lpips_converged")

PRESET_AXIS = "preset"
_SCENE_DIR_RE = re.compile(r"^(?P<scene>.+)-(?P<variation>\d+)$")


# ---------------------------------------------------------------------------- reference convergence
def _load_records(root: Path) -> list[dict]:
    """Every ``result.json`` below ``root`` (``<scene>-<variation>/<slug>/result.json``), each with
    ``_dir`` (its folder relative to ``root``); unreadable ones as failed records."""
    out = []
    for p in sorted(Path(root).glob("*/*/result.json")):
        rel = p.parent.relative_to(root)
        if any(part.startswith((".", "_")) for part in rel.parts):
            continue
        try:
            rec = json.loads(p.read_text())
            if not isinstance(rec, dict):
                raise ValueError("not a JSON object")
        except (OSError, ValueError) as e:
            m = _SCENE_DIR_RE.match(rel.parts[0])
            rec = {"status": "failed", "reason": f"result.json unreadable: {e}", "setting": rel.parts[1],
                   "scene": m["scene"] if m else rel.parts[0], "variation": int(m["variation"]) if m else None}
        rec["_dir"] = rel.as_posix()
        out.append(rec)
    return out


def _is_spp_record(rec: dict) -> bool:
    return rec.get("axis") not in (None, PRESET_AXIS) and set(rec.get("overrides") or {}) == {SPP_KEY}


def reference_psnr_vs_max_spp(
    root: str | os.PathLike, records: Sequence[dict] | None = None
) -> dict[str, float | None]:
    """``{record folder: PSNR}`` for the settings of every axis that varies only ``reference.spp``
    (see the module docstring), from the saved ``reference.npy`` and ``metric_mask.npy``.
    ``None`` for the highest-spp setting itself and where a file or the mask is missing."""
    from snell_bench.metrics import MetricUnavailable, masked_psnr

    root = Path(root)
    records = _load_records(root) if records is None else records
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        if r.get("status") == "ok" and _is_spp_record(r):
            groups.setdefault((r["_dir"].split("/")[0], r["axis"]), []).append(r)
    out: dict[str, float | None] = {}

    def load(r, name):
        p = root / r["_dir"].split("/")[0] / str(r.get("inputs_dir", "")) / name
        return np.load(p) if p.is_file() else None

    for (_, _), recs in groups.items():
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


def update_spp_records(scene_dir: Path) -> None:
    """Write ``reference_psnr_vs_max_spp`` into the spp-axis records of one scene (only if changed)."""
    if not scene_dir.is_dir():
        return
    root = scene_dir.parent
    records = [r for r in _load_records(root) if r["_dir"].split("/")[0] == scene_dir.name]
    values = reference_psnr_vs_max_spp(root, records)
    for r in records:
        if r["_dir"] not in values:
            continue
        v = values[r["_dir"]]
        if "reference_psnr_vs_max_spp" in r and r["reference_psnr_vs_max_spp"] == v:
            continue
        rec = {k: val for k, val in r.items() if k != "_dir"}
        rec["reference_psnr_vs_max_spp"] = v
        write_json(root / r["_dir"] / "result.json", rec)


# ---------------------------------------------------------------------------- Pareto front
def pareto_front(cost: Sequence[float], score: Sequence[float]) -> np.ndarray:
    """Boolean mask of the points not dominated when minimising ``cost`` and maximising ``score``.

    Point ``j`` dominates ``i`` if ``cost[j] <= cost[i]`` and ``score[j] >= score[i]`` with at least
    one strict. Identical points do not dominate each other (all of them are on the front). A point
    with NaN cost or score is never on the front and dominates nothing."""
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


# ---------------------------------------------------------------------------- report
def _float(v) -> float:
    try:
        return float("nan") if v is None else float(v)
    except (TypeError, ValueError):
        return float("nan")


def _value_text(v) -> str | None:
    """An axis value for a CSV cell: scalars as text, compound values as JSON."""
    if v is None:
        return None
    return json.dumps(v, sort_keys=True) if isinstance(v, (dict, list)) else str(v)


def collect_tradeoff(root: str | os.PathLike) -> pd.DataFrame:
    """One row per scene x setting below ``root``: identity, knobs (``knob.<name>``), stage times
    (``timings_s.<stage>``), sampler breakdown (``sampler_s.<part>``), model calls
    (``model_calls.<branch>``), metrics, ``missing.<metric>`` reasons and
    ``reference_psnr_vs_max_spp`` (recomputed from the saved references). Sorted by scene, then the
    setting's order in the sweep."""
    root = Path(root)
    records = _load_records(root)
    conv = reference_psnr_vs_max_spp(root, records)
    rows = []
    for r in records:
        row = {
            "scene": r.get("scene"), "variation": r.get("variation"), "setting": r.get("setting"),
            "slug": r.get("slug"), "order": r.get("order"), "axis": r.get("axis"),
            "value": _value_text(r.get("value")),
            "overrides": json.dumps(r.get("overrides") or {}, sort_keys=True),
            "status": r.get("status"), "reason": r.get("reason"), "model": r.get("model"),
            "inputs_key": r.get("inputs_key"), "inputs_reused_from": r.get("inputs_reused_from"),
        }
        for k, v in (r.get("knobs") or {}).items():
            row[f"knob.{k}"] = v
        for k in STAGES + ("total",):
            row[f"timings_s.{k}"] = _float((r.get("timings_s") or {}).get(k))
        for k, v in (r.get("sampler_timings_s") or {}).items():
            row[f"sampler_s.{k}"] = _float(v)
        for k, v in (r.get("model_calls") or {}).items():
            row[f"model_calls.{k}"] = v
        for k in RECORD_METRICS:
            row[k] = _float((r.get("metrics") or {}).get(k))
            row[f"missing.{k}"] = (r.get("missing") or {}).get(k)
        row["reference_psnr_vs_max_spp"] = _float(conv.get(r["_dir"], r.get("reference_psnr_vs_max_spp")))
        row["converged_spp"] = (r.get("converged_reference") or {}).get("spp")
        row["dir"] = r["_dir"]
        rows.append(row)
    df = pd.DataFrame(rows)
    if df.empty:
        return df
    df["order"] = pd.to_numeric(df["order"], errors="coerce")
    return df.sort_values(["scene", "order", "setting"], na_position="last", kind="mergesort").reset_index(drop=True)


def tradeoff_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per setting (rows in sweep order): means over the scenes where it is ``ok`` of every stage
    time, ``psnr``, ``psnr_true``, ``lpips``, the ``*_converged`` metrics and ``reference_psnr_vs_max_spp``; ``n`` (ok scenes),
    ``n_scenes``, ``lpips_missing`` (the reasons, when LPIPS has no value) and ``pareto``: on the
    front of (mean total time ↓, mean :func:`fidelity_column` ↑) among the settings that succeeded on every
    scene."""
    if df.empty:
        raise FileNotFoundError("no settings (result.json) to tabulate")
    n_scenes = df["scene"].nunique()
    ok = df[df["status"] == "ok"]
    cols = [f"timings_s.{k}" for k in STAGES + ("total",)] + ["psnr", "psnr_true", "lpips", "mae",
                                                              "psnr_converged", "mae_converged", "lpips_converged",
                                                              "reference_psnr_vs_max_spp"]
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
    """The fidelity the Pareto front uses: PSNR against the converged reference where the sweep has
    one (it does not move with ``reference.spp``), else PSNR against each setting's own reference."""
    return "psnr_converged" if "psnr_converged" in table and table["psnr_converged"].notna().any() else "psnr"


def _fmt(v, spec: str = "{:.2f}") -> str:
    return "—" if v is None or (isinstance(v, float) and math.isnan(v)) else spec.format(v)


def tradeoff_markdown(table: pd.DataFrame, df: pd.DataFrame, title: str = "Speed/accuracy trade-off") -> str:
    """The per-setting table as Markdown, with the provenance and notes (failures, missing metrics)."""
    models = sorted({str(m) for m in df["model"].dropna()}) if "model" in df else []
    status = Counter(str(s) for s in df["status"])
    counts = ", ".join(f"{v} {k}" for k, v in sorted(status.items()))
    spps = sorted({int(v) for v in df.get("converged_spp", pd.Series(dtype=float)).dropna()})
    conv_text = f"{'/'.join(map(str, spps))} spp" if spps else "none in this sweep"
    fid_text = "PSNR (conv.)" if fidelity_column(table) == "psnr_converged" else "PSNR"
    lines = [
        f"# {title}",
        "",
        f"Means over the scenes where a setting succeeded ({', '.join(sorted(df['scene'].dropna().unique()))}); "
        f"model: {', '.join(models) or 'unknown'}; {len(df)} runs ({counts}). "
        f"Times in seconds; {TOTAL_NOTE}. PSNR: masked, vs the setting's own reference render (so it also "
        "moves with reference.spp, see the reference convergence below); PSNR (conv.): vs a converged reference "
        f"of the same scene, object and resolution ({conv_text}); PSNR (true): vs the true render, traced with "
        "reference.true_max_bounces (the setting's warps.max_bounces where that is null). "
        f"**pareto**: on the front of (mean total ↓, mean {fid_text} ↑) among the settings that succeeded on "
        "every scene. Presets in bold.",
        "",
    ]
    head = ["setting", "scene", "warps", "reference", "true render", "generator", "sampling", "metrics",
            "total", "PSNR", "PSNR (conv.)", "PSNR (true)", "LPIPS", "n", "pareto"]
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|" + "|".join(["---"] + ["---:"] * (len(head) - 2) + [":---:"]) + "|")
    for setting, r in table.iterrows():
        label = f"**{setting}**" if r["axis"] == PRESET_AXIS else str(setting)
        lp = _fmt(r["lpips"], "{:.3f}") if not math.isnan(r["lpips"]) else "missing"
        cells = [label] + [_fmt(r[f"timings_s.{k}"]) for k in ("scene", "warps", "reference", "true_render",
                                                              "generator", "sampling", "metrics", "total")]
        cells += [_fmt(r["psnr"]), _fmt(r["psnr_converged"]), _fmt(r["psnr_true"]), lp,
                  f"{int(r['n'])}/{int(r['n_scenes'])}",
                  "★" if r["pareto"] else ""]
        if r["axis"] == PRESET_AXIS:
            cells = [f"**{x}**" if x and not x.startswith("**") else x for x in cells]
        lines.append("| " + " | ".join(cells) + " |")
    spp = df[df.apply(_is_spp_axis_row, axis=1)] if not df.empty else df
    if not spp.empty:
        lines += ["", "## Reference convergence", "",
                  "Masked PSNR (grayscale, histogram-matched) of each reference render against the highest-spp "
                  "reference of its axis for the same scene, over that reference's metric mask; mean over scenes; "
                  "computed from the saved float references (`reference.npy`).", "",
                  "| setting | spp | PSNR vs max spp |", "|---|---:|---:|"]
        for (axis, setting), g in spp.groupby(["axis", "setting"], sort=False):
            n = int(g["knob.spp"].iloc[0]) if "knob.spp" in g and g["knob.spp"].notna().any() else None
            top = n is not None and n == spp.loc[spp["axis"] == axis, "knob.spp"].max()
            v = table.loc[setting, "reference_psnr_vs_max_spp"] if setting in table.index else float("nan")
            lines.append(f"| {setting} | {n if n is not None else '—'} | "
                         f"{'(highest spp: the comparison reference)' if top else _fmt(v)} |")
    notes = []
    for _, r in df[df["status"] != "ok"].iterrows():
        notes.append(f"{r['status']}: {r['scene']} / {r['setting']} — {' '.join(str(r['reason']).split())}")
    for m in RECORD_METRICS:
        col = f"missing.{m}"
        ok = df[df["status"] == "ok"]
        if col in ok and ok[m].isna().any():
            for why, n in Counter(str(v) for v in ok.loc[ok[m].isna(), col]).items():
                notes.append(f"{m}: missing in {n} of {len(ok)} ok runs — {' '.join(why.split())}")
    if notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in notes]
    return "\n".join(lines) + "\n"


def _is_spp_axis_row(r) -> bool:
    try:
        return (r["status"] == "ok" and isinstance(r["axis"], str) and r["axis"] != PRESET_AXIS
                and set(json.loads(r["overrides"])) == {SPP_KEY})
    except (TypeError, ValueError):
        return False


def pareto_figure(table: pd.DataFrame, out_png: str | os.PathLike, title: str = "") -> Path:
    """``pareto.png``: mean total seconds (log x) against mean PSNR vs the reference, one marker and
    colour per axis, presets as labelled stars, the Pareto front as a step line; a second panel with
    PSNR vs the true render when any setting has it."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    fid = fidelity_column(table)
    panels = [(fid, "mean masked PSNR vs converged reference (dB)" if fid == "psnr_converged"
               else "mean masked PSNR vs reference (dB)")]
    if table["psnr_true"].notna().any():
        panels.append(("psnr_true", "mean masked PSNR vs true render (dB)"))
    fig = Figure(figsize=(6.0 * len(panels), 4.6), dpi=110, facecolor="white")
    FigureCanvasAgg(fig)
    axes_names = [a for a in dict.fromkeys(table["axis"]) if a not in (None, PRESET_AXIS) and not _isnan(a)]
    markers = "osD^v<>phX8"
    colors = [f"C{i}" for i in range(10)]
    for pi, (metric, ylabel) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), pi + 1)
        x = table["timings_s.total"].to_numpy(float)
        y = table[metric].to_numpy(float)
        base = (table["axis"].isna()).to_numpy() | np.array([_isnan(a) for a in table["axis"]])
        if base.any():
            ax.scatter(x[base], y[base], marker="o", s=60, facecolors="none", edgecolors="black", label="baseline",
                       zorder=3)
        for i, a in enumerate(axes_names):
            sel = (table["axis"] == a).to_numpy()
            ax.scatter(x[sel], y[sel], marker=markers[i % len(markers)], color=colors[i % len(colors)], s=28,
                       label=a, zorder=3)
            for lab, xi, yi in zip(table.index[sel], x[sel], y[sel]):
                if np.isfinite(xi) and np.isfinite(yi):
                    ax.annotate(lab.split("=", 1)[-1], (xi, yi), fontsize=6, xytext=(3, 2), textcoords="offset points",
                                color=colors[i % len(colors)])
        pre = (table["axis"] == PRESET_AXIS).to_numpy()
        if pre.any():
            ax.scatter(x[pre], y[pre], marker="*", s=160, color="gold", edgecolors="black", linewidths=0.6,
                       label="presets", zorder=4)
            for lab, xi, yi in zip(table.index[pre], x[pre], y[pre]):
                if np.isfinite(xi) and np.isfinite(yi):
                    ax.annotate(lab.split(":", 1)[-1], (xi, yi), fontsize=8, fontweight="bold", xytext=(5, -10),
                                textcoords="offset points")
        complete = (table["n"] == table["n_scenes"]).to_numpy()
        front = pareto_front(np.where(complete, x, np.nan), np.where(complete, y, np.nan))
        if front.any():
            o = np.argsort(x[front], kind="mergesort")
            ax.step(x[front][o], y[front][o], where="post", color="grey", lw=1.2, ls="--", label="Pareto front",
                    zorder=2)
            ax.scatter(x[front], y[front], s=150, facecolors="none", edgecolors="grey", linewidths=1.0, zorder=2)
        finite = x[np.isfinite(x)]
        if finite.size and (finite > 0).all():
            ax.set_xscale("log")
            ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
            ax.xaxis.set_minor_locator(LogLocator(base=10, subs=tuple(range(1, 10))))
            ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
            ax.xaxis.set_minor_formatter(NullFormatter())
        _clip_outliers(ax, table.index, x, y)
        ax.set_xlabel("mean total time per image (s, log scale)")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
        if pi == 0:
            ax.legend(fontsize=7, loc="best")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, facecolor="white", metadata={"Software": None})
    return out_png


def _clip_outliers(ax, labels, x: np.ndarray, y: np.ndarray) -> None:
    """Keep the y range on the bulk of the settings: settings separated from all others by a gap
    more than twice the rest of the range (e.g. one bounce, which breaks the glass) are drawn at the
    lower edge as arrows labelled with their values."""
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 4:
        return
    ys = np.sort(y[ok])
    gaps = np.diff(ys)
    i = int(np.argmax(gaps))
    if gaps[i] <= 2 * (ys[-1] - ys[i + 1]) or i + 1 > len(ys) // 2:  # no isolated low cluster
        return
    lo = ys[i + 1]
    out = ok & (y < lo)
    bottom = lo - 0.05 * (y[ok & ~out].max() - lo + 1e-9)
    ax.set_ylim(bottom=bottom)
    for lab, xi, yi in zip(np.asarray(labels)[out], x[out], y[out]):
        ax.annotate(f"{lab}: {yi:.2f} dB", (xi, bottom), xytext=(0, 14), textcoords="offset points", fontsize=6,
                    ha="center", arrowprops={"arrowstyle": "->", "lw": 0.8, "color": "black"})


def _isnan(v) -> bool:
    return isinstance(v, float) and math.isnan(v)


def build_tradeoff_report(runs_root: str | os.PathLike, out_dir: str | os.PathLike) -> list[Path]:
    """Write ``tradeoff.csv`` (one row per scene x setting), ``tradeoff.md`` and ``pareto.png`` from
    a sweep's run folder alone; returns the written paths."""
    runs_root, out_dir = Path(runs_root), Path(out_dir)
    df = collect_tradeoff(runs_root)
    if df.empty:
        raise FileNotFoundError(f"no settings (result.json) below {runs_root}")
    out_dir.mkdir(parents=True, exist_ok=True)
    table = tradeoff_table(df)
    csv = out_dir / "tradeoff.csv"
    _atomic_write_bytes(csv, df.to_csv(index=False, lineterminator="\n").encode())
    md = out_dir / "tradeoff.md"
    _atomic_write_bytes(md, tradeoff_markdown(table, df, f"Speed/accuracy trade-off ({runs_root.name})").encode())
    png = pareto_figure(table, out_dir / "pareto.png", f"{runs_root.name}: cost vs fidelity")
    return [csv, md, png]


def stdout_table(table: pd.DataFrame) -> str:
    t = pd.DataFrame({
        "total s": table["timings_s.total"].map(lambda v: _fmt(v)),
        "sampling s": table["timings_s.sampling"].map(lambda v: _fmt(v)),
        "PSNR": table["psnr"].map(lambda v: _fmt(v)),
        "PSNR conv": table["psnr_converged"].map(lambda v: _fmt(v)),
        "PSNR true": table["psnr_true"].map(lambda v: _fmt(v)),
        "n": [f"{int(a)}/{int(b)}" for a, b in zip(table["n"], table["n_scenes"])],
        "pareto": table["pareto"].map(lambda v: "*" if v else ""),
    }, index=table.index)
    return t.to_string()
