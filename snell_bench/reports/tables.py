"""Tables from the cells of :func:`~snell_bench.reports.collect.collect`: methods x
metrics, scenes x methods, the ablation, time saved against fidelity lost; and the best /
second-best ranking the writers mark (:mod:`~snell_bench.reports.ranking`, re-exported here).

A table is a DataFrame whose index holds the row labels (``index.name`` is the row header) and
whose columns are metric names plus ``n``, the number of ``ok`` cells averaged (a scene table has
method labels as columns and one metric for all of them). The builders store display hints in
``table.attrs``: ``provenance``, ``notes``, ``caption``, ``metric`` (scene tables), ``highlight``
(``"columns"``, ``"rows"`` or ``"blocks"``: where best and second best are ranked), ``methods`` and
``cells`` (per row, the folders of the cells it stands for, every status: the HTML report's
tooltips and filters read them).

A table never averages cells of different values of a swept axis (:func:`swept_axes`: today the
IOR, when one object ran at two or more IORs): where the axis varies within the cells a row would
average, the table gets the axis as its outermost index level (``"IOR"``), one block per value
(:mod:`~snell_bench.reports.swept`, whose names are re-exported here).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Sequence

import numpy as np
import pandas as pd

from .collect import cell_notes, provenance_line, recorded_metrics, reference_noise_note
from .ranking import column_metric, rank_marks
from .spec import (
    ABLATION_METRICS,
    ABLATION_ROWS,
    MEASURES,
    METRICS,
    OPTIONAL_METRICS,
    SCENE_METRICS,
    TABLE1_METRICS,
    TIME_TRAVEL_ROWS,
    TIME_TRAVEL_VARIANTS,
    metric_spec,
)
from .swept import DEFAULT_IOR, ior_label, keep_swept, object_ior, object_order, swept_axes, swept_parts

__all__ = [
    "SAVING_METHODS",
    "TIME_TRAVEL_METRICS",
    "method_labels",
    "with_recorded_metrics",
    "object_ior",
    "ior_label",
    "DEFAULT_IOR",
    "swept_axes",
    "method_table",
    "scene_table",
    "block_table",
    "ablation_table",
    "time_travel_table",
    "savings_table",
    "column_metric",
    "rank_marks",
]

TIME_TRAVEL_METRICS = ("psnr", "lpips", "mae", "clip", "image_reward")
"""Value columns of :func:`time_travel_table`, before the recorded optional metrics and the cost."""

SAVING_METHODS = ("full_frame", "adaptive")
"""Methods compared with ``snellcaster`` in :func:`savings_table` (same images, or modelling less)."""


def _mean(s: pd.Series) -> float:
    # Series.mean, not the grouped cython mean: that one sums with compensation and can differ in
    # the last bit, which the full-precision CSVs would show
    return s.mean()


# --------------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------------


def _method_order(methods: Iterable[str], order: Sequence[str] | None) -> list[str]:
    methods = sorted(set(methods))
    if not order:
        return methods
    first = [m for m in order if m in methods]
    return first + [m for m in methods if m not in first]


def method_labels(df: pd.DataFrame) -> dict[str, str]:
    """Method name -> display label: its most common ``method_label`` (the name if none); labels
    shared by several methods get the method name appended."""
    labels = {}
    for meth, g in df.groupby("method", sort=True):
        vals = [v for v in g["method_label"] if isinstance(v, str) and v]
        labels[meth] = Counter(vals).most_common(1)[0][0] if vals else str(meth)
    dup = Counter(labels.values())
    return {k: (f"{v} ({k})" if dup[v] > 1 else v) for k, v in labels.items()}


def _means(df: pd.DataFrame, methods: Sequence[str], metrics: Sequence[str]) -> pd.DataFrame:
    """Per method (rows, in ``methods``' order): the mean of each metric over the ``ok`` cells
    (NaN where none has a value) and ``n``, the number of those cells."""
    ok = df[df["status"] == "ok"]
    present = [m for m in metrics if m in ok.columns]
    means = ok.groupby("method")[present].agg(_mean) if present else pd.DataFrame(index=[])
    out = means.reindex(index=list(methods), columns=list(metrics)).astype(float)
    out["n"] = ok["method"].value_counts().reindex(list(methods), fill_value=0).to_numpy(dtype=int)
    out.index.name = None
    return out


def with_recorded_metrics(df: pd.DataFrame, metrics: Sequence[str]) -> tuple[str, ...]:
    """``metrics`` followed by those of :data:`OPTIONAL_METRICS` the cells record, then every
    other metric they record (users' metrics, ``metrics.extra``: :func:`~.collect.recorded_metrics`).

    ``lpips_box`` is added wherever any cell's ``metrics.json`` has the key (a column of "—" with
    its reason in the notes if it has no value anywhere); ``mae`` and ``psnr_true`` where any
    ``ok`` cell has a value; a user's metric wherever any cell records it (its reasons in the notes).

    Args:
        df: cells from ``collect``.
        metrics: the table's own columns, in order.

    Returns:
        The columns, in order, without repeats.
    """
    ok = df[df["status"] == "ok"] if "status" in df.columns else df
    extra = []
    for m in OPTIONAL_METRICS:
        if m in metrics or m not in df.columns:
            continue
        if m == "lpips_box" or ok[m].notna().any():
            extra.append(m)
    extra += [m for m in recorded_metrics(df) if m not in METRICS and m not in metrics and m not in extra]
    return tuple(metrics) + tuple(extra)


def _cells_of(df: pd.DataFrame, values: Sequence[str], column: str = "method") -> list[list[str]]:
    """Per value of ``column`` (a method), the folders of its cells in ``df`` (every status)."""
    if "cell_dir" not in df.columns:
        return [[] for _ in values]
    return [[str(d) for d in df.loc[df[column].astype(str) == v, "cell_dir"]] for v in values]


def _group_order(values: Iterable[str], by: str) -> list[str]:
    values = sorted({str(v) for v in values})
    return sorted(values, key=object_order) if by == "object" else values


def _check(df: pd.DataFrame) -> None:
    missing = [c for c in ("method", "status") if c not in df.columns]
    if missing:
        raise ValueError(f"not a cell table from collect(): no column(s) {missing}")


def method_table(
    df: pd.DataFrame, metrics: Sequence[str] = TABLE1_METRICS, order: Sequence[str] | None = None
) -> pd.DataFrame:
    """Table 1: the mean of each metric per method over the cells with status ``ok``.

    A metric with no value in some ``ok`` cells is averaged over the cells that have one; the notes
    say how many lack it and why.

    Args:
        df: cells from ``collect``.
        metrics: the value columns, in order.
        order: method names shown first, in this order; the others follow, sorted by name.

    Returns:
        One row per method, labelled by ``method_label`` (``index.name`` ``"Method"``), with the
        ``metrics`` and ``n``, the number of ``ok`` cells (0 for a method whose cells all failed;
        its values are NaN). The notes end with the references' self-noise where the cells record
        it (:func:`~snell_bench.reports.collect.reference_noise_note`). Where the cells
        sweep an axis (:func:`swept_axes`), indexed by ``(IOR, Method)``, ranked per IOR.

    Raises:
        ValueError: ``df`` has no ``method`` or ``status`` column.
    """
    _check(df)
    labels = method_labels(df)

    def build(d: pd.DataFrame) -> pd.DataFrame:
        methods = _method_order(d["method"].dropna().astype(str), order)
        table = _means(d, methods, metrics)
        table.index = pd.Index([labels[m] for m in methods], name="Method")
        noise = reference_noise_note(d)
        table.attrs.update(
            provenance=provenance_line(d),
            notes=cell_notes(d, metrics) + ([noise] if noise else []),
            caption="Means over cells with status ok; n = cells averaged.",
            highlight="columns",
            methods=list(methods),
            cells=_cells_of(d, methods),
        )
        return table

    return keep_swept(df, build, ["method"])


def scene_table(df: pd.DataFrame, metric: str = "psnr", order: Sequence[str] | None = None) -> pd.DataFrame:
    """The mean of one metric per scene and method over the cells with status ``ok``.

    Args:
        df: cells from ``collect``.
        metric: the metric of every value.
        order: the method columns' order, as in :func:`method_table`.

    Returns:
        One row per scene (sorted, ``index.name`` ``"Scene"``), one column per method (labelled by
        ``method_label``); NaN where a scene has no value for a method. Best and second best are
        ranked per scene (``attrs["highlight"] == "rows"``); ``attrs["cells"]`` holds every cell of
        the row's scene (a column's are those of its method, ``attrs["methods"]``). Where the cells
        sweep an axis (:func:`swept_axes`), indexed by ``(IOR, Scene)``.

    Raises:
        ValueError: ``df`` has no ``method`` or ``status`` column.
    """
    _check(df)
    methods = _method_order(df["method"].dropna().astype(str), order)
    labels = method_labels(df)

    def build(d: pd.DataFrame) -> pd.DataFrame:
        scenes = sorted(d["scene"].dropna().astype(str).unique())
        ok = d[d["status"] == "ok"]
        if metric in ok.columns and len(ok):
            table = ok.groupby(["scene", "method"])[metric].agg(_mean).unstack("method")
        else:
            table = pd.DataFrame()
        table = table.reindex(index=scenes, columns=methods).astype(float)
        table.columns = [labels[m] for m in methods]
        table.index.name = "Scene"
        spec = metric_spec(metric)
        table.attrs.update(
            provenance=provenance_line(d),
            notes=cell_notes(d, [metric]),
            caption=f"{spec.label} {spec.arrow} per scene: means over cells with status ok.",
            highlight="rows",
            metric=metric,
            methods=list(methods),
            cells=_cells_of(d, scenes, "scene"),
        )
        return table

    return keep_swept(df, build, ["scene", "method"])


def block_table(
    df: pd.DataFrame,
    metrics: Sequence[str] = SCENE_METRICS,
    order: Sequence[str] | None = None,
    by: str = "scene",
) -> pd.DataFrame:
    """Table 3: one block of rows per scene (or per object), a row per method, a column per metric.

    Args:
        df: cells from ``collect``.
        metrics: the value columns, in order.
        order: method names shown first in every block, as in :func:`method_table`.
        by: ``"scene"`` (Table 3) or ``"object"`` (the IOR sweep: objects ordered by name, then IOR).

    Returns:
        A table indexed by ``(scene, method label)`` (``index.names`` ``["Scene", "Method"]``, or
        ``["Object", "Method"]``): in each block the methods that have a cell there, with the mean
        of each metric over their ``ok`` cells (NaN where none has a value) and ``n``. Best and
        second best are ranked per column within each block (``attrs["highlight"] == "blocks"``).
        Where the cells sweep an axis that varies within a block (:func:`swept_axes`: the IOR in
        a per-scene table of the IOR sweep), indexed by ``(IOR, Scene, Method)``, a block per IOR
        and scene.

    Raises:
        ValueError: ``df`` has no ``method`` or ``status`` column, or ``by`` is not a column of it.
    """
    _check(df)
    if by not in df.columns:
        raise ValueError(f"by={by!r} is not a column of the cell table; use 'scene' or 'object'")
    methods = _method_order(df["method"].dropna().astype(str), order)
    labels = method_labels(df)

    def build(d: pd.DataFrame) -> pd.DataFrame:
        parts, keys, shown, cells = [], [], [], []
        for g in _group_order(d[by].dropna(), by):
            sub = d[d[by].astype(str) == g]
            here = [m for m in methods if (sub["method"] == m).any()]
            if not here:
                continue
            parts.append(_means(sub, here, metrics))
            keys += [(g, labels[m]) for m in here]
            shown += [m for m in here if m not in shown]
            cells += _cells_of(sub, here)
        cols = list(metrics) + ["n"]
        table = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=cols)
        table = table[cols]
        table["n"] = table["n"].astype(int)
        table.index = pd.MultiIndex.from_tuples(keys, names=[by.capitalize(), "Method"])
        what = "scene" if by == "scene" else by
        table.attrs.update(
            provenance=provenance_line(d),
            notes=cell_notes(d, metrics),
            caption=f"Means per {what} over cells with status ok; n = cells averaged.",
            highlight="blocks",
            methods=shown,
            cells=cells,
        )
        return table

    return keep_swept(df, build, [by, "method"])


def ablation_table(df: pd.DataFrame, metrics: Sequence[str] = ABLATION_METRICS) -> pd.DataFrame:
    """The ablation rows present in ``df``, in the paper's order.

    Args:
        df: cells from ``collect``; cells of methods outside :data:`ABLATION_ROWS` are ignored,
            also for provenance and notes.
        metrics: the value columns, in order.

    Returns:
        One row per variant (Full, w/o reflection, w/o panorama, w/o DPA, w/o LPW, w/o time
        travel; ``index.name`` ``"Variant"``) with the means over cells with status ``ok`` and ``n``;
        indexed by ``(IOR, Variant)`` where the cells sweep an axis (:func:`swept_axes`).

    Raises:
        ValueError: ``df`` has no ``method`` or ``status`` column.
    """
    _check(df)
    label = dict(ABLATION_ROWS)

    def build(d: pd.DataFrame) -> pd.DataFrame:
        names = [m for m, _ in ABLATION_ROWS if (d["method"] == m).any()]
        table = _means(d, names, metrics)
        table.index = pd.Index([label[m] for m in names], name="Variant")
        table.attrs.update(
            provenance=provenance_line(d),
            notes=cell_notes(d, metrics),
            caption="Ablation: means over cells with status ok; n = cells averaged.",
            highlight="columns",
            methods=list(names),
            cells=_cells_of(d, names),
        )
        return table

    return keep_swept(df[df["method"].isin([m for m, _ in ABLATION_ROWS])], build, ["method"])


def time_travel_table(df: pd.DataFrame, metrics: Sequence[str] = TIME_TRAVEL_METRICS) -> pd.DataFrame:
    """The time-travel experiment: one block per variant, a row per R_main.

    Args:
        df: cells from ``collect``; cells of methods outside :data:`TIME_TRAVEL_ROWS` are ignored,
            also for provenance and notes.
        metrics: the value columns, in order; the costs (never ranked) follow where the cells
            record them: the mean generator calls of the main view (``model_calls.main``) and the
            mean sampling time (``timings_s.sampling``).

    Returns:
        A table indexed by ``(variant label, R_main)`` (``index.names`` ``["Variant", "R_main"]``):
        the variants of :data:`TIME_TRAVEL_VARIANTS` in order, each with its R values ascending
        (the R = 1 run in both), the means over the ``ok`` cells and ``n``; best and second best
        ranked per column within each variant. Empty when no time-travel method ran. Indexed by
        ``(IOR, Variant, R_main)`` where the cells sweep an axis (:func:`swept_axes`).

    Raises:
        ValueError: ``df`` has no ``method`` or ``status`` column.
    """
    _check(df)
    cols = list(metrics) + [c for c in MEASURES if c in df.columns]

    def build(d: pd.DataFrame) -> pd.DataFrame:
        names = [m for m, _, _ in TIME_TRAVEL_ROWS if (d["method"] == m).any()]
        parts, keys, cells = [], [], []
        for variant, label in TIME_TRAVEL_VARIANTS:
            rows = sorted((r, m) for m, vs, r in TIME_TRAVEL_ROWS if variant in vs and m in names)
            if rows:
                parts.append(_means(d, [m for _, m in rows], cols))
                keys += [(label, r) for r, _ in rows]
                cells += _cells_of(d, [m for _, m in rows])
        table = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=cols + ["n"])
        table["n"] = table["n"].astype(int)
        table.index = pd.MultiIndex.from_tuples(keys, names=["Variant", "R_main"])
        table.attrs.update(
            provenance=provenance_line(d),
            notes=cell_notes(d, metrics),
            caption="Time travel: means over cells with status ok; R_main = repeats of the main view; "
            "n = cells averaged.",
            highlight="blocks",
            methods=names,
            cells=cells,
        )
        return table

    return keep_swept(df[df["method"].isin([m for m, _, _ in TIME_TRAVEL_ROWS])], build, ["method"])


def _stage_time(df: pd.DataFrame) -> pd.Series:
    """Per-cell time of what a method controls: its warps plus its sampling (seconds)."""
    cols = [c for c in ("timings_s.warps", "timings_s.sampling") if c in df.columns]
    return df[cols].sum(axis=1, min_count=1) if cols else pd.Series(np.nan, index=df.index)


def savings_table(
    df: pd.DataFrame, reference: str = "snellcaster", methods: Sequence[str] = SAVING_METHODS
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Time saved against fidelity lost, per method, over the cells it shares with ``reference``.

    Args:
        df: cells from ``collect``.
        reference: the method compared against.
        methods: the methods compared with it.

    Returns:
        ``(summary, per_cell)``. ``per_cell`` pairs every ok cell of a method with the
        ``reference`` cell of the same scene, variation and object: time (warps + sampling) of
        both, PSNR of both and the difference, and the decisions the method took. ``summary`` has
        one row per method: cells, mean times, time saved (share of the reference's), mean and
        largest |ΔPSNR|, cells without the panorama branch, cells without any reflection, mean
        share of object pixels that kept a reflection, mean share of background treated as at
        infinity. Both are empty when no method shares a cell with ``reference``. Where the cells
        sweep an axis (:func:`swept_axes`), both have it as their first column (``"IOR"``) and
        ``summary`` one row per value and method.
    """
    axes = swept_axes(df, ["method"])
    if axes:
        summaries, per_cells = [], []
        for key, sel in swept_parts(axes):
            summary, per_cell = _savings(df[sel], reference, methods, method_labels(df))
            for frame, out in ((summary, summaries), (per_cell, per_cells)):
                if not frame.empty:
                    for name, value in reversed(list(zip(axes, key))):
                        frame.insert(0, name, value)
                    out.append(frame)
        return (
            pd.concat(summaries, ignore_index=True) if summaries else pd.DataFrame(),
            pd.concat(per_cells, ignore_index=True) if per_cells else pd.DataFrame(),
        )
    return _savings(df, reference, methods, method_labels(df))


def _savings(
    df: pd.DataFrame, reference: str, methods: Sequence[str], labels: dict[str, str]
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """:func:`savings_table` of cells that sweep nothing."""
    ok = df[df["status"] == "ok"].copy()
    ok["_time"] = _stage_time(ok)
    keys = ["scene", "variation", "object"]
    ref = ok[ok["method"] == reference].set_index(keys)
    rows, summary = [], []
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
                "method": m,
                "scene": r["scene"],
                "variation": r["variation"],
                "object": r["object"],
                "time_s": r["_time"],
                "reference_time_s": b["_time"],
                "psnr": r.get("psnr", np.nan),
                "reference_psnr": b.get("psnr", np.nan),
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
        summary.append(
            {
                "method": labels.get(m, m),
                "cells": len(c),
                "time (s)": t,
                f"{labels.get(reference, reference)} (s)": tr,
                "time saved": 1 - t / tr if tr > 0 else np.nan,
                "mean ΔPSNR (dB)": c["delta_psnr"].mean(),
                "max |ΔPSNR| (dB)": c["delta_psnr"].abs().max(),
                "panorama skipped": int((c["panorama_used"] == False).sum()),  # noqa: E712 (NaN is neither)
                "reflection off": int((c["reflection_kept"] == False).sum()),  # noqa: E712
                "reflection kept (share of px)": c["reflection_share_kept"].mean(),
                "far background (share of px)": c["far_fraction"].mean(),
            }
        )
    per_cell = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame()
    return pd.DataFrame(summary), per_cell
