"""The axes a grid sweeps that no table may average over (today the IOR, named in the object
folder: ``sphere-ior1.333``), and the tables built one block per swept value."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
import pandas as pd

__all__ = ["DEFAULT_IOR", "object_ior", "ior_label", "object_order", "swept_axes", "swept_parts", "keep_swept"]


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


def object_order(name: str) -> tuple:
    """Sort key of an object folder: by object name, the one without an IOR first, then by IOR."""
    base, ior = object_ior(name)
    return (base, 0 if ior != ior else 1, 0.0 if ior != ior else ior)


def swept_parts(axes: dict[str, pd.Series]) -> Iterator[tuple[tuple, np.ndarray]]:
    """Each combination of the labels of :func:`swept_axes` that some cell has, in order
    (:data:`DEFAULT_IOR` first, then numbers ascending, then text), with the mask of its cells."""
    names = list(axes)
    labels = pd.DataFrame(axes)
    keys = sorted(set(labels.itertuples(index=False, name=None)), key=lambda k: tuple(map(_axis_sort_key, k)))
    for key in keys:
        yield key, (labels == pd.Series(key, index=names)).all(axis=1).to_numpy()


def keep_swept(df: pd.DataFrame, build, within: Sequence[str]) -> pd.DataFrame:
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
    parts, part_keys, cells = [], [], []
    for key, sel in swept_parts(axes):
        part = build(df[sel])
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
