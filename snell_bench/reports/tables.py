"""Tables from the cells of :func:`~snell_bench.reports.collect.collect`: methods x
metrics, scenes x methods, the ablation, time saved against fidelity lost; and the best /
second-best ranking the writers mark.

A table is a DataFrame whose index holds the row labels (``index.name`` is the row header) and
whose columns are metric names plus ``n``, the number of ``ok`` cells averaged (a scene table has
method labels as columns and one metric for all of them). The builders store display hints in
``table.attrs``: ``provenance``, ``notes``, ``caption``, ``metric`` (scene tables), ``highlight``
(``"columns"``, ``"rows"`` or ``"blocks"``: where best and second best are ranked), ``methods`` and
``cells`` (per row, the folders of the cells it stands for, every status: the HTML report's
tooltips and filters read them).

A table never averages cells of different values of a swept axis (:func:`swept_axes`: today the
IOR, when one object ran at two or more IORs): where the axis varies within the cells a row would
average, the table gets the axis as its outermost index level (``"IOR"``), one block per value.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Sequence

import numpy as np
import pandas as pd

from .collect import cell_notes, provenance_line, recorded_metrics, reference_noise_note
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
    Metric,
    metric_spec,
)

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


def object_ior(name: str) -> tuple[str, float]:
    """``(object name, IOR)`` of an object folder (``"sphere-ior1.333"`` -> ``("sphere", 1.333)``);
    NaN for an object without an IOR in its name."""
    base, sep, ior = str(name).rpartition("-ior")
    if sep:
        try:
            return base, float(ior)
        except ValueError:
            pass
    return str(name), float("nan")


DEFAULT_IOR = "default"
"""The IOR label of an object folder without ``-ior`` in its name (the object config's own IOR)."""


def ior_label(name: str) -> str:
    """The IOR of an object folder as written in its name (``"sphere-ior1.333"`` -> ``"1.333"``,
    ``"sphere-iorwater"`` -> ``"water"``); :data:`DEFAULT_IOR` without ``-ior``."""
    _, sep, ior = str(name).rpartition("-ior")
    return ior if sep and ior else DEFAULT_IOR


def _object_base(name: str) -> str:
    base, sep, ior = str(name).rpartition("-ior")
    return base if sep and ior else str(name)


def _axis_sort_key(label: str) -> tuple:
    """Order of an axis' labels: :data:`DEFAULT_IOR` first, then numbers ascending, then text."""
    if label == DEFAULT_IOR:
        return (0, 0.0, "")
    try:
        return (1, float(label), "")
    except ValueError:
        return (2, 0.0, str(label))


def swept_axes(df: pd.DataFrame, within: Sequence[str] = ()) -> dict[str, pd.Series]:
    """The axes the cells sweep that no mean may average over.

    Today one axis, ``"IOR"``: swept when one object (the folder name before ``-ior``) ran at two
    or more IORs (:func:`ior_label`; an object folder without ``-ior`` counts as
    :data:`DEFAULT_IOR`).

    Args:
        df: cells from ``collect``.
        within: the columns a table groups the cells by (``["scene", "method"]``); an axis is
            returned only where it varies within one of those groups (an IOR table grouped by
            object never has it). Empty: every swept axis.

    Returns:
        ``{level name: the label of each cell (a Series aligned with df)}``, empty when nothing is
        swept.
    """
    out: dict[str, pd.Series] = {}
    if "object" not in df.columns or df.empty:
        return out
    objects = df["object"].astype(str)
    labels = objects.map(ior_label)
    per_object = pd.DataFrame({"base": objects.map(_object_base), "ior": labels}).groupby("base")["ior"].nunique()
    if not (per_object > 1).any():
        return out
    keys = [c for c in within if c in df.columns]
    varies = labels.groupby([df[c].astype(str) for c in keys]).nunique().gt(1).any() if keys else True
    if varies:
        out["IOR"] = labels
    return out


def _cells_of(df: pd.DataFrame, methods: Sequence[str]) -> list[list[str]]:
    """Per method, the folders of its cells in ``df`` (every status)."""
    if "cell_dir" not in df.columns:
        return [[] for _ in methods]
    return [[str(d) for d in df.loc[df["method"] == m, "cell_dir"]] for m in methods]


def _keep_swept(df: pd.DataFrame, build, within: Sequence[str]) -> pd.DataFrame:
    """``build(df)``, or, where a swept axis varies within the groups ``within``, ``build`` of the
    cells of each of its values, stacked under an outer index level named after the axis.

    The stacked table keeps the attrs of ``build(df)`` (provenance and notes over every cell) with
    ``cells`` per row, best and second best ranked within each block (``highlight``
    ``"columns"`` becomes ``"blocks"``) and the caption saying which axis keeps rows apart.
    """
    whole = build(df)
    axes = swept_axes(df, within)
    if not axes:
        return whole
    names = list(axes)
    labels = pd.DataFrame(axes)
    keys = sorted(set(labels.itertuples(index=False, name=None)), key=lambda k: tuple(map(_axis_sort_key, k)))
    parts, part_keys, cells = [], [], []
    for key in keys:
        sel = (labels == pd.Series(key, index=names)).all(axis=1)
        part = build(df[sel.to_numpy()])
        if len(part) == 0:
            continue
        parts.append(part.reindex(columns=whole.columns))
        part_keys.append(key if len(key) > 1 else key[0])
        cells += part.attrs.get("cells", [[] for _ in range(len(part))])
    if not parts:
        return whole
    table = pd.concat(parts, keys=part_keys, names=names + list(whole.index.names))
    if "n" in table.columns:
        table["n"] = table["n"].fillna(0).astype(int)
    highlight = whole.attrs.get("highlight")
    caption = whole.attrs.get("caption", "")
    what = " and ".join(names)
    table.attrs = {
        **whole.attrs,
        "cells": cells,
        "highlight": "blocks" if highlight == "columns" else highlight,
        "caption": (caption + " " if caption else "") + f"One block per {what}: the cells sweep it.",
    }
    return table


def _group_order(values: Iterable[str], by: str) -> list[str]:
    values = sorted({str(v) for v in values})
    if by != "object":
        return values

    def key(v):
        name, ior = object_ior(v)
        return (name, 0 if ior != ior else 1, 0.0 if ior != ior else ior)

    return sorted(values, key=key)


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

    return _keep_swept(df, build, ["method"])


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
            cells=[[str(c) for c in d.loc[d["scene"].astype(str) == sc, "cell_dir"]] for sc in scenes]
            if "cell_dir" in d.columns
            else [[] for _ in scenes],
        )
        return table

    return _keep_swept(df, build, ["scene", "method"])


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

    return _keep_swept(df, build, [by, "method"])


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

    return _keep_swept(df[df["method"].isin([m for m, _ in ABLATION_ROWS])], build, ["method"])


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

    return _keep_swept(df[df["method"].isin([m for m, _, _ in TIME_TRAVEL_ROWS])], build, ["method"])


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
        labels = pd.DataFrame(axes)
        for key in sorted(set(labels.itertuples(index=False, name=None)), key=lambda k: tuple(map(_axis_sort_key, k))):
            sel = (labels == pd.Series(key, index=list(axes))).all(axis=1).to_numpy()
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


# --------------------------------------------------------------------------------------------
# Ranking
# --------------------------------------------------------------------------------------------


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
