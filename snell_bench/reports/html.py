"""The HTML report: ``index.html`` beside the Markdown, LaTeX and CSV files of a report folder, one
static page that opens from disk (``file://``) with no server and no network.

A grid experiment's page (:func:`write_grid_page`) holds, in order:

1. the provenance line (model, scene source, recipe, metrics protocol, cell counts) and filters:
   a checkbox per scene, object and method;
2. every table of the report (the method table, the per-scene table, the ablation, IOR and
   time-travel tables, time saved against fidelity lost), built from the same DataFrames as the
   Markdown, LaTeX and CSV files, each with its provenance line, caption, notes and links to those
   files; a click on a column header sorts the rows;
3. one plot per swept axis (:func:`~.plots.axis_plots`: each metric against the IOR, against
   R_main);
4. the gallery (:func:`~.gallery.gallery`): a row per scene-variation / object with I⁻, the
   reference, the mask, and per method the image, its |error| map and its panorama, each tile
   captioned with its cell's metrics;
5. every failed or skipped cell and every metric without a value, with the recorded reasons;
6. the record files left out (not cell records, with what is wrong with each: "Files skipped");
   links to the other files of the folder.

A speed/accuracy sweep's page (:func:`write_tradeoff_page`) holds its per-setting table (sortable),
the fidelity against each setting, the time-fidelity Pareto plot, its notes and the files skipped.

Conventions:
    - Templates: Jinja2, shipped in ``snell_bench/reports/templates/`` (``grid.html.j2``,
      ``tradeoff.html.j2``, the shared ``base.html.j2`` and ``macros.html.j2``, ``report.css`` and
      ``report.js`` inlined into the page). Autoescaping is on: every string from a cell file
      (scene and object names, labels, reasons) is escaped; the only unescaped insertions are the
      inlined CSS and JavaScript and the figures' JSON, escaped by :func:`~.plots.plot_json`.
    - Self-contained: images are copies under ``images/`` (:mod:`.gallery`); Plotly's JavaScript is
      written once as ``plotly.min.js`` beside ``index.html`` when the page has a plot (one copy
      shared by every plot, cached by the browser, and the page itself stays small enough to read
      and diff), loaded with a relative ``<script src>``; every link is relative.
    - Tables: a value shows as in the Markdown table (the metric's format, "—" for a missing
      value, best **bold**, second best underlined, as ranked by
      :func:`~.tables.rank_marks`); its ``data-value`` attribute holds the full-precision number
      (``repr``, empty where missing) that sorting uses; a missing value's ``title`` says why (the
      reasons recorded by the cells the row stands for). Index levels show their label on every
      row (the rows can be reordered). Sorting: a click sorts ascending, a second descending, a
      third restores the table's order; numbers numerically, missing values last in both
      directions, ties in the table's order.
    - Filters: an element with ``data-scenes``, ``data-objects`` or ``data-methods`` (JSON lists)
      is hidden when none of its values of one of them is checked: gallery rows by scene and
      object, gallery columns by method, table rows by the cells they stand for.
    - Deterministic: the same cells give the same bytes (images included).
"""

from __future__ import annotations

import math
import os
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from snell_bench.utils.io import write_text

from .collect import cell_notes, recorded_metrics
from .gallery import Gallery, error_lut
from .plots import Plot
from .ranking import rank_marks
from .spec import MISSING, metric_spec
from .swept import DEFAULT_IOR
from .text import as_float, is_missing, reason
from .tradeoff import PRESET_AXIS
from .writers import _cell_text, _header, _index_header, rank_scope

__all__ = [
    "PAGE",
    "PLOTLY_JS",
    "Cell",
    "Row",
    "TableView",
    "environment",
    "table_view",
    "frame_view",
    "tradeoff_view",
    "write_grid_page",
    "write_tradeoff_page",
]

PAGE = "index.html"
"""The page's file name."""

PLOTLY_JS = "plotly.min.js"
"""Plotly's JavaScript, written beside the page when it has a plot."""


@dataclass(frozen=True)
class Cell:
    """One table cell: its ``text``, the ``value`` sorting uses (``repr`` of a number, "" if
    missing, the text for labels), its CSS ``cls`` and ``title`` (the tooltip)."""

    text: str
    value: str
    cls: str = ""
    title: str | None = None
    header: bool = False


@dataclass
class Row:
    """One table row and what it stands for (for the filters)."""

    cells: list[Cell]
    scenes: list[str] = field(default_factory=list)
    objects: list[str] = field(default_factory=list)
    methods: list[str] = field(default_factory=list)


@dataclass
class TableView:
    """A table as the page shows it."""

    id: str
    title: str
    header: list[tuple[str, str]]  # (text, "number" | "text")
    rows: list[Row]
    provenance: str = ""
    caption: str = ""
    legend: str = ""
    notes: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)


def environment():
    """The Jinja2 environment of the page's templates (autoescaping on, undefined names an error)."""
    from jinja2 import Environment, PackageLoader, StrictUndefined

    env = Environment(
        loader=PackageLoader("snell_bench.reports", "templates"),
        autoescape=True,
        undefined=StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )
    env.filters["number"] = _number
    return env


# --------------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------------


def _number(v) -> str:
    """A number as ``data-value``: ``repr`` of the float, "" where missing or not finite."""
    x = as_float(v)
    return repr(x) if math.isfinite(x) else ""


def _label_type(values: Sequence) -> str:
    nums = [v for v in values if str(v) != DEFAULT_IOR]
    try:
        [float(v) for v in nums]
    except (TypeError, ValueError):
        return "text"
    return "number" if nums else "text"


def _reasons(cells: pd.DataFrame, metric: str) -> str:
    """Why ``metric`` has no value in a row: the reasons of its cells (``"<status>: <reason>"`` for
    a cell not ok, the recorded ``missing.<metric>`` for an ok one), one a line, with their counts."""
    reasons: Counter = Counter()
    for _, r in cells.iterrows():
        if r.get("status") != "ok":
            reasons[f"{r.get('status')}: {reason(r.get('reason'))}"] += 1
        elif metric not in cells.columns:
            reasons["not recorded"] += 1
        elif is_missing(r.get(metric)):
            reasons[reason(r.get(f"missing.{metric}"))] += 1
    if not reasons:
        return "no cell"
    return "\n".join(f"{why} (×{n})" if n > 1 else why for why, n in sorted(reasons.items()))


def table_view(
    table: pd.DataFrame, title: str, stem: str, df: pd.DataFrame | None = None, files: Sequence[str] = ()
) -> TableView:
    """A table of :mod:`.tables` as the page shows it.

    Args:
        table: the DataFrame the Markdown, LaTeX and CSV writers write.
        title: its heading.
        stem: its file stem (the page id is ``table-<stem>``).
        df: the cells (``collect``), for the reasons of missing values and the filters; without
            it, missing values have no tooltip and rows are never filtered.
        files: the other files of the table (``method_table.md``, ...), linked under it.

    Returns:
        The :class:`TableView`: a header cell per index level and column (as in the Markdown
        table), the cells of every row (module docstring), each row's scenes, objects and methods.
    """
    ranks = rank_marks(table)
    names = _index_header(table)
    levels = [list(table.index.get_level_values(i)) for i in range(table.index.nlevels)]
    header = [(n, _label_type(levels[i])) for i, n in enumerate(names)]
    header += [(_header(table, c), "number") for c in table.columns]  # every value column holds numbers
    cells_of = table.attrs.get("cells") or [[] for _ in range(len(table))]
    methods_of_cols = table.attrs.get("methods") if table.attrs.get("metric") else None
    by_dir = df.set_index("cell_dir", drop=False) if df is not None and "cell_dir" in df.columns else None
    rows = []
    for i, key in enumerate(table.index):
        key = list(key) if isinstance(key, tuple) else [key]
        mine = by_dir.loc[[d for d in cells_of[i] if d in by_dir.index]] if by_dir is not None else None
        cells = [Cell(str(k), str(k), "label", header=True) for k in key]
        for j, col in enumerate(table.columns):
            v = table.iat[i, j]
            text = _cell_text(table, i, j)
            cls = ["num"] + [{1: "best", 2: "second"}[ranks[(i, j)]]] if (i, j) in ranks else ["num"]
            tip = None
            if text == MISSING:
                cls.append("missing")
                if mine is not None and col != "n":
                    if methods_of_cols:  # a scene table: a metric for all, a method per column
                        tip = _reasons(mine[mine["method"] == methods_of_cols[j]], table.attrs["metric"])
                    else:
                        tip = _reasons(mine, str(col))
            cells.append(Cell(text, _number(v), " ".join(cls), tip))
        row = Row(cells)
        if mine is not None and len(mine):
            row.scenes = sorted({str(s) for s in mine["scene"].dropna()})
            row.objects = sorted({str(s) for s in mine["object"].dropna()})
            row.methods = sorted({str(s) for s in mine["method"].dropna()})
        rows.append(row)
    return TableView(
        f"table-{stem}",
        title,
        header,
        rows,
        table.attrs.get("provenance", ""),
        table.attrs.get("caption", ""),
        f"Bold: best per {rank_scope(table)}; underlined: second best; {MISSING}: no value (its tooltip says why).",
        list(table.attrs.get("notes", [])),
        list(files),
    )


def frame_view(
    frame: pd.DataFrame,
    title: str,
    stem: str,
    *,
    note: str = "",
    files: Sequence[str] = (),
    methods: dict | None = None,
) -> TableView:
    """Any DataFrame as a sortable table without ranking (its index is not shown).

    Args:
        frame: the rows.
        title: its heading.
        stem: its file stem (the page id is ``table-<stem>``).
        note: the caption.
        files: the other files of the table, linked under it.
        methods: method label -> method name, to filter rows whose ``method`` column holds a label.

    Returns:
        The :class:`TableView`: floats with 3 decimals as :func:`~.writers.plain_markdown` writes
        them ("—" if not finite), integers and text as they are.
    """
    header = [(str(c), "number" if pd.api.types.is_numeric_dtype(frame[c]) else "text") for c in frame.columns]
    rows = []
    for values in frame.itertuples(index=False):
        cells = []
        for v in values:
            if isinstance(v, (float, np.floating)):
                ok = np.isfinite(v)
                cells.append(Cell(f"{v:.3f}" if ok else MISSING, _number(v), "num" + ("" if ok else " missing")))
            elif isinstance(v, (int, np.integer)) and not isinstance(v, bool):
                cells.append(Cell(str(v), repr(float(v)), "num"))
            else:
                cells.append(Cell(str(v), str(v), "label"))
        row = Row(cells)
        if methods and "method" in frame.columns:
            label = str(values[list(frame.columns).index("method")])
            row.methods = [methods.get(label, label)]
        rows.append(row)
    return TableView(f"table-{stem}", title, header, rows, "", note, "", [], list(files))


_TRADEOFF_COLUMNS = (
    ("warps", "timings_s.warps", "{:.2f}"),
    ("reference", "timings_s.reference", "{:.2f}"),
    ("true render", "timings_s.true_render", "{:.2f}"),
    ("generator", "timings_s.generator", "{:.2f}"),
    ("sampling", "timings_s.sampling", "{:.2f}"),
    ("metrics", "timings_s.metrics", "{:.2f}"),
    ("total", "timings_s.total", "{:.2f}"),
    *(
        (metric_spec(m).label, m, metric_spec(m).format)
        for m in ("psnr", "psnr_converged", "psnr_true", "lpips", "mae")
    ),
    ("ref. self-noise", "reference_self_noise_db", "{:.2f}"),
)


def tradeoff_view(table: pd.DataFrame, files: Sequence[str] = ()) -> TableView:
    """A sweep's per-setting table as the page shows it.

    Args:
        table: from :func:`~.tradeoff.tradeoff_table`.
        files: the other files of the table, linked under it.

    Returns:
        The :class:`TableView`: setting, axis, the stage times (s), PSNR, PSNR (conv.), PSNR (true),
        LPIPS (its tooltip the recorded reasons where it has no value), MAE, the reference's
        self-noise, ``n`` (ok scenes of all) and ★ on the Pareto front; presets in bold.
    """
    header = [("setting", "text"), ("axis", "text")] + [(h, "number") for h, _, _ in _TRADEOFF_COLUMNS]
    header += [("n", "number"), ("pareto", "text")]
    rows = []
    for setting, r in table.iterrows():
        preset = r["axis"] == PRESET_AXIS
        axis = r["axis"] if isinstance(r["axis"], str) else "(baseline)"
        cells = [Cell(str(setting), str(setting), "label" + (" preset" if preset else ""), header=True)]
        cells.append(Cell(axis, axis, "label"))
        for _, col, fmt in _TRADEOFF_COLUMNS:
            v = r.get(col, float("nan"))
            missing = is_missing(v) or not math.isfinite(float(v))
            tip = None
            if missing and col == "lpips" and isinstance(r.get("lpips_missing"), str):
                tip = r["lpips_missing"]
            cls = "num" + (" missing" if missing else "") + (" preset" if preset else "")
            cells.append(Cell(MISSING if missing else fmt.format(float(v)), _number(v), cls, tip))
        cells.append(Cell(f"{int(r['n'])}/{int(r['n_scenes'])}", repr(float(r["n"])), "num"))
        cells.append(Cell("★" if r["pareto"] else "", "1" if r["pareto"] else "", "label"))
        rows.append(Row(cells))
    caption = "Means over the scenes where a setting succeeded; times in seconds; ★: on the Pareto front."
    return TableView("table-tradeoff", "Speed/accuracy trade-off", header, rows, "", caption, "", [], list(files))


# --------------------------------------------------------------------------------------------
# Pages
# --------------------------------------------------------------------------------------------


def _write_plotly(out_dir: Path, plots: Sequence[Plot], written: list[Path]) -> bool:
    """Write Plotly's JavaScript beside the page when it has a plot; remove an earlier copy when not."""
    # One file beside the page (what include_plotlyjs="directory" does), not inlined: ~4.8 MB once
    # per report folder instead of in the page's text, which stays small to load, read and diff.
    path = out_dir / PLOTLY_JS
    if not plots:
        path.unlink(missing_ok=True)
        return False
    import plotly.offline

    text = plotly.offline.get_plotlyjs()
    if not path.is_file() or path.read_text(encoding="utf-8") != text:
        write_text(path, text)
    written.append(path)
    return True


def _gradient() -> str:
    """The |error| colour map as CSS linear-gradient stops (every 15th entry and the last)."""
    lut = error_lut()
    last = len(lut) - 1
    ks = list(range(0, last, 15)) + [last]
    return ", ".join(f"rgb({lut[k][0]},{lut[k][1]},{lut[k][2]}) {100 * k / last:.1f}%" for k in ks)


def write_grid_page(
    out_dir: str | os.PathLike,
    *,
    name: str,
    source: str,
    provenance: str,
    tables: Sequence[TableView],
    plots: Sequence[Plot],
    gallery: Gallery,
    df: pd.DataFrame,
    files: Sequence[tuple[str, str]],
    skipped: Sequence[tuple[str, str]] = (),
) -> list[Path]:
    """Write a grid experiment's ``index.html`` (and ``plotly.min.js`` when it has a plot).

    Args:
        out_dir: the report folder.
        name: the experiment's name.
        source: the run directory relative to ``out_dir`` (shown, not linked).
        provenance: the provenance line of every cell.
        tables: the tables, in order.
        plots: the swept axes' plots.
        gallery: the gallery, its images already written.
        df: the cells (``collect``), for the filters and the notes.
        files: ``(title, relative path)`` of the other files of the report folder.
        skipped: the record files left out, ``(path relative to the run folder, problem)``.

    Returns:
        The paths written: ``index.html``, then ``plotly.min.js`` if written.
    """
    out_dir = Path(out_dir)
    written: list[Path] = []
    has_plotly = _write_plotly(out_dir, plots, written)
    shown = recorded_metrics(df)
    html = (
        environment()
        .get_template("grid.html.j2")
        .render(
            name=name,
            source=source,
            provenance=provenance,
            tables=tables,
            plots=plots,
            plotly_js=PLOTLY_JS if has_plotly else None,
            gallery=gallery,
            scenes=sorted({str(s) for s in df["scene"].dropna()}),
            objects=sorted({str(s) for s in df["object"].dropna()}),
            methods=gallery.methods,
            notes=cell_notes(df, shown),
            files=files,
            skipped=list(skipped),
            gradient=_gradient(),
        )
    )
    written.insert(0, write_text(out_dir / PAGE, html))
    return written


def write_tradeoff_page(
    out_dir: str | os.PathLike,
    *,
    title: str,
    summary: str,
    table: TableView,
    plots: Sequence[Plot],
    notes: Sequence[str],
    files: Sequence[tuple[str, str]],
    skipped: Sequence[tuple[str, str]] = (),
    page: str = "tradeoff.html",
) -> list[Path]:
    """Write a speed/accuracy sweep's page and ``plotly.min.js``.

    Args:
        out_dir: the report folder.
        title: the page's heading.
        summary: what the numbers are (a paragraph).
        table: the per-setting table.
        plots: the fidelity against each setting, the Pareto plot.
        notes: failed settings and missing metrics with their reasons.
        files: ``(title, relative path)`` of the other files of the report folder.
        skipped: the record files left out, ``(path relative to the run folder, problem)``.
        page: its file name in ``out_dir`` (the grid's page, ``index.html``, links it).

    Returns:
        The paths written: the page, then ``plotly.min.js``.
    """
    out_dir = Path(out_dir)
    written: list[Path] = []
    has_plotly = _write_plotly(out_dir, plots, written)
    html = (
        environment()
        .get_template("tradeoff.html.j2")
        .render(
            title=title,
            summary=summary,
            table=table,
            plots=plots,
            plotly_js=PLOTLY_JS if has_plotly else None,
            notes=notes,
            files=files,
            skipped=list(skipped),
        )
    )
    written.insert(0, write_text(out_dir / page, html))
    return written
