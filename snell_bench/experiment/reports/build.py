"""Every report of a run folder at once: a grid experiment's tables, figure and README, or a
speed/accuracy sweep's CSV, Markdown and Pareto plot. Every file is written atomically."""

from __future__ import annotations

import os
import re
from pathlib import Path

from snell_bench.utils.io import atomic_write_bytes, write_text

from .collect import collect
from .figures import pareto_figure, qualitative_figure
from .spec import ABLATION_ROWS, TABLE1_METRICS
from .tables import SAVING_METHODS, ablation_table, method_table, provenance_line, savings_table, scene_table
from .tradeoff import collect_tradeoff, tradeoff_table
from .writers import plain_markdown, to_csv, to_latex, to_markdown, tradeoff_markdown

__all__ = ["build_reports", "build_tradeoff_report"]

_SAVINGS_NOTE = (
    "Time = warps + sampling per cell, against Snellcaster on the same scene and object; "
    "ΔPSNR = method − Snellcaster (masked, against the reference)."
)


def _slug(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", s).strip("_").lower() or "exp"


def build_reports(run_dir: str | os.PathLike, out_dir: str | os.PathLike, experiment_name: str) -> list[Path]:
    """Write every table and the figure of one experiment from its run directory alone.

    Writes ``method_table``, ``scene_table`` (PSNR) and, if the runs contain an ablation variant
    (a method of :data:`ABLATION_ROWS` other than ``snellcaster``), ``ablation_table``, each as
    ``.md``, ``.tex`` and ``.csv``; ``savings.md``, ``savings.csv`` and ``savings_per_cell.csv``
    when ``full_frame`` or ``adaptive`` ran beside ``snellcaster``; ``qualitative.png``; and
    ``README.md`` linking them with the provenance line and the notes. The method table has the
    columns of Table 1, followed by MAE and PSNR (true) where any cell has them.

    Args:
        run_dir: the experiment's run directory.
        out_dir: where to write (created if needed).
        experiment_name: shown in titles and LaTeX labels.

    Returns:
        The written paths.

    Raises:
        FileNotFoundError: there is no cell below ``run_dir``.
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
        write_text(md, to_markdown(table, title))
        write_text(tex, to_latex(table, title, label=f"tab:{_slug(experiment_name)}_{stem}"))
        to_csv(table, csv)
        written += [md, tex, csv]
    savings = None
    if df["method"].isin(SAVING_METHODS).any() and (df["method"] == "snellcaster").any():
        summary, per_cell = savings_table(df)
        if not summary.empty:
            title = f"Time saved against fidelity lost ({experiment_name})"
            write_text(out_dir / "savings.md", plain_markdown(summary, title, _SAVINGS_NOTE))
            write_text(out_dir / "savings.csv", summary.to_csv(index=False))
            write_text(out_dir / "savings_per_cell.csv", per_cell.to_csv(index=False))
            written += [out_dir / "savings.md", out_dir / "savings.csv", out_dir / "savings_per_cell.csv"]
            savings = summary
    written.append(qualitative_figure(run_dir, out_dir / "qualitative.png"))

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
        lines.append(
            "- Time saved against fidelity lost: [savings.md](savings.md) · [savings.csv](savings.csv) · "
            "[savings_per_cell.csv](savings_per_cell.csv)"
        )
    lines += ["- Qualitative comparison: [qualitative.png](qualitative.png)", ""]
    lines += [to_markdown(tables[0][2], tables[0][1])]
    lines += ["![qualitative comparison](qualitative.png)", ""]
    written.append(write_text(out_dir / "README.md", "\n".join(lines)))
    return written


def build_tradeoff_report(runs_root: str | os.PathLike, out_dir: str | os.PathLike) -> list[Path]:
    """Write the report of a speed/accuracy sweep from its run folder alone.

    Args:
        runs_root: the sweep's run folder.
        out_dir: where to write (created if needed).

    Returns:
        The written paths: ``tradeoff.csv`` (one row per scene x setting), ``tradeoff.md`` (per
        setting, means over the scenes where it succeeded) and ``pareto.png``.

    Raises:
        FileNotFoundError: there is no ``result.json`` below ``runs_root``.
    """
    runs_root, out_dir = Path(runs_root), Path(out_dir)
    df = collect_tradeoff(runs_root)
    if df.empty:
        raise FileNotFoundError(f"no settings (result.json) below {runs_root}")
    out_dir.mkdir(parents=True, exist_ok=True)
    table = tradeoff_table(df)
    csv = out_dir / "tradeoff.csv"
    atomic_write_bytes(csv, df.to_csv(index=False, lineterminator="\n").encode())
    md = write_text(
        out_dir / "tradeoff.md", tradeoff_markdown(table, df, f"Speed/accuracy trade-off ({runs_root.name})")
    )
    png = pareto_figure(table, out_dir / "pareto.png", f"{runs_root.name}: cost vs fidelity")
    return [csv, md, png]
