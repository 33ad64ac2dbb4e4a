"""Every report of a run folder at once: a grid experiment's tables, figures, HTML page and README,
or a speed/accuracy sweep's CSV, Markdown, Pareto plot and HTML page. Every file is written
atomically.

A build returns the paths it wrote as :class:`Written`, which also lists the record files it left
out (not cell records: their "files skipped" section, :func:`~.collect.skipped_files`);
:func:`summary_line` says both in one line. A run folder without any cell record raises
:class:`NoCells`."""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from snell_bench.utils.io import atomic_write_bytes, write_text
from snell_bench.utils.locks import hold

from .collect import collect, skipped_files
from .figures import figure_rows, method_columns, panorama_pages, qualitative_figure, qualitative_pages
from .gallery import gallery
from .html import PAGE, frame_view, table_view, tradeoff_view, write_grid_page, write_tradeoff_page
from .plots import axis_plots, pareto_plot, tradeoff_axis_plot
from .spec import ABLATION_METRICS, ABLATION_ROWS, ABLATION_TABLE2_METRICS, SCENE_METRICS, TABLE1_METRICS
from .sweep_figures import pareto_figure, time_travel_figure
from .tables import (
    SAVING_METHODS,
    TIME_TRAVEL_METRICS,
    ablation_table,
    block_table,
    method_labels,
    method_table,
    provenance_line,
    savings_table,
    swept_axes,
    time_travel_table,
    with_recorded_metrics,
)
from .text import md_code, md_escape, slug
from .tradeoff import collect_tradeoff, tradeoff_table
from .tradeoff_text import tradeoff_markdown, tradeoff_notes, tradeoff_summary
from .writers import (
    csv_safe,
    plain_markdown,
    skipped_markdown,
    to_csv,
    to_latex,
    to_markdown,
)

__all__ = ["build_reports", "NoCells", "Written", "summary_line"]


class NoCells(FileNotFoundError):
    """A run folder holds no cell record to report (or does not exist)."""


class Written(list):
    """The paths a build wrote, in order (a ``list``), and ``skipped``: the record files it left
    out, as ``(path relative to the run folder, problem)`` (:func:`~.collect.skipped_files`)."""

    def __init__(self, paths=(), skipped=()) -> None:
        super().__init__(paths)
        self.skipped = [tuple(x) for x in skipped]


def summary_line(out_dir: str | os.PathLike, written: Sequence[Path]) -> str:
    """The line printed after a build: where the report is, how many files, and the record files
    left out.

    Args:
        out_dir: the report folder.
        written: what the build returned (:class:`Written`; a plain list has nothing skipped).

    Returns:
        E.g. ``"reports: reports/x (12 files); open reports/x/index.html; 2 record files skipped
        (not cell records): see reports/x/README.md"``.
    """
    out_dir = Path(out_dir)
    line = f"reports: {out_dir} ({len(written)} files); open {out_dir / PAGE}"
    n = len(getattr(written, "skipped", ()))
    if n:
        where = "README.md"
        line += f"; {n} record file{'s' if n != 1 else ''} skipped (not cell records): see {out_dir / where}"
    return line


def _no_cells(run_dir: Path, record: str, skipped: list) -> NoCells:
    """The error of a run folder with nothing to report."""
    if not run_dir.is_dir():
        return NoCells(f"{run_dir} does not exist")
    why = f"no {record} below {run_dir}"
    if skipped:
        path, problem = skipped[0]
        more = f" (and {len(skipped) - 1} more)" if len(skipped) > 1 else ""
        why += f" that is a cell record: {len(skipped)} skipped, e.g. {path}: {problem}{more}"
    return NoCells(why)


_SAVINGS_NOTE = (
    "Time = warps + sampling per cell, against Snellcaster on the same scene and object; "
    "ΔPSNR = method − Snellcaster (masked, against the reference)."
)


def _is_ior_sweep(df) -> bool:
    """Whether the cells hold one object at two or more IORs (``name:ior`` objects)."""
    return "IOR" in swept_axes(df)


def _remove_stale_images(folder: Path, keep: list[Path]) -> None:
    """Remove the files of ``images/`` that this build did not write (cells removed since)."""
    if not folder.is_dir():
        return
    kept = {p.resolve() for p in keep}
    for path in folder.iterdir():
        if path.is_file() and path.resolve() not in kept:
            path.unlink()


def build_reports(
    run_dir: str | os.PathLike, out_dir: str | os.PathLike, experiment_name: str, *, max_rows: int = 4
) -> list[Path]:
    """Write every table and figure of one experiment from its run directory alone.

    Tables (each as ``.md``, ``.tex`` and ``.csv``; every column of the paper's table is shown,
    a metric without a value in any cell as "—" with its recorded reason in the notes; the
    recorded optional metrics, :func:`~snell_bench.reports.tables.with_recorded_metrics`,
    follow):

    - ``method_table``: Table 1, methods x (CLIP, ImageReward, PSNR, LPIPS);
    - ``scene_table``: Table 3, one block per scene, a row per method, the same columns;
    - ``ablation_table`` (Table 2: MAE, PSNR, LPIPS) and ``ablation_table_all`` (Table 4: MAE,
      PSNR, LPIPS, CLIP, ImageReward), when the runs contain an ablation variant (a method of
      :data:`ABLATION_ROWS` other than ``snellcaster``);
    - ``ior_table``, one block per IOR, when one object ran at two or more IORs;
    - ``time_travel_table``, one block per variant, a row per R_main, when time-travel methods ran;
    - ``savings.md``, ``savings.csv`` and ``savings_per_cell.csv`` when ``full_frame`` or
      ``adaptive`` ran beside ``snellcaster``.

    Figures: ``qualitative_1.png``, ``qualitative_2.png``, ... (reference | methods, ``max_rows``
    rows a page, every row); ``panorama_1.png``, ... (main image beside its panorama, every cell
    with a ``panorama.png``); ``ior.png`` (every IOR row on one page) and ``time_travel.png``
    (PSNR and LPIPS against R_main) with their tables.

    ``index.html`` (:mod:`.html`): every table above, sortable, with its notes; a plot per swept
    axis; the gallery of every group of cells with thumbnails under ``images/`` and the |error|
    maps; the missing values with their reasons; ``plotly.min.js`` beside it when it has a plot.
    ``README.md`` links everything with the provenance line (model, scene source, recipe, metrics
    protocol, cell counts).

    Args:
        run_dir: the experiment's run directory.
        out_dir: where to write (created if needed).
        experiment_name: shown in titles and LaTeX labels.
        max_rows: rows per page of the paged figures.

    Returns:
        The written paths (``index.html`` and the images included).

    Record files that are not cell records are left out and listed (with what is wrong) in the
    README's and the page's "Files skipped" sections, and counted in the provenance line.

    Raises:
        NoCells: there is no cell below ``run_dir`` (or no ``run_dir``); a ``FileNotFoundError``.
    """
    run_dir, out_dir = Path(run_dir), Path(out_dir)
    df = collect(run_dir)
    if df.empty:
        raise _no_cells(run_dir, "metrics.json", skipped_files(df))
    out_dir.mkdir(parents=True, exist_ok=True)
    with hold(out_dir):  # the shards of a grid that finish together write one report in turn
        return Written(_write_reports(df, run_dir, out_dir, experiment_name, max_rows), skipped_files(df))


def _grid_tables(df: pd.DataFrame, name: str, ior: bool) -> list[tuple[str, str, pd.DataFrame]]:
    """The tables of :func:`build_reports`, ``(file stem, title, table)`` each, in order."""
    tables = [
        ("method_table", f"Table 1: methods ({name})", method_table(df, with_recorded_metrics(df, TABLE1_METRICS))),
        ("scene_table", f"Table 3: per scene ({name})", block_table(df, with_recorded_metrics(df, SCENE_METRICS))),
    ]
    if df["method"].isin([m for m, _ in ABLATION_ROWS[1:]]).any():
        tables += [
            (
                "ablation_table",
                f"Table 2: ablation ({name})",
                ablation_table(df, with_recorded_metrics(df, ABLATION_TABLE2_METRICS)),
            ),
            (
                "ablation_table_all",
                f"Table 4: ablation, every metric ({name})",
                ablation_table(df, with_recorded_metrics(df, ABLATION_METRICS)),
            ),
        ]
    if ior:
        tables.append(
            (
                "ior_table",
                f"Index of refraction ({name})",
                block_table(
                    df, with_recorded_metrics(df, ("psnr", "lpips", "mae", "clip", "image_reward")), by="object"
                ),
            )
        )
    tt = time_travel_table(df, with_recorded_metrics(df, TIME_TRAVEL_METRICS))
    if len(tt):
        tables.append(("time_travel_table", f"Time travel ({name})", tt))
    return tables


def _write_reports(df, run_dir: Path, out_dir: Path, name: str, max_rows: int) -> list[Path]:
    """The body of :func:`build_reports`, while it holds ``out_dir``."""
    ior = _is_ior_sweep(df)
    tables = _grid_tables(df, name, ior)
    tt = {stem: t for stem, _, t in tables}.get("time_travel_table")
    written: list[Path] = []
    for stem, title, table in tables:
        md, tex, csv = (out_dir / f"{stem}.{ext}" for ext in ("md", "tex", "csv"))
        write_text(md, to_markdown(table, title))
        write_text(tex, to_latex(table, title, label=f"tab:{slug(name, '_') or 'exp'}_{stem}"))
        to_csv(table, csv)
        written += [md, tex, csv]
    savings = None
    if df["method"].isin(SAVING_METHODS).any() and (df["method"] == "snellcaster").any():
        summary, per_cell = savings_table(df)
        if not summary.empty:
            title = f"Time saved against fidelity lost ({name})"
            write_text(out_dir / "savings.md", plain_markdown(summary, title, _SAVINGS_NOTE))
            write_text(out_dir / "savings.csv", csv_safe(summary).to_csv(index=False))
            write_text(out_dir / "savings_per_cell.csv", csv_safe(per_cell).to_csv(index=False))
            written += [out_dir / "savings.md", out_dir / "savings.csv", out_dir / "savings_per_cell.csv"]
            savings = summary
    _remove_stale_pages(out_dir, ("qualitative", "panorama"))
    qualitative = qualitative_pages(run_dir, out_dir, "qualitative", max_rows=max_rows, df=df)
    shown = df[df["method"].astype(str).isin(method_columns(df))]  # of a sweep: its baseline and presets
    panoramas = panorama_pages(run_dir, out_dir, "panorama", max_rows=max_rows, df=shown)
    written += qualitative + panoramas
    figures = []
    if ior:
        rows = figure_rows(df, by_ior=True)
        figures.append(("Every IOR", qualitative_figure(run_dir, out_dir / "ior.png", cells=rows, df=df)))
    if tt is not None:
        figures.append(
            (
                "PSNR and LPIPS against R_main",
                time_travel_figure(tt, out_dir / "time_travel.png", f"Time travel ({name})"),
            )
        )
    written += [p for _, p in figures]
    sweep = collect_tradeoff(run_dir)  # the cells of named override sets (grid.axes): the speed/accuracy part
    src = Path(os.path.relpath(run_dir.resolve(), out_dir.resolve())).as_posix()
    pages = qualitative + panoramas
    written += _write_page(df, run_dir, out_dir, name, src, tables, savings, pages, figures, ior, not sweep.empty)
    if not sweep.empty:  # after the grid's page, which removes Plotly's script when it has no plot
        written += _write_tradeoff_report(sweep, run_dir, out_dir)
    written.append(_write_readme(df, out_dir, name, src, tables, savings, qualitative, panoramas, figures, max_rows))
    return written


def _write_readme(df, out_dir, name, src, tables, savings, qualitative, panoramas, figures, max_rows) -> Path:
    """``README.md`` of :func:`build_reports`: every file linked, with the provenance line."""
    lines = [
        f"# Reports: {md_escape(name)}",
        "",
        f"Built from the cells under {md_code(src)} alone; {md_escape(provenance_line(df))}.",
        "",
        f"- The report as one page, to open in a browser (sortable tables, every image with its |error| map, "
        f"plots of the swept axes): [{PAGE}]({PAGE})",
    ]
    for stem, title, _ in tables:
        lines.append(
            f"- {md_escape(title)}: [{stem}.md]({stem}.md) · [{stem}.tex]({stem}.tex) · [{stem}.csv]({stem}.csv)"
        )
    if savings is not None:
        lines.append(
            "- Time saved against fidelity lost: [savings.md](savings.md) · [savings.csv](savings.csv) · "
            "[savings_per_cell.csv](savings_per_cell.csv)"
        )
    links = " · ".join(f"[{p.name}]({p.name})" for p in qualitative)
    lines.append(f"- Qualitative comparison, {max_rows} rows a page: {links}")
    if panoramas:
        links = " · ".join(f"[{p.name}]({p.name})" for p in panoramas)
        lines.append(f"- Main image and its panorama: {links}")
    else:
        lines.append("- Main image and its panorama: no cell has a panorama.png")
    for title, path in figures:
        lines.append(f"- {title}: [{path.name}]({path.name})")
    if (out_dir / "tradeoff.md").is_file() and (out_dir / "tradeoff.html").is_file():
        lines.append(
            "- Speed/accuracy trade-off (per setting, Pareto front): [tradeoff.html](tradeoff.html) · "
            "[tradeoff.md](tradeoff.md) · [tradeoff.csv](tradeoff.csv) · [pareto.png](pareto.png)"
        )
    lines += ["", to_markdown(tables[0][2], tables[0][1])]
    lines += [f"![qualitative comparison]({qualitative[0].name})", ""] if qualitative else []
    lines += skipped_markdown(skipped_files(df), "##")
    return write_text(out_dir / "README.md", "\n".join(lines))


def _write_page(
    df: pd.DataFrame,
    run_dir: Path,
    out_dir: Path,
    name: str,
    src: str,
    tables: list[tuple[str, str, pd.DataFrame]],
    savings: pd.DataFrame | None,
    pages: list[Path],
    figures: list[tuple[str, Path]],
    ior: bool,
    sweep: bool = False,
) -> list[Path]:
    """``index.html`` of :func:`build_reports` (:func:`~.html.write_grid_page`) with its images:
    the tables as written beside it, the figure pages and figures linked; the paths written."""
    views = [table_view(t, title, stem, df, [f"{stem}.{e}" for e in ("md", "tex", "csv")]) for stem, title, t in tables]
    saving_files = ["savings.md", "savings.csv", "savings_per_cell.csv"]
    if savings is not None:
        labels = {v: k for k, v in method_labels(df).items()}
        views.append(
            frame_view(
                savings,
                f"Time saved against fidelity lost ({name})",
                "savings",
                note=_SAVINGS_NOTE,
                files=saving_files,
                methods=labels,
            )
        )
    shown = gallery(df, run_dir, out_dir, by_ior=ior)
    _remove_stale_images(out_dir / "images", shown.files)
    files = [(title, f"{stem}.{e}") for stem, title, _ in tables for e in ("md", "tex", "csv")]
    files += [("Time saved against fidelity lost", f) for f in saving_files] if savings is not None else []
    files += [(p.stem.replace("_", ", page ").capitalize(), p.name) for p in pages]
    files += [(title, p.name) for title, p in figures] + [("Reports in Markdown", "README.md")]
    files += [("Speed/accuracy trade-off", "tradeoff.html")] if sweep else []
    page = write_grid_page(
        out_dir,
        name=name,
        source=src,
        provenance=provenance_line(df),
        tables=views,
        plots=axis_plots(tables),
        gallery=shown,
        df=df,
        files=files,
        skipped=skipped_files(df),
    )
    return shown.files + page


def _remove_stale_pages(out_dir: Path, stems: tuple[str, ...]) -> None:
    """Remove the pages of an earlier build (``<stem>_<k>.png``), which may have had more pages."""
    for stem in stems:
        for path in out_dir.glob(f"{stem}_*.png"):
            if re.fullmatch(rf"{re.escape(stem)}_\d+\.png", path.name):
                path.unlink()


def _write_tradeoff_report(df, runs_root: Path, out_dir: Path) -> list[Path]:
    """The speed/accuracy part of a report whose cells hold settings (``grid.axes``):
    ``tradeoff.csv`` (one row per cell of a setting), ``tradeoff.md`` (per setting, means over the
    groups where it succeeded), ``pareto.png`` and ``tradeoff.html`` (the per-setting table,
    sortable; fidelity against each setting and the Pareto plot, with Plotly)."""
    table = tradeoff_table(df)
    csv = out_dir / "tradeoff.csv"
    atomic_write_bytes(csv, csv_safe(df).to_csv(index=False, lineterminator="\n").encode())
    md = write_text(
        out_dir / "tradeoff.md", tradeoff_markdown(table, df, f"Speed/accuracy trade-off ({runs_root.name})")
    )
    png = pareto_figure(table, out_dir / "pareto.png", f"{runs_root.name}: cost vs fidelity")
    plots = [p for p in (tradeoff_axis_plot(table, df), pareto_plot(table)) if p is not None]
    page = write_tradeoff_page(
        out_dir,
        title=f"Speed/accuracy trade-off ({runs_root.name})",
        summary=tradeoff_summary(table, df),
        table=tradeoff_view(table, ["tradeoff.md", "tradeoff.csv"]),
        plots=plots,
        notes=tradeoff_notes(df),
        skipped=skipped_files(df),
        files=[
            ("Per scene and setting", "tradeoff.csv"),
            ("Per setting", "tradeoff.md"),
            ("Pareto plot", "pareto.png"),
            ("Every cell: the grid's report", PAGE),
        ],
    )
    return [csv, md, png, *page]
