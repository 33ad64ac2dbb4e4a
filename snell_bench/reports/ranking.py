"""Best and second-best values of a table, as the writers and the HTML page mark them: per column,
per row or per block, in each metric's direction, on the values as displayed."""

from __future__ import annotations

import pandas as pd

from .spec import MEASURES, METRICS, Metric, metric_spec

__all__ = ["column_metric", "rank_marks"]


def column_metric(table: pd.DataFrame, col) -> Metric | None:
    """The metric of a value column: the table's ``attrs["metric"]`` for scene tables, else the
    column's own; None for ``n`` and for columns that are not metrics."""
    if col == "n" or col in MEASURES:
        return None
    if table.attrs.get("metric"):
        return metric_spec(table.attrs["metric"])
    if col in METRICS:
        return METRICS[col]
    spec = metric_spec(str(col))  # a user's metric, installed here (metrics.extra)
    return None if spec.source == "unknown" else spec


def rank_marks(table: pd.DataFrame) -> dict[tuple[int, int], int]:
    """Best and second-best cells of a table.

    Cells are ranked per column, per row when ``table.attrs["highlight"] == "rows"``, or per
    column within each block of rows sharing every index level but the last when it is ``"blocks"``, in
    the direction of their metric (:func:`column_metric`), on the values as displayed (rounded to the
    metric's format), so ties share the rank. A column (row) with fewer than two values gets no
    mark; ``n`` and non-metric columns are never ranked.

    Args:
        table: a table of this module.

    Returns:
        ``{(row position, column position): 1 for best, 2 for second best}``.
    """
    ranks: dict[tuple[int, int], int] = {}
    highlight = table.attrs.get("highlight")
    cols = list(table.columns)
    if highlight == "rows":
        groups = [[(i, j) for j in range(len(cols))] for i in range(len(table))]
    elif highlight == "blocks":
        first = [k[:-1] if isinstance(k, tuple) else k for k in table.index]
        blocks: dict = {}
        for i, b in enumerate(first):
            blocks.setdefault(b, []).append(i)
        groups = [[(i, j) for i in rows] for rows in blocks.values() for j in range(len(cols))]
    else:
        groups = [[(i, j) for i in range(len(table))] for j in range(len(cols))]
    for cells in groups:
        vals = []
        for i, j in cells:
            spec = column_metric(table, cols[j])
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
