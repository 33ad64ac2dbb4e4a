"""The HTML report's interactive plots (Plotly): each metric against every swept axis of a grid
experiment, and a speed/accuracy sweep's fidelity against each setting beside its time-fidelity
Pareto plot.

Conventions:
    - A plot is a :class:`Plot`: a title, an id (ASCII, unique in the page) and the figure as JSON
      text, safe inside ``<script type="application/json">`` (``<``, ``>`` and ``&`` written as
      ``\\u003c`` ... escapes, valid JSON). The page draws it with ``Plotly.newPlot``.
    - Values are plain lists of floats (never Plotly's base64 typed arrays), NaN as null: the JSON
      is readable and the tests read the points back.
    - Every text Plotly draws (trace names, axis titles, hover text) is HTML-escaped first: Plotly
      reads a subset of HTML in its labels, and a label is data.
    - Swept axes are found in the data, not in the experiment's name (:func:`axis_plots`): an index
      level of a table whose labels are all numbers with two or more values (``R_main``), or a level
      named after a swept axis of the cells (``IOR``, :func:`~.tables.swept_axes`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .ranking import column_metric
from .spec import MEASURES, metric_spec
from .text import html_escape, slug
from .tradeoff import PRESET_AXIS, complete_front, fidelity_column

__all__ = [
    "Plot",
    "plot_json",
    "numeric_labels",
    "axis_plots",
    "tradeoff_axis_plot",
    "pareto_plot",
    "SWEPT_LEVELS",
]

SWEPT_LEVELS = ("IOR",)
"""Index levels that are swept axes whatever their labels (:func:`~.tables.swept_axes`)."""

_COLUMNS = 3  # subplots per row
_ROW_PX = 330


@dataclass(frozen=True)
class Plot:
    """One figure of the page: ``id`` (ASCII), ``title`` and ``spec``, the figure as JSON text."""

    id: str
    title: str
    spec: str


def plot_json(fig) -> str:
    """A Plotly figure as JSON text that can sit inside a ``<script>`` element.

    Args:
        fig: a ``plotly.graph_objects.Figure``.

    Returns:
        ``{"data": [...], "layout": {...}}`` with ``<``, ``>`` and ``&`` escaped as ``\\u003c``,
        ``\\u003e`` and ``\\u0026`` (JSON strings only hold them, so the text stays valid JSON).
    """
    import plotly.io as pio

    text = pio.to_json(fig, validate=True, pretty=False, engine="json")
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def _floats(values) -> list:
    return [None if v is None or not math.isfinite(float(v)) else float(v) for v in values]


def numeric_labels(labels: Sequence) -> list[float] | None:
    """The labels as numbers, or None where any is not one (``"default"``, ``"water"``)."""
    out = []
    for v in labels:
        try:
            x = float(v)
        except (TypeError, ValueError):
            return None
        if not math.isfinite(x):
            return None
        out.append(x)
    return out


def _grid(n: int) -> tuple[int, int]:
    cols = min(n, _COLUMNS)
    return math.ceil(n / cols), cols


def _subplots(titles: Sequence[str]):
    from plotly.subplots import make_subplots

    rows, cols = _grid(len(titles))
    fig = make_subplots(
        rows=rows,
        cols=cols,
        subplot_titles=[html_escape(t) for t in titles],
        horizontal_spacing=0.08,
        vertical_spacing=min(0.25, 0.5 / rows),
    )
    fig.update_layout(
        template="plotly_white",
        height=_ROW_PX * rows + 60,
        margin={"l": 60, "r": 20, "t": 40, "b": 50},
        legend={"orientation": "h", "y": -0.15 if rows == 1 else -0.05},
        hovermode="closest",
    )
    return fig, cols


def _value_columns(table: pd.DataFrame) -> list:
    """Columns with at least one value that are metrics or costs (never ``n``)."""
    cols = []
    for c in table.columns:
        if c == "n" or (column_metric(table, c) is None and c not in MEASURES):
            continue
        if pd.to_numeric(table[c], errors="coerce").notna().any():
            cols.append(c)
    return cols


def _label(table: pd.DataFrame, c) -> str:
    if c in MEASURES:
        return MEASURES[c].label
    spec = column_metric(table, c) or metric_spec(str(c))
    return f"{spec.label} {spec.arrow}"


def _swept_level(table: pd.DataFrame, level: int) -> bool:
    name = table.index.names[level]
    values = list(dict.fromkeys(table.index.get_level_values(level)))
    if name in SWEPT_LEVELS:
        return len(values) > 1
    nums = numeric_labels(values)
    return nums is not None and len(set(nums)) > 1


def axis_plots(tables: Sequence[tuple[str, str, pd.DataFrame]]) -> list[Plot]:
    """One plot per swept axis: every metric (and cost) of the first table that has the axis as an
    index level, against it.

    Args:
        tables: ``(stem, title, table)`` of the report, in the order of the page.

    Returns:
        A :class:`Plot` per swept level (a level named in :data:`SWEPT_LEVELS` with two or more
        labels, or whose labels are two or more distinct numbers), in the order of first appearance:
        a subplot per value column with values, one line per combination of the other index levels
        (e.g. per method against the IOR, per variant against R_main), one point per value of the
        axis (its mean over the cells, as in the table; hover: ``n``). Numeric labels are placed on
        a numeric axis, others (``"default"``) in the table's order on a category axis.
    """
    plots, seen = [], set()
    for _, title, table in tables:
        if table.index.nlevels < 2 or len(table) == 0:
            continue
        for level in range(table.index.nlevels):
            name = str(table.index.names[level])
            if name in seen or not _swept_level(table, level):
                continue
            seen.add(name)
            cols = _value_columns(table)
            if not cols:
                continue
            import plotly.graph_objects as go

            fig, ncols = _subplots([f"{_label(table, c)} against {name}" for c in cols])
            others = [i for i in range(table.index.nlevels) if i != level]
            x_all = list(dict.fromkeys(table.index.get_level_values(level)))
            numeric = numeric_labels(x_all) is not None
            series: dict[tuple, list[int]] = {}
            for i, key in enumerate(table.index):
                series.setdefault(tuple(key[j] for j in others), []).append(i)
            for k, c in enumerate(cols):
                row, col = k // ncols + 1, k % ncols + 1
                for si, (skey, rows) in enumerate(series.items()):
                    xs = [table.index[i][level] for i in rows]
                    ys = pd.to_numeric(table[c].iloc[rows], errors="coerce").tolist()
                    n = table["n"].iloc[rows].tolist() if "n" in table.columns else [None] * len(rows)
                    fig.add_trace(
                        go.Scatter(
                            x=_floats(xs) if numeric else [html_escape(x) for x in xs],
                            y=_floats(ys),
                            mode="lines+markers",
                            name=html_escape(" / ".join(str(s) for s in skey)),
                            legendgroup=str(si),
                            showlegend=k == 0,
                            marker={"color": _color(si)},
                            line={"color": _color(si)},
                            text=[f"n = {v}" for v in n],
                            hovertemplate="%{x}: %{y}<br>%{text}<extra>%{fullData.name}</extra>",
                        ),
                        row=row,
                        col=col,
                    )
                fig.update_xaxes(title_text=html_escape(name), row=row, col=col)
                if not numeric:
                    fig.update_xaxes(
                        type="category", categoryorder="array", categoryarray=[html_escape(x) for x in x_all]
                    )
            plots.append(Plot(f"plot-{slug(name) or 'axis'}", f"Against {name} ({title})", plot_json(fig)))
    return plots


def _color(i: int) -> str:
    import plotly.colors

    palette = plotly.colors.qualitative.D3
    return palette[i % len(palette)]


# --------------------------------------------------------------------------------------------
# Speed/accuracy sweeps
# --------------------------------------------------------------------------------------------

_FIDELITY = {
    "psnr_converged": "PSNR vs converged reference (dB)",
    "psnr": "PSNR vs own reference (dB)",
    "psnr_true": "PSNR vs true render (dB)",
}


def _axis_names(table: pd.DataFrame) -> list[str]:
    return [a for a in dict.fromkeys(table["axis"]) if isinstance(a, str) and a != PRESET_AXIS]


def tradeoff_axis_plot(table: pd.DataFrame, df: pd.DataFrame) -> Plot | None:
    """Fidelity against each swept setting of a speed/accuracy sweep.

    Args:
        table: per-setting means from ``tradeoff_table``.
        df: its rows (``collect_tradeoff``), for each setting's value on its axis.

    Returns:
        A subplot per axis (in sweep order): the mean :func:`~.tradeoff.fidelity_column` and, where
        any setting has it, the mean PSNR against the true render, against the setting's value (a
        numeric axis where every value of the axis is a number, else the values in sweep order);
        hover: the setting, its mean total time and ``n``/``n_scenes``. None without an axis.
    """
    import plotly.graph_objects as go

    axes = _axis_names(table)
    if not axes:
        return None
    fid = fidelity_column(table)
    metrics = [fid] + (["psnr_true"] if table["psnr_true"].notna().any() else [])
    value_of = df.drop_duplicates("setting").set_index("setting")["value"] if "value" in df else pd.Series(dtype=object)
    fig, ncols = _subplots([f"{a}" for a in axes])
    for k, a in enumerate(axes):
        row, col = k // ncols + 1, k % ncols + 1
        sub = table[table["axis"] == a]
        values = [value_of.get(s, s) for s in sub.index]
        nums = numeric_labels(values)
        xs = nums if nums is not None else [html_escape(v) for v in values]
        for mi, m in enumerate(metrics):
            fig.add_trace(
                go.Scatter(
                    x=xs,
                    y=_floats(sub[m]),
                    mode="lines+markers",
                    name=html_escape(_FIDELITY.get(m, m)),
                    legendgroup=m,
                    showlegend=k == 0,
                    marker={"color": _color(mi)},
                    line={"color": _color(mi)},
                    text=[
                        f"{html_escape(s)}<br>total {t:.2f} s<br>n = {n}/{ns}"
                        for s, t, n, ns in zip(sub.index, sub["timings_s.total"], sub["n"], sub["n_scenes"])
                    ],
                    hovertemplate="%{text}<br>%{y:.2f} dB<extra>%{fullData.name}</extra>",
                ),
                row=row,
                col=col,
            )
        fig.update_xaxes(title_text=html_escape(a), row=row, col=col)
        if nums is None:
            fig.update_xaxes(type="category", row=row, col=col)
        elif min(nums) > 0 and max(nums) / min(nums) >= 20:
            fig.update_xaxes(type="log", row=row, col=col)
        fig.update_yaxes(title_text="dB" if col == 1 else None, row=row, col=col)
    return Plot("plot-settings", "Fidelity against each setting", plot_json(fig))


def pareto_plot(table: pd.DataFrame) -> Plot:
    """Mean total time (log scale) against mean fidelity, one colour per axis, presets as stars,
    the baseline as a ring, and the Pareto front (settings that succeeded on every scene) as a
    step line; hover names the setting.

    Args:
        table: per-setting means from ``tradeoff_table``.

    Returns:
        The :class:`Plot`.
    """
    import plotly.graph_objects as go

    fid = fidelity_column(table)
    fig = go.Figure()
    x = table["timings_s.total"].to_numpy(float)
    y = table[fid].to_numpy(float)
    groups = [(a, (table["axis"] == a).to_numpy(), "circle") for a in _axis_names(table)]
    base = np.array([not isinstance(a, str) for a in table["axis"]])
    groups = (
        [("baseline", base, "circle-open")] + groups + [("presets", (table["axis"] == PRESET_AXIS).to_numpy(), "star")]
    )
    for gi, (name, sel, symbol) in enumerate(groups):
        if not sel.any():
            continue
        fig.add_trace(
            go.Scatter(
                x=_floats(x[sel]),
                y=_floats(y[sel]),
                mode="markers",
                name=html_escape(name),
                marker={"symbol": symbol, "size": 14 if symbol == "star" else 9, "color": _color(gi)},
                text=[html_escape(s) for s in table.index[sel]],
                hovertemplate="%{text}<br>total %{x:.2f} s<br>%{y:.2f} dB<extra></extra>",
            )
        )
    front = complete_front(table, x, y)
    if front.size:
        fig.add_trace(
            go.Scatter(
                x=_floats(x[front]),
                y=_floats(y[front]),
                mode="lines",
                line={"shape": "hv", "dash": "dash", "color": "grey"},
                name="Pareto front",
                text=[html_escape(s) for s in table.index[front]],
                hovertemplate="%{text}<extra>Pareto front</extra>",
            )
        )
    finite = x[np.isfinite(x)]
    fig.update_layout(
        template="plotly_white",
        height=460,
        margin={"l": 60, "r": 20, "t": 30, "b": 50},
        xaxis={
            "title": {"text": "mean total time per image (s)"},
            "type": "log" if finite.size and (finite > 0).all() else "linear",
        },
        yaxis={"title": {"text": html_escape(_FIDELITY.get(fid, fid))}},
    )
    return Plot("plot-pareto", "Time against fidelity (Pareto front)", plot_json(fig))
