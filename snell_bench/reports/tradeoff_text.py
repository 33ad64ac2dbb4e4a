"""The speed/accuracy part of a report in words: ``tradeoff.md`` (per-setting table, reference
convergence, notes), the page's summary paragraph and notes; Markdown through :func:`.writers.pipe_table`,
every string from the records escaped (:func:`~.text.md_escape`)."""

from __future__ import annotations

import json
import math
from collections import Counter

import pandas as pd

from .collect import skipped_files
from .spec import MISSING, metric_spec
from .text import is_missing, md_escape, one_line
from .tradeoff import PRESET_AXIS, RECORD_METRICS, SPP_KEY, STAGES, TOTAL_NOTE, fidelity_column
from .writers import pipe_table, skipped_markdown

__all__ = ["tradeoff_markdown", "tradeoff_summary", "tradeoff_notes"]


def _fmt(v, spec: str = "{:.2f}") -> str:
    return MISSING if is_missing(v) else spec.format(v)


def tradeoff_markdown(table: pd.DataFrame, df: pd.DataFrame, title: str = "Speed/accuracy trade-off") -> str:
    """The per-setting table as Markdown.

    Args:
        table: from :func:`tradeoff_table`.
        df: the rows it was built from (:func:`collect_tradeoff`), for provenance and notes.
        title: the ``#`` heading.

    Returns:
        The heading, what the numbers are, the per-setting pipe table (presets in bold, the Pareto
        front starred, "missing" for LPIPS without a value), the reference convergence of the spp
        axes, notes listing failed settings and missing metrics with their reasons, and the record
        files left out (:func:`~.collect.skipped_files`); every text from the records escaped
        (:func:`~.text.md_escape`).
    """
    lines = [f"# {md_escape(title)}", "", tradeoff_summary(table, df, bold="**", quote=md_escape), ""]
    stages = (*STAGES, "total")
    head = ["setting", *(k.replace("_", " ") for k in stages), *(metric_spec(m).label for m in _TRADEOFF_METRICS)]
    head += ["ref. self-noise", "n", "pareto"]
    rows = []
    for setting, r in table.iterrows():
        label = f"**{md_escape(setting)}**" if r["axis"] == PRESET_AXIS else md_escape(setting)
        cells = [label] + [_fmt(r[f"timings_s.{k}"]) for k in stages]
        cells += [
            *(_metric_text(m, r.get(m, float("nan")), "missing") for m in _TRADEOFF_METRICS),
            _fmt(r.get("reference_self_noise_db", float("nan"))),
            f"{int(r['n'])}/{int(r['n_scenes'])}",
            "★" if r["pareto"] else "",
        ]
        if r["axis"] == PRESET_AXIS:
            cells = [f"**{x}**" if x and not x.startswith("**") else x for x in cells]
        rows.append(cells)
    lines += pipe_table(head, rows, [None] + ["right"] * (len(head) - 2) + ["center"])
    lines += _convergence_markdown(table, df)
    notes = tradeoff_notes(df)
    if notes:
        lines += ["", "## Notes", ""] + [f"- {md_escape(n)}" for n in notes]
    lines += skipped_markdown(skipped_files(df), "##")
    return "\n".join(lines) + "\n"


def _convergence_markdown(table: pd.DataFrame, df: pd.DataFrame) -> list[str]:
    """The "Reference convergence" section of :func:`tradeoff_markdown` (none without an spp axis)."""
    spp = df[df.apply(_is_spp_axis_row, axis=1)] if not df.empty else df
    if spp.empty:
        return []
    rows = []
    for (axis, setting), g in spp.groupby(["axis", "setting"], sort=False):
        n = int(g["knob.spp"].iloc[0]) if "knob.spp" in g and g["knob.spp"].notna().any() else None
        top = n is not None and n == spp.loc[spp["axis"] == axis, "knob.spp"].max()
        v = table.loc[setting, "reference_psnr_vs_max_spp"] if setting in table.index else float("nan")
        own = table.loc[setting, "reference_self_noise_db"] if setting in table.index else float("nan")
        rows.append(
            [
                md_escape(setting),
                str(n) if n is not None else MISSING,
                "(highest spp: the comparison reference)" if top else _fmt(v),
                _fmt(own),
            ]
        )
    return [
        "",
        "## Reference convergence",
        "",
        "Masked PSNR (grayscale, histogram-matched) of each reference render against the highest-spp "
        "reference of its axis for the same scene, over that reference's metric mask; mean over scenes; "
        "computed from the saved float references (`reference.npy`).",
        "",
        *pipe_table(
            ["setting", "spp", "PSNR vs max spp", "self-noise (two halves)"], rows, [None, "right", "right", "right"]
        ),
    ]


def tradeoff_summary(table: pd.DataFrame, df: pd.DataFrame, bold: str = "", quote=str) -> str:
    """What a sweep's per-setting numbers are: scenes, model, runs, times, every PSNR column and
    the Pareto flag (the paragraph under the heading of :func:`tradeoff_markdown`).

    Args:
        table: from :func:`tradeoff_table`.
        df: the rows it was built from (:func:`collect_tradeoff`).
        bold: the mark around the word "pareto" (``"**"`` in Markdown).
        quote: applied to the names from the records (scenes, models): :func:`~.text.md_escape` in
            Markdown; ``str`` where the page escapes them itself.

    Returns:
        One paragraph; the record files left out (:func:`~.collect.skipped_files`) are counted in it.
    """
    models = sorted({quote(m) for m in df["model"].dropna()}) if "model" in df else []
    status = Counter(str(s) for s in df["status"])
    counts = ", ".join(f"{v} {quote(k)}" for k, v in sorted(status.items()))
    bad = len(skipped_files(df))
    counts += f"; {bad} file{'s' if bad != 1 else ''} skipped (not cell records)" if bad else ""
    spps = sorted({int(v) for v in df.get("converged_spp", pd.Series(dtype=float)).dropna()})
    conv_text = f"{'/'.join(map(str, spps))} spp" if spps else "none in this sweep"
    fid_text = "PSNR (conv.)" if fidelity_column(table) == "psnr_converged" else "PSNR"
    return (
        f"Means over the scenes where a setting succeeded ({', '.join(quote(x) for x in sorted(df['scene'].dropna().unique()))}); "
        f"model: {', '.join(models) or 'unknown'}; {len(df)} runs ({counts}). "
        f"Times in seconds; {TOTAL_NOTE}. PSNR: masked, vs the setting's own reference render (so it also "
        "moves with reference.spp, see the reference convergence below); PSNR (conv.): vs a converged reference "
        f"of the same scene, object and resolution ({conv_text}); PSNR (true): vs the true render, traced with "
        "reference.true_max_bounces (the setting's warps.max_bounces where that is null); ref. self-noise: the "
        "PSNR of the setting's reference against its own noise-free limit, estimated from two independent "
        "halves of its samples (the ceiling of its PSNR column). "
        f"{bold}pareto{bold}: on the front of (mean total ↓, mean {fid_text} ↑) among the settings that succeeded on "
        "every scene. Presets in bold."
    )


def tradeoff_notes(df: pd.DataFrame) -> list[str]:
    """A sweep's notes: every setting not ok on a scene with its reason, and every metric of
    :data:`RECORD_METRICS` missing in ok runs, grouped by the recorded reason.

    Args:
        df: rows from :func:`collect_tradeoff`.

    Returns:
        One line each, reasons on one line.
    """
    notes = []
    for _, r in df[df["status"] != "ok"].iterrows():
        notes.append(f"{r['status']}: {r['scene']} / {r['setting']} — {one_line(r['reason'])}")
    for m in RECORD_METRICS:
        col = f"missing.{m}"
        ok = df[df["status"] == "ok"]
        if col in ok and ok[m].isna().any():
            for why, n in Counter(str(v) for v in ok.loc[ok[m].isna(), col]).items():
                notes.append(f"{m}: missing in {n} of {len(ok)} ok runs — {one_line(why)}")
    return notes


def _is_spp_axis_row(r) -> bool:
    try:
        return (
            r["status"] == "ok"
            and isinstance(r["axis"], str)
            and r["axis"] != PRESET_AXIS
            and set(json.loads(r["overrides"])) == {SPP_KEY}
        )
    except (TypeError, ValueError):
        return False


#: The metric columns of a sweep's tables, in order (labels and formats from the metric registry).
_TRADEOFF_METRICS = ("psnr", "psnr_converged", "psnr_true", "lpips")


def _metric_text(name: str, value, missing: str = MISSING) -> str:
    """A sweep's metric value as its spec prints it (``missing`` for no value)."""
    v = float("nan") if value is None else float(value)
    return missing if math.isnan(v) else metric_spec(name).fmt(v)
