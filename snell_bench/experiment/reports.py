"""Tables and figures of the paper, rebuilt from a run directory alone.

A run directory holds one folder per cell, ``<scene>-<variation>/<object>/<method>/``, with
``image.png``, ``reference.png``, ``mask.png`` and ``metrics.json``. This module reads those files
and nothing else:

- :func:`collect` gathers every cell into a :class:`pandas.DataFrame`, one row per cell.
- :func:`method_table` (Table 1: methods x metrics), :func:`scene_table` (scenes x methods for one
  metric) and :func:`ablation_table` (the ablation rows in the paper's order) average over the
  cells whose ``status`` is ``"ok"``.
- :func:`to_markdown`, :func:`to_latex` and :func:`to_csv` write a table. The Markdown and LaTeX
  versions carry a provenance line (which model and scene source produced the numbers, how many
  cells) and a notes section listing every failed or skipped cell with its reason, and every metric
  that has no value in some of the averaged cells, so no cell is dropped silently.
- :func:`qualitative_figure` draws reference | Snellcaster | baselines for a few cells, each tile
  with an inset zoom on the object's bounding box.
- :func:`build_reports` writes all of the above, plus a ``README.md`` linking them.

Conventions
-----------
- A table is a DataFrame whose index holds the row labels (``index.name`` is the row header) and
  whose columns are metric names (``psnr``, ``lpips``, ...) plus ``n``, the number of ``ok`` cells
  averaged; :func:`scene_table` instead has method labels as columns and one metric for all of
  them. Values are floats, NaN where no cell has a value; the writers show NaN as "—".
- Writers read display hints from ``table.attrs``: ``provenance``, ``notes``, ``caption``,
  ``metric`` (the metric of every value column, for scene tables) and ``highlight`` (``"columns"``
  or ``"rows"``: where best and second-best are ranked). The table builders set them.
- Best and second-best are ranked on the values as displayed (rounded to the metric's format), so
  ties share the mark; a column with fewer than two values gets no mark.
- Ordering is deterministic: cells sorted by scene, variation, object, method; method rows sorted
  by method name unless an ``order`` is given.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import pandas as pd

__all__ = [
    "Metric",
    "METRICS",
    "TABLE1_METRICS",
    "ABLATION_METRICS",
    "ABLATION_ROWS",
    "MODEL_DESCRIPTIONS",
    "MISSING",
    "collect",
    "provenance_line",
    "cell_notes",
    "method_table",
    "scene_table",
    "ablation_table",
    "to_markdown",
    "to_latex",
    "to_csv",
    "qualitative_figure",
    "build_reports",
]

MISSING = "—"
"""How a missing value is shown in Markdown and LaTeX tables."""


@dataclass(frozen=True)
class Metric:
    """How a metric is labelled, compared and printed."""

    name: str
    label: str
    higher_is_better: bool
    format: str

    @property
    def arrow(self) -> str:
        """"↑" if higher is better, else "↓"."""
        return "↑" if self.higher_is_better else "↓"

    def fmt(self, value: float) -> str:
        """The value as printed in a table (``MISSING`` for NaN)."""
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return MISSING
        return self.format.format(value)


METRICS: dict[str, Metric] = {
    m.name: m
    for m in (
        Metric("psnr", "PSNR", True, "{:.2f}"),
        Metric("mae", "MAE", False, "{:.4f}"),
        Metric("lpips", "LPIPS", False, "{:.3f}"),
        Metric("clip", "CLIP", True, "{:.2f}"),
        Metric("image_reward", "ImageReward", True, "{:.3f}"),
        Metric("psnr_true", "PSNR (true)", True, "{:.2f}"),
    )
}
"""The metrics of ``metrics.json``: label, direction and print format."""

TABLE1_METRICS = ("clip", "image_reward", "psnr", "lpips")
"""Columns of the paper's Table 1, in its order."""

ABLATION_METRICS = ("mae", "psnr", "lpips", "clip", "image_reward")
"""Columns of the paper's ablation table, in its order."""

ABLATION_ROWS: tuple[tuple[str, str], ...] = (
    ("snellcaster", "Full"),
    ("no_reflection", "w/o reflection"),
    ("no_pano", "w/o panorama"),
    ("no_dpa", "w/o DPA"),
    ("no_lpw", "w/o LPW"),
    ("no_tt", "w/o time travel"),
)
"""Ablation rows in the paper's order: (method name, row label)."""

MODEL_DESCRIPTIONS = {
    "analytic": "CPU stand-in for FLUX",
    "tiny_flux": "tiny random-weight FLUX, outputs meaningless",
    "flux": "FLUX.1-dev",
}
"""What each ``model`` value of ``metrics.json`` is, for provenance lines."""

_BASE_COLUMNS = (
    "experiment", "scene", "variation", "object", "method", "method_label", "status", "reason",
    "model", "scene_source",
)
_CELL_DIR_RE = re.compile(r"^(?P<scene>.+)-(?P<variation>\d+)$")


# --------------------------------------------------------------------------------------------
# Collecting cells
# --------------------------------------------------------------------------------------------


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


def _float_or_nan(v) -> float:
    if v is None:
        return float("nan")
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def _row_from_record(rec: dict, rel: Path) -> dict:
    row = {k: rec.get(k) for k in _BASE_COLUMNS}
    for k, v in _cell_from_path(rel).items():
        if row.get(k) is None:
            row[k] = v
    for k, v in rec.items():
        if k not in row and k not in ("metrics", "missing", "timings_s") and not isinstance(v, (dict, list)):
            row[k] = v
    for k, v in (rec.get("metrics") or {}).items():
        row[k] = _float_or_nan(v)
    for k, v in (rec.get("missing") or {}).items():
        row[f"missing.{k}"] = None if v is None else str(v)
    for k, v in (rec.get("timings_s") or {}).items():
        row[f"timings_s.{k}"] = _float_or_nan(v)
    for group in ("decisions", "warps"):  # what the cell modelled (flattened: decisions.panorama.used)
        row.update(_flatten(rec.get(group) or {}, group))
    row["cell_dir"] = rel.as_posix()
    return row


def _flatten(d: dict, prefix: str) -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}.{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key))
        elif not isinstance(v, list):
            out[key] = v
    return out


def collect(run_dir: str | os.PathLike) -> pd.DataFrame:
    """One row per cell below ``run_dir``.

    Every ``metrics.json`` below ``run_dir`` gives a row with the columns ``experiment``, ``scene``,
    ``variation``, ``object``, ``method``, ``method_label``, ``status``, ``reason``, ``model``,
    ``scene_source``; one column per metric (``psnr``, ``lpips``, ...; NaN where null); the reason
    a metric is missing as ``missing.<metric>``; stage timings as ``timings_s.<stage>``; and
    ``cell_dir``, the cell's folder relative to ``run_dir``. Folders whose name starts with "." or
    "_" (e.g. shared ``_inputs``) are not cells. A ``metrics.json`` that cannot be read,
    and a cell folder with a ``config.yaml`` but no ``metrics.json``, give a row with status
    ``"failed"`` and the reason, with scene, variation, object and method taken from the path.
    Rows are sorted by scene, variation, object, method and folder.
    """
    run_dir = Path(run_dir)
    rows = []
    seen = set()
    for path in sorted(run_dir.rglob("metrics.json")):
        rel = path.parent.relative_to(run_dir)
        if any(p.startswith((".", "_")) for p in rel.parts):
            continue
        seen.add(path.parent)
        try:
            rec = json.loads(path.read_text())
            if not isinstance(rec, dict):
                raise ValueError("not a JSON object")
        except (OSError, ValueError) as e:
            rec = {"status": "failed", "reason": f"metrics.json unreadable: {e}"}
        rows.append(_row_from_record(rec, rel))
    for path in sorted(run_dir.rglob("config.yaml")):
        rel = path.parent.relative_to(run_dir)
        if path.parent in seen or not _is_cell_dir(rel):
            continue
        rows.append(_row_from_record({"status": "failed", "reason": "incomplete cell: config.yaml but no metrics.json"}, rel))
    df = pd.DataFrame(rows)
    for c in _BASE_COLUMNS + ("cell_dir",):
        if c not in df.columns:
            df[c] = None
    if df.empty:
        return df
    df["variation"] = pd.to_numeric(df["variation"], errors="coerce").astype("Int64")
    df["status"] = df["status"].fillna("failed")
    keys = ["scene", "variation", "object", "method", "cell_dir"]
    df = df.sort_values(keys, na_position="last", kind="mergesort").reset_index(drop=True)
    fixed = [c for c in _BASE_COLUMNS if c in df.columns]
    metric_cols = [m for m in METRICS if m in df.columns]
    other = sorted(c for c in df.columns if c not in fixed and c not in metric_cols and c != "cell_dir")
    return df[fixed + metric_cols + other + ["cell_dir"]]


# --------------------------------------------------------------------------------------------
# Provenance and notes
# --------------------------------------------------------------------------------------------


def _str_values(s: pd.Series) -> Counter:
    return Counter("unknown" if (v is None or (isinstance(v, float) and math.isnan(v))) else str(v) for v in s)


def provenance_line(df: pd.DataFrame) -> str:
    """Which model and scene source produced these cells, and how many there are.

    E.g. ``"model: analytic (CPU stand-in for FLUX) · scenes: procedural · 12 cells (10 ok,
    1 failed, 1 skipped)"``. With several models or sources each is listed with its cell count.
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
    order = ["ok", "failed", "skipped"] + sorted(set(status) - {"ok", "failed", "skipped"})
    breakdown = ", ".join(f"{status[k]} {k}" for k in order if status.get(k) or k == "ok")
    n = len(df)
    parts.append(f"{n} cell{'s' if n != 1 else ''} ({breakdown})")
    return " · ".join(parts)


def _cell_name(r) -> str:
    var = r["variation"]
    var = "?" if var is None or pd.isna(var) else str(int(var))
    return f"{r['scene']}-{var} / {r['object']} / {r['method']}"


def cell_notes(df: pd.DataFrame, metrics: Iterable[str] = ()) -> list[str]:
    """Footnote lines: every cell not ``ok`` with its reason, then, for each of ``metrics``, the
    ``ok`` cells without a value, grouped by the reason recorded in ``missing.<metric>``, with the
    count per method. Reasons are put on one line (whitespace collapsed), never shortened."""
    notes = []
    for _, r in df[df["status"] != "ok"].iterrows():
        reason = r.get("reason")
        reason = "no reason recorded" if reason is None or (isinstance(reason, float) and math.isnan(reason)) else reason
        notes.append(f"{r['status']}: {_cell_name(r)} — {_one_line(reason)}")
    ok = df[df["status"] == "ok"]
    for m in metrics:
        if m not in ok.columns:
            if len(ok):
                notes.append(f"{_metric(m).label}: not recorded in any of the {len(ok)} ok cells")
            continue
        miss = ok[ok[m].isna()]
        if miss.empty:
            continue
        col = f"missing.{m}"
        reasons = miss[col] if col in miss.columns else pd.Series([None] * len(miss), index=miss.index)
        groups: dict[str, Counter] = {}
        for (_, r), why in zip(miss.iterrows(), reasons):
            why = "no reason recorded" if why is None or (isinstance(why, float) and math.isnan(why)) else _one_line(why)
            groups.setdefault(why, Counter())[str(r["method"])] += 1
        for why in sorted(groups):
            per = groups[why]
            k = sum(per.values())
            by = ", ".join(f"{meth} ×{per[meth]}" for meth in sorted(per))
            notes.append(f"{_metric(m).label}: no value in {k} of {len(ok)} ok cells ({by}) — {why}")
    return notes


def _one_line(text) -> str:
    """A reason on one line (multi-line exception messages would break list items and tables)."""
    return " ".join(str(text).split())


def _metric(name: str) -> Metric:
    return METRICS.get(name) or Metric(name, name, True, "{:.3f}")


# --------------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------------


def _method_order(methods: Iterable[str], order: Sequence[str] | None) -> list[str]:
    methods = sorted(set(methods))
    if not order:
        return methods
    first = [m for m in order if m in methods]
    return first + [m for m in methods if m not in first]


def _method_labels(df: pd.DataFrame) -> dict[str, str]:
    """Method name -> display label (its most common ``method_label``; the name if none); labels
    shared by several methods get the method name appended."""
    labels = {}
    for meth, g in df.groupby("method", sort=True):
        vals = [v for v in g["method_label"] if isinstance(v, str) and v]
        labels[meth] = Counter(vals).most_common(1)[0][0] if vals else str(meth)
    dup = Counter(labels.values())
    return {k: (f"{v} ({k})" if dup[v] > 1 else v) for k, v in labels.items()}


def _means(df: pd.DataFrame, methods: Sequence[str], metrics: Sequence[str]) -> pd.DataFrame:
    ok = df[df["status"] == "ok"]
    out = pd.DataFrame(index=list(methods), columns=list(metrics) + ["n"], dtype=float)
    for meth in methods:
        g = ok[ok["method"] == meth]
        for m in metrics:
            out.loc[meth, m] = float(g[m].mean()) if m in g.columns and g[m].notna().any() else float("nan")
        out.loc[meth, "n"] = len(g)
    out["n"] = out["n"].astype(int)
    return out


def _check(df: pd.DataFrame) -> None:
    missing = [c for c in ("method", "status") if c not in df.columns]
    if missing:
        raise ValueError(f"not a cell table from collect(): no column(s) {missing}")


def method_table(
    df: pd.DataFrame, metrics: Sequence[str] = TABLE1_METRICS, order: Sequence[str] | None = None
) -> pd.DataFrame:
    """Mean of each metric per method over the cells with status ``ok``, and ``n``, the number of
    those cells (0 for a method whose cells all failed; its values are NaN).

    Rows are labelled by ``method_label`` and ordered by method name, or by ``order`` (method names
    first in that order, the others after them, sorted). A metric with no value in some ``ok``
    cells is averaged over the cells that have one; the notes say how many lack it and why.
    """
    _check(df)
    methods = _method_order(df["method"].dropna().astype(str), order)
    table = _means(df, methods, metrics)
    labels = _method_labels(df)
    table.index = [labels[m] for m in methods]
    table.index.name = "Method"
    table.attrs.update(
        provenance=provenance_line(df),
        notes=cell_notes(df, metrics),
        caption="Means over cells with status ok; n = cells averaged.",
        highlight="columns",
        methods=list(methods),
    )
    return table


def scene_table(
    df: pd.DataFrame, metric: str = "psnr", order: Sequence[str] | None = None
) -> pd.DataFrame:
    """Mean of ``metric`` per scene (rows, sorted) and method (columns, labelled by
    ``method_label``, ordered as in :func:`method_table`) over the cells with status ``ok``;
    best and second best are marked per scene."""
    _check(df)
    methods = _method_order(df["method"].dropna().astype(str), order)
    labels = _method_labels(df)
    scenes = sorted(df["scene"].dropna().astype(str).unique())
    ok = df[df["status"] == "ok"]
    table = pd.DataFrame(index=scenes, columns=[labels[m] for m in methods], dtype=float)
    for s in scenes:
        for meth in methods:
            g = ok[(ok["scene"] == s) & (ok["method"] == meth)]
            v = g[metric].mean() if metric in g.columns and g[metric].notna().any() else float("nan")
            table.loc[s, labels[meth]] = float(v)
    table.index.name = "Scene"
    spec = _metric(metric)
    table.attrs.update(
        provenance=provenance_line(df),
        notes=cell_notes(df, [metric]),
        caption=f"{spec.label} {spec.arrow} per scene: means over cells with status ok.",
        highlight="rows",
        metric=metric,
        methods=list(methods),
    )
    return table


def ablation_table(df: pd.DataFrame, metrics: Sequence[str] = ABLATION_METRICS) -> pd.DataFrame:
    """The ablation rows present in ``df``, in the paper's order (:data:`ABLATION_ROWS`: Full,
    w/o reflection, w/o panorama, w/o DPA, w/o LPW, w/o time travel), with the means over cells
    with status ``ok`` and ``n``. Cells of other methods are ignored, also for provenance."""
    _check(df)
    names = [m for m, _ in ABLATION_ROWS if (df["method"] == m).any()]
    sub = df[df["method"].isin(names)]
    table = _means(sub, names, metrics)
    label = dict(ABLATION_ROWS)
    table.index = [label[m] for m in names]
    table.index.name = "Variant"
    table.attrs.update(
        provenance=provenance_line(sub),
        notes=cell_notes(sub, metrics),
        caption="Ablation: means over cells with status ok; n = cells averaged.",
        highlight="columns",
        methods=list(names),
    )
    return table


# --------------------------------------------------------------------------------------------
# Writers
# --------------------------------------------------------------------------------------------


def _column_metric(table: pd.DataFrame, col) -> Metric | None:
    """The metric of a value column (None for counts and unknown non-metric columns)."""
    if col == "n":
        return None
    if table.attrs.get("metric"):
        return _metric(table.attrs["metric"])
    return METRICS.get(col)


def _ranks(table: pd.DataFrame) -> dict[tuple[int, int], int]:
    """{(row, col): 1 for best, 2 for second best}, ranked per column or per row as the table's
    ``highlight`` says, on the values as displayed (ties share a rank)."""
    ranks: dict[tuple[int, int], int] = {}
    by_rows = table.attrs.get("highlight") == "rows"
    cols = list(table.columns)
    groups = (
        [[(i, j) for j in range(len(cols))] for i in range(len(table))]
        if by_rows
        else [[(i, j) for i in range(len(table))] for j in range(len(cols))]
    )
    for cells in groups:
        vals = []
        for i, j in cells:
            spec = _column_metric(table, cols[j])
            if spec is None:
                continue
            v = table.iat[i, j]
            if v is None or pd.isna(v):
                continue
            shown = float(spec.fmt(float(v)))
            vals.append(((i, j), shown if spec.higher_is_better else -shown))
        if len(vals) < 2:
            continue
        distinct = sorted({v for _, v in vals}, reverse=True)
        for ij, v in vals:
            if v == distinct[0]:
                ranks[ij] = 1
            elif len(distinct) > 1 and v == distinct[1]:
                ranks[ij] = 2
    return ranks


def _cell_text(table: pd.DataFrame, i: int, j: int) -> str:
    col = table.columns[j]
    v = table.iat[i, j]
    if col == "n":
        return MISSING if pd.isna(v) else str(int(v))
    spec = _column_metric(table, col) or _metric(str(col))
    return spec.fmt(None if pd.isna(v) else float(v))


def _header(table: pd.DataFrame, col) -> str:
    if col == "n":
        return "n"
    spec = _column_metric(table, col)
    if spec is not None and not table.attrs.get("metric"):
        return f"{spec.label} {spec.arrow}"
    return str(col)


def _resolve(table, provenance, notes):
    provenance = table.attrs.get("provenance", "") if provenance is None else provenance
    notes = list(table.attrs.get("notes", [])) if notes is None else list(notes)
    return provenance, notes


def to_markdown(
    table: pd.DataFrame, title: str, provenance: str | None = None, notes: Sequence[str] | None = None
) -> str:
    """The table as Markdown: a ``##`` heading, the provenance line, a pipe table (best value
    **bold**, second best _italic_, missing "—"), and a "Notes" section listing the failed and
    skipped cells with their reasons and the metrics missing in averaged cells.

    ``provenance`` and ``notes`` default to the ones the table builder stored in ``table.attrs``.
    """
    provenance, notes = _resolve(table, provenance, notes)
    ranks = _ranks(table)
    cols = list(table.columns)
    head = [str(table.index.name or "")] + [_header(table, c) for c in cols]
    lines = [f"## {title}", "", f"_{provenance}_" if provenance else "", ""]
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|" + "|".join([":---"] + ["---:"] * len(cols)) + "|")
    for i, idx in enumerate(table.index):
        cells = [str(idx)]
        for j in range(len(cols)):
            t = _cell_text(table, i, j)
            r = ranks.get((i, j))
            cells.append(f"**{t}**" if r == 1 else f"_{t}_" if r == 2 else t)
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    caption = table.attrs.get("caption")
    where = "scene" if table.attrs.get("highlight") == "rows" else "column"
    lines.append(
        (caption + " " if caption else "") + f"**Bold**: best per {where}; _italic_: second best; {MISSING}: no value."
    )
    lines += ["", "### Notes", ""]
    lines += [f"- {n}" for n in notes] if notes else ["- All cells ok; every metric shown has a value in every cell."]
    return "\n".join(lines) + "\n"


_LATEX_ESCAPES = {
    "\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
    "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
    "↑": r"$\uparrow$", "↓": r"$\downarrow$", "·": r"$\cdot$", "×": r"$\times$",
}


def _tex(s: str) -> str:
    return "".join(_LATEX_ESCAPES.get(ch, ch) for ch in str(s))


def to_latex(
    table: pd.DataFrame,
    title: str,
    provenance: str | None = None,
    notes: Sequence[str] | None = None,
    label: str | None = None,
) -> str:
    """The table as a LaTeX ``table`` (booktabs): the caption is ``title`` and the provenance line,
    the best value per column (per scene for scene tables) is in ``\\textbf{}``, the second best in
    ``\\underline{}`` (ties share the mark), missing values are "—" (UTF-8, the LaTeX default
    input encoding), and the notes (failed and skipped cells, missing metrics) follow the tabular
    in ``\\footnotesize``."""
    provenance, notes = _resolve(table, provenance, notes)
    ranks = _ranks(table)
    cols = list(table.columns)
    caption = _tex(title.rstrip("."))
    if provenance:
        caption += ". " + _tex(provenance)
    lines = [
        r"\begin{table}[t]",
        r"\centering",
        r"\caption{" + caption + ".}",
    ]
    if label:
        lines.append(r"\label{" + label + "}")
    lines += [
        r"\begin{tabular}{l" + "r" * len(cols) + "}",
        r"\toprule",
        " & ".join([_tex(table.index.name or "")] + [_tex(_header(table, c)) if c != "n" else "$n$" for c in cols])
        + r" \\",
        r"\midrule",
    ]
    for i, idx in enumerate(table.index):
        cells = [_tex(idx)]
        for j in range(len(cols)):
            t = _cell_text(table, i, j)
            r = ranks.get((i, j))
            cells.append(r"\textbf{" + t + "}" if r == 1 else r"\underline{" + t + "}" if r == 2 else t)
        lines.append(" & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    if notes:
        lines.append(r"\par\smallskip{\footnotesize")
        lines += [_tex(n) + r"\\" for n in notes]
        lines.append("}")
    lines.append(r"\end{table}")
    return "\n".join(lines) + "\n"


def to_csv(table: pd.DataFrame, path: str | os.PathLike | None = None) -> str:
    """The table's numbers as CSV (index first, NaN as an empty field, full precision); written to
    ``path`` if given. ``pandas.read_csv(path, index_col=0)`` reads it back."""
    text = table.to_csv(index=True, float_format=None, lineterminator="\n")
    if path is not None:
        Path(path).write_text(text)
    return text


# --------------------------------------------------------------------------------------------
# Qualitative figure
# --------------------------------------------------------------------------------------------


def _load_rgb(path: Path) -> np.ndarray | None:
    from PIL import Image

    if not path.is_file():
        return None
    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
    except OSError:
        return None


def _mask_box(path: Path) -> tuple[float, float, float, float] | None:
    """Bounding box of the white pixels of a mask as fractions (x0, y0, x1, y1) of its size."""
    img = _load_rgb(path)
    if img is None:
        return None
    m = img.mean(-1) > 0.5
    if not m.any():
        return None
    ys, xs = np.nonzero(m)
    H, W = m.shape
    return xs.min() / W, ys.min() / H, (xs.max() + 1) / W, (ys.max() + 1) / H


def _zoom_window(box, W: int, H: int, pad: float = 0.15) -> tuple[int, int, int, int]:
    """A square pixel window around a fractional box, padded and kept inside the image."""
    x0, y0, x1, y1 = box[0] * W, box[1] * H, box[2] * W, box[3] * H
    side = max(x1 - x0, y1 - y0) * (1 + 2 * pad)
    side = int(min(max(side, 8), W, H))
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    left = int(round(min(max(cx - side / 2, 0), W - side)))
    top = int(round(min(max(cy - side / 2, 0), H - side)))
    return left, top, left + side, top + side


def qualitative_figure(
    run_dir: str | os.PathLike,
    out_png: str | os.PathLike,
    cells: Sequence[tuple[str, int, str]] | None = None,
    methods: Sequence[str] | None = None,
    inset: bool = True,
    *,
    max_rows: int = 4,
    tile_width_in: float = 2.4,
    dpi: int = 100,
) -> Path:
    """A grid PNG: one row per cell ``(scene, variation, object)``, columns reference |
    Snellcaster | the other methods, each tile with an inset zoom on the object.

    ``cells`` defaults to the first cell (by variation, then object) of each scene, then further
    cells, up to ``max_rows``. ``methods`` defaults to ``snellcaster`` followed by the other methods,
    sorted. The reference is the row's ``reference.png`` (from the Snellcaster cell when it has one).
    The inset crops a square around the bounding box of the row's ``mask.png`` (the same window
    in every tile of the row, marked by a yellow frame) and sits in the tile's corner farthest
    from the object; a tile without an image says why. The
    figure is ``dpi * (0.3 + tile_width_in * n_columns)`` pixels wide; tiles keep the aspect ratio
    of the first image found.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    run_dir = Path(run_dir)
    df = collect(run_dir)
    if df.empty:
        raise FileNotFoundError(f"no cells (metrics.json) below {run_dir}")
    df = df.dropna(subset=["scene", "variation", "object", "method"])
    keys = sorted({(str(r.scene), int(r.variation), str(r.object)) for r in df.itertuples()})
    if cells is None:
        chosen, scenes = [], set()
        for k in keys:
            if k[0] not in scenes:
                chosen.append(k)
                scenes.add(k[0])
        chosen += [k for k in keys if k not in chosen]
        cells = chosen[:max_rows]
    cells = [(str(s), int(v), str(o)) for s, v, o in cells]
    all_methods = sorted(df["method"].astype(str).unique())
    if methods is None:
        methods = (["snellcaster"] if "snellcaster" in all_methods else []) + [
            m for m in all_methods if m != "snellcaster"
        ]
    methods = list(methods)
    labels = _method_labels(df)

    def cell_row(key, method):
        g = df[(df["scene"] == key[0]) & (df["variation"] == key[1]) & (df["object"] == key[2]) & (df["method"] == method)]
        return None if g.empty else g.iloc[0]

    # one (image, reason) per tile; the reference and the mask per row
    grid, boxes = [], []
    for key in cells:
        rows = {m: cell_row(key, m) for m in methods}
        same_row = df[(df["scene"] == key[0]) & (df["variation"] == key[1]) & (df["object"] == key[2])]
        dirs = [run_dir / r["cell_dir"] for r in rows.values() if r is not None] + [
            run_dir / d for d in same_row["cell_dir"]
        ]
        ref = next((img for d in dirs if (img := _load_rgb(d / "reference.png")) is not None), None)
        box = next((b for d in dirs if (b := _mask_box(d / "mask.png")) is not None), None)
        tiles = [(ref, "no reference.png")]
        for m in methods:
            r = rows[m]
            if r is None:
                tiles.append((None, "not run"))
                continue
            img = _load_rgb(run_dir / r["cell_dir"] / "image.png")
            why = r["status"] if r["status"] != "ok" else "no image.png"
            if r["status"] != "ok" and isinstance(r.get("reason"), str):
                why += ": " + r["reason"]
            tiles.append((img, why))
        grid.append(tiles)
        boxes.append(box)

    first = next((img for tiles in grid for img, _ in tiles if img is not None), None)
    aspect = first.shape[0] / first.shape[1] if first is not None else 9 / 16
    ncols, nrows = 1 + len(methods), max(len(cells), 1)
    left_in, top_in = 0.3, 0.3
    tile_h_in = tile_width_in * aspect
    fig_w, fig_h = left_in + ncols * tile_width_in, top_in + nrows * tile_h_in
    fig = Figure(figsize=(fig_w, fig_h), dpi=dpi, facecolor="white")
    FigureCanvasAgg(fig)
    titles = ["Reference"] + [labels.get(m, m) for m in methods]
    gap = 0.03  # fraction of a tile left blank on each side
    for i, tiles in enumerate(grid):
        for j, (img, why) in enumerate(tiles):
            x = (left_in + j * tile_width_in) / fig_w
            y = 1 - (top_in + (i + 1) * tile_h_in) / fig_h
            w, h = tile_width_in / fig_w, tile_h_in / fig_h
            ax = fig.add_axes((x + gap * w, y + gap * h, w * (1 - 2 * gap), h * (1 - 2 * gap)))
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(titles[j], fontsize=9, pad=3)
            if img is None:
                ax.set_facecolor((0.85, 0.85, 0.85))
                text = why if len(why) <= 60 else why[:57] + "..."
                ax.text(0.5, 0.5, text, ha="center", va="center", fontsize=6, wrap=True, transform=ax.transAxes)
                continue
            ax.imshow(img, interpolation="antialiased")
            ax.set_aspect("auto")
            box = boxes[i]
            if inset and box is not None:
                H, W = img.shape[:2]
                l, t, r, b = _zoom_window(box, W, H)
                ax.add_patch(Rectangle((l - 0.5, t - 0.5), r - l, b - t, fill=False, ec="yellow", lw=0.8))
                side_in = 0.42 * min(tile_width_in, tile_h_in)
                iw, ih = side_in / tile_width_in, side_in / tile_h_in
                # the corner farthest from the object, so the inset hides as little of it as possible
                cx, cy = (l + r) / 2 / W, (t + b) / 2 / H
                ix = 1 - iw - 0.01 if cx < 0.5 else 0.01
                iy = 0.01 if cy < 0.5 else 1 - ih - 0.01
                sub = ax.inset_axes((ix, iy, iw, ih))
                sub.imshow(img[t:b, l:r], interpolation="nearest")
                sub.set_aspect("auto")
                sub.set_xticks([])
                sub.set_yticks([])
                for sp in sub.spines.values():
                    sp.set_edgecolor("yellow")
                    sp.set_linewidth(1.0)
        key = cells[i]
        fig.text(
            0.5 * left_in / fig_w, 1 - (top_in + (i + 0.5) * tile_h_in) / fig_h,
            f"{key[0]}-{key[1]} / {key[2]}", rotation=90, ha="center", va="center", fontsize=7,
        )
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=dpi, facecolor="white", metadata={"Software": None})
    return out_png


# --------------------------------------------------------------------------------------------
# Everything at once
# --------------------------------------------------------------------------------------------


SAVING_METHODS = ("full_frame", "adaptive")
"""Methods compared with ``snellcaster`` in :func:`savings_table` (same images, or modelling less)."""


def _stage_time(df: pd.DataFrame) -> pd.Series:
    """Per-cell time of what a method controls: its warps plus its sampling (seconds)."""
    cols = [c for c in ("timings_s.warps", "timings_s.sampling") if c in df.columns]
    return df[cols].sum(axis=1, min_count=1) if cols else pd.Series(np.nan, index=df.index)


def savings_table(df: pd.DataFrame, reference: str = "snellcaster",
                  methods: Sequence[str] = SAVING_METHODS) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Time saved against fidelity lost, per method, over the cells it shares with ``reference``.

    Returns ``(summary, per_cell)``. ``per_cell`` pairs every ok cell of a method with the
    ``reference`` cell of the same scene, variation and object: time (warps + sampling) of both,
    PSNR of both and the difference, and the decisions the method took. ``summary`` has one row
    per method: cells, mean times, time saved (share of the reference's), mean and largest
    |ΔPSNR|, cells without the panorama branch, cells without any reflection, mean share of object
    pixels that kept a reflection, mean share of background treated as at infinity.
    """
    ok = df[df["status"] == "ok"].copy()
    ok["_time"] = _stage_time(ok)
    keys = ["scene", "variation", "object"]
    ref = ok[ok["method"] == reference].set_index(keys)
    rows, summary = [], []
    labels = _method_labels(df)
    for m in methods:
        sub = ok[ok["method"] == m]
        if sub.empty or ref.empty:
            continue
        cells = []
        for _, r in sub.iterrows():
            k = tuple(r[c] for c in keys)
            if k not in ref.index:
                continue
            b = ref.loc[k]
            if isinstance(b, pd.DataFrame):
                b = b.iloc[0]
            cell = {
                "method": m, "scene": r["scene"], "variation": r["variation"], "object": r["object"],
                "time_s": r["_time"], "reference_time_s": b["_time"],
                "psnr": r.get("psnr", np.nan), "reference_psnr": b.get("psnr", np.nan),
                "panorama_used": r.get("decisions.panorama.used", np.nan),
                "panorama_observed_share": r.get("decisions.panorama.observed_share", np.nan),
                "reflection_kept": r.get("decisions.reflection.kept", np.nan),
                "reflection_share_kept": r.get("decisions.reflection.share_kept", np.nan),
                "far_fraction": r.get("warps.far_background.far_fraction", np.nan),
            }
            cell["delta_psnr"] = cell["psnr"] - cell["reference_psnr"]
            cells.append(cell)
        if not cells:
            continue
        c = pd.DataFrame(cells)
        rows.append(c)
        t, tr = c["time_s"].mean(), c["reference_time_s"].mean()
        summary.append({
            "method": labels.get(m, m), "cells": len(c), "time (s)": t, f"{labels.get(reference, reference)} (s)": tr,
            "time saved": 1 - t / tr if tr > 0 else np.nan,
            "mean ΔPSNR (dB)": c["delta_psnr"].mean(), "max |ΔPSNR| (dB)": c["delta_psnr"].abs().max(),
            "panorama skipped": int((c["panorama_used"] == False).sum()),  # noqa: E712 (NaN is neither)
            "reflection off": int((c["reflection_kept"] == False).sum()),  # noqa: E712
            "reflection kept (share of px)": c["reflection_share_kept"].mean(),
            "far background (share of px)": c["far_fraction"].mean(),
        })
    per_cell = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame()
    return pd.DataFrame(summary), per_cell


def _plain_markdown(table: pd.DataFrame, title: str, note: str = "") -> str:
    def fmt(v):
        if isinstance(v, (float, np.floating)):
            return MISSING if not np.isfinite(v) else f"{v:.3f}"
        return str(v)

    cols = list(table.columns)
    lines = [f"## {title}", ""] + ([note, ""] if note else [])
    lines += ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in table.itertuples(index=False)]
    return "\n".join(lines) + "\n"


def build_reports(run_dir: str | os.PathLike, out_dir: str | os.PathLike, experiment_name: str) -> list[Path]:
    """Write every table and the figure of one experiment from its run directory alone.

    Writes ``method_table``, ``scene_table`` (PSNR) and, if the runs contain an ablation variant
    (a method of :data:`ABLATION_ROWS` other than ``snellcaster``), ``ablation_table``, each as
    ``.md``, ``.tex`` and ``.csv``; ``qualitative.png``; and ``README.md`` linking them with the
    provenance line and the notes. The method table has the columns of Table 1, followed by MAE and
    PSNR (true) where any cell has them. Returns the written paths.
    """
    run_dir, out_dir = Path(run_dir), Path(out_dir)
    df = collect(run_dir)
    if df.empty:
        raise FileNotFoundError(f"no cells (metrics.json) below {run_dir}")
    out_dir.mkdir(parents=True, exist_ok=True)
    extra = [m for m in ("mae", "psnr_true") if m in df.columns and df.loc[df["status"] == "ok", m].notna().any()]
    tables = [
        ("method_table", f"Methods ({experiment_name})", method_table(df, TABLE1_METRICS + tuple(extra))),
        ("scene_table", f"PSNR per scene ({experiment_name})", scene_table(df, "psnr")),
    ]
    if df["method"].isin([m for m, _ in ABLATION_ROWS[1:]]).any():
        tables.append(("ablation_table", f"Ablation ({experiment_name})", ablation_table(df)))
    written: list[Path] = []
    for stem, title, table in tables:
        md, tex, csv = (out_dir / f"{stem}.{ext}" for ext in ("md", "tex", "csv"))
        md.write_text(to_markdown(table, title))
        tex.write_text(to_latex(table, title, label=f"tab:{_slug(experiment_name)}_{stem}"))
        to_csv(table, csv)
        written += [md, tex, csv]
    savings = None
    if df["method"].isin(SAVING_METHODS).any() and (df["method"] == "snellcaster").any():
        summary, per_cell = savings_table(df)
        if not summary.empty:
            note = ("Time = warps + sampling per cell, against Snellcaster on the same scene and object; "
                    "ΔPSNR = method − Snellcaster (masked, against the reference).")
            (out_dir / "savings.md").write_text(_plain_markdown(summary, f"Time saved against fidelity lost ({experiment_name})", note))
            summary.to_csv(out_dir / "savings.csv", index=False)
            per_cell.to_csv(out_dir / "savings_per_cell.csv", index=False)
            written += [out_dir / "savings.md", out_dir / "savings.csv", out_dir / "savings_per_cell.csv"]
            savings = summary
    fig = qualitative_figure(run_dir, out_dir / "qualitative.png")
    written.append(fig)

    src = Path(os.path.relpath(run_dir.resolve(), out_dir.resolve())).as_posix()
    lines = [
        f"# Reports: {experiment_name}",
        "",
        f"Built from the cells under `{src}` alone; {provenance_line(df)}.",
        "",
    ]
    for stem, title, _ in tables:
        lines.append(f"- {title}: [{stem}.md]({stem}.md) · [{stem}.tex]({stem}.tex) · [{stem}.csv]({stem}.csv)")
    if savings is not None:
        lines.append("- Time saved against fidelity lost: [savings.md](savings.md) · [savings.csv](savings.csv) · "
                     "[savings_per_cell.csv](savings_per_cell.csv)")
    lines += ["- Qualitative comparison: [qualitative.png](qualitative.png)", ""]
    lines += [to_markdown(tables[0][2], tables[0][1])]
    lines += ["![qualitative comparison](qualitative.png)", ""]
    readme = out_dir / "README.md"
    readme.write_text("\n".join(lines))
    written.append(readme)
    return written


def _slug(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", s).strip("_").lower() or "exp"
