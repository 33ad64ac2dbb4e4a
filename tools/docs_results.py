"""Snapshot the report tables that the documentation shows, and the README's picture.

The result pages of the documentation show the tables of ``reports/<experiment>/``, which a fresh
checkout does not have (``reports/*/`` is git-ignored). This script copies the tables of the listed
experiments (every ``<table>.csv``, full precision, the home folder in its notes written as ``~``)
into committed snapshots, ``docs/results/data/<experiment>/``, with a ``report.json`` that keeps
each table's title, provenance line (model, scene source, recipe, metrics protocol, cell counts),
caption and notes from the report's Markdown. The MkDocs hook (``tools/docs_hooks.py``) renders the
pages' tables from these snapshots, so no number on a result page is typed by hand.

For the speed/accuracy sweep it also writes ``tradeoff_settings.csv``: the per-setting means the
report's ``tradeoff.md`` shows, computed by the report's own
:func:`snell_bench.reports.tradeoff_table` from ``tradeoff.csv``.

Usage (``make docs-results``)::

    python tools/docs_results.py                 # every experiment of EXPERIMENTS that has a report
    python tools/docs_results.py smoke photo     # only these
    python tools/docs_results.py --reports other/reports --out docs/results/data

An experiment without a report is left as it is (its snapshot, if any, stays) and listed; the pages
then say that the snapshot is missing and how to make it. The smoke report's first qualitative page
also becomes ``docs/assets/smoke.png`` (the README's picture, at most 960 pixels wide, 256 colours).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

__all__ = ["EXPERIMENTS", "main", "read_report_markdown", "smoke_picture", "snapshot", "tradeoff_means"]

ROOT = Path(__file__).resolve().parents[1]

#: The experiments whose tables the documentation shows: name -> the command that makes its report
#: (``reports/<name>/``) and the page that shows it.
EXPERIMENTS: dict[str, dict[str, str]] = {
    "smoke": {"command": "python -m snell_bench +experiment=smoke", "page": "results.md"},
    "ablation": {"command": "python -m snell_bench +experiment=ablation", "page": "results.md"},
    "ablation_mixture": {
        "command": "python -m snell_bench +experiment=ablation model=mixture experiment_name=ablation_mixture",
        "page": "results.md",
    },
    "ablation_mixture_authors": {
        "command": "python -m snell_bench +experiment=ablation model=mixture recipe=authors "
        "experiment_name=ablation_mixture_authors",
        "page": "paper.md",
    },
    "ior_sweep": {"command": "python -m snell_bench +experiment=ior_sweep", "page": "results.md"},
    "time_travel": {"command": "python -m snell_bench +experiment=time_travel model=mixture", "page": "results.md"},
    "photo": {"command": "python -m snell_bench +experiment=photo", "page": "photo.md"},
    "tradeoff": {"command": "python -m snell_bench +experiment=tradeoff", "page": "presets.md"},
    "adaptive": {"command": "python -m snell_bench +experiment=adaptive", "page": "adaptive.md"},
    "extremes": {"command": "python -m snell_bench +experiment=extremes", "page": "extremes.md"},
}

#: Report CSVs that are not tables of the documentation (one row per cell).
SKIPPED_CSV = ("savings_per_cell.csv",)

#: The README's picture: at most this many pixels wide.
PICTURE_WIDTH = 960


def _private(text: str) -> str:
    """Report text with the home folder written as ``~`` (the reports' notes name local paths)."""
    return text.replace(str(Path.home()), "~")


def read_report_markdown(text: str) -> dict:
    """What a report's Markdown table says besides its numbers.

    Args:
        text: a ``<table>.md`` of a report (``## title``, an italic provenance line, the pipe table,
            a caption, ``### Notes``), or a speed/accuracy sweep's ``tradeoff.md``.

    Returns:
        ``title``, ``provenance``, ``caption`` and ``notes`` (a list), each empty where the text
        has none.

    Examples:
        >>> md = "## T (x)\\n\\n_model: analytic · 2 cells (2 ok)_\\n\\n| a |\\n|---|\\n| 1 |\\n\\n"
        >>> md += "Means over cells. **Bold**: best.\\n\\n### Notes\\n\\n- LPIPS: no weights\\n"
        >>> read_report_markdown(md)["provenance"], read_report_markdown(md)["notes"]
        ('model: analytic · 2 cells (2 ok)', ['LPIPS: no weights'])
    """
    lines = _private(text).splitlines()
    out = {"title": "", "provenance": "", "caption": "", "notes": []}
    in_notes, after_table = False, False
    for line in lines:
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            heading = s.lstrip("#").strip()
            in_notes = heading.lower() == "notes"
            if not out["title"] and not in_notes:
                out["title"] = heading
            continue
        if in_notes:
            if s.startswith("- "):
                out["notes"].append(s[2:].strip())
            continue
        if s.startswith("|"):
            after_table = True
            continue
        if not out["provenance"] and re.fullmatch(r"_(.+)_", s):
            out["provenance"] = s[1:-1].strip()
        elif not out["provenance"] and s.startswith("Means over the scenes"):
            out["provenance"] = s.split(" Times in seconds")[0].rstrip(".")
        elif after_table and not out["caption"]:
            out["caption"] = s.split("**Bold**")[0].strip()
    out["provenance"] = _unescape(out["provenance"])
    out["notes"] = [_unescape(n) for n in out["notes"]]
    return out


def _unescape(s: str) -> str:
    """Markdown text without the report writer's backslash escapes (the page escapes it again)."""
    return re.sub(r"\\([\\`*_\[\]<>|&~])", r"\1", s)


def tradeoff_means(raw):
    """The per-setting means of a speed/accuracy sweep, as its report's ``tradeoff.md`` shows them.

    Args:
        raw: ``reports/tradeoff/tradeoff.csv`` read with pandas (one row per scene and setting).

    Returns:
        One row per setting: ``setting``, ``axis``, the stage times, the PSNRs, LPIPS, the
        reference's self-noise, ``n`` (``"ok/scenes"``) and ``pareto`` (``"★"`` on the front).
    """
    from snell_bench.reports import tradeoff_table

    table = tradeoff_table(raw)
    out = table.drop(columns=[c for c in ("lpips_missing",) if c in table.columns]).copy()
    out["n"] = [f"{int(a)}/{int(b)}" for a, b in zip(table["n"], table["n_scenes"])]
    out["pareto"] = ["★" if p else "" for p in table["pareto"]]
    out = out.drop(columns=["n_scenes"])
    out.index.name = "setting"
    return out.reset_index()


def _provenance(readme: Path) -> str:
    """The provenance line of a report's ``README.md`` (what follows "Built from ... alone;")."""
    if not readme.is_file():
        return ""
    for line in readme.read_text(encoding="utf-8").splitlines():
        m = re.match(r"Built from .*? alone; (.*?)\.?$", line.strip())
        if m:
            return m.group(1)
    return ""


def snapshot(experiment: str, reports: Path, out: Path) -> list[Path] | None:
    """Copy one experiment's report tables into its snapshot folder.

    Args:
        experiment: the experiment's name (``reports/<experiment>/``).
        reports: the reports folder.
        out: the snapshots' folder (``docs/results/data``).

    Returns:
        The written files, or None where the experiment has no report (its snapshot is left).

    Raises:
        KeyError: ``experiment`` is not in :data:`EXPERIMENTS`.
    """
    command = EXPERIMENTS[experiment]["command"]
    src = reports / experiment
    csvs = sorted(p for p in src.glob("*.csv") if p.name not in SKIPPED_CSV) if src.is_dir() else []
    if not csvs:
        return None
    dst = out / experiment
    dst.mkdir(parents=True, exist_ok=True)
    keep, tables = {"report.json"}, {}
    for csv in csvs:
        (dst / csv.name).write_text(_private(csv.read_text(encoding="utf-8")), encoding="utf-8")
        keep.add(csv.name)
        md = csv.with_suffix(".md")
        tables[csv.stem] = read_report_markdown(md.read_text(encoding="utf-8")) if md.is_file() else {}
    if (src / "tradeoff.csv").is_file():
        import pandas as pd

        means = tradeoff_means(pd.read_csv(src / "tradeoff.csv"))
        means.to_csv(dst / "tradeoff_settings.csv", index=False, lineterminator="\n")
        keep.add("tradeoff_settings.csv")
        tables["tradeoff_settings"] = dict(tables.get("tradeoff", {}))
        tables["tradeoff_settings"]["caption"] = (
            "Means over the scenes where a setting succeeded; times in seconds, total = warps + sampling + "
            "reference + metrics per image; PSNR (conv.): against a converged reference of the same scene, "
            "object and resolution; Pareto: on the front of (total ↓, PSNR (conv.) ↑)."
        )
    meta = {
        "experiment": experiment,
        "command": command,
        "provenance": _provenance(src / "README.md") or tables.get("tradeoff", {}).get("provenance", ""),
        "tables": tables,
    }
    (dst / "report.json").write_text(json.dumps(meta, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    for stale in dst.iterdir():
        if stale.name not in keep:
            stale.unlink()
    return sorted(dst / name for name in keep)


def smoke_picture(reports: Path, out: Path, width: int = PICTURE_WIDTH) -> Path | None:
    """The README's picture: the smoke report's first qualitative page, at most ``width`` pixels wide.

    Args:
        reports: the reports folder.
        out: the PNG to write (``docs/assets/smoke.png``).
        width: the largest width in pixels.

    Returns:
        ``out``, or None where the smoke report has no ``qualitative_1.png``.
    """
    from PIL import Image

    src = reports / "smoke" / "qualitative_1.png"
    if not src.is_file():
        return None
    with Image.open(src) as im:
        im = im.convert("RGB")
        if im.width > width:
            im = im.resize((width, round(im.height * width / im.width)), Image.Resampling.LANCZOS)
        out.parent.mkdir(parents=True, exist_ok=True)
        im.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(out, optimize=True)
    return out


def main(argv: list[str] | None = None) -> int:
    """Snapshot the listed experiments' report tables (all of :data:`EXPERIMENTS` by default).

    Args:
        argv: the command line (``sys.argv[1:]`` by default).

    Returns:
        0; an unknown experiment name is an error (exit status 2) naming the known ones.
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("experiments", nargs="*", help=f"default: all of {', '.join(EXPERIMENTS)}")
    parser.add_argument("--reports", type=Path, default=ROOT / "reports", help="the reports folder")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "data", help="the snapshots' folder")
    parser.add_argument("--picture", type=Path, default=ROOT / "docs" / "assets" / "smoke.png", help="README picture")
    args = parser.parse_args(argv)
    unknown = [e for e in args.experiments if e not in EXPERIMENTS]
    if unknown:
        parser.error(f"unknown experiment(s) {unknown}; known: {', '.join(EXPERIMENTS)} (tools/docs_results.py)")
    for name in args.experiments or list(EXPERIMENTS):
        written = snapshot(name, args.reports, args.out)
        if written is None:
            print(f"{name}: no tables in {args.reports / name}/ (make them: {EXPERIMENTS[name]['command']})")
        else:
            print(f"{name}: {len(written)} files -> {args.out / name}/")
    if not args.experiments or "smoke" in args.experiments:
        picture = smoke_picture(args.reports, args.picture)
        if picture is None:
            print(f"picture: no {args.reports / 'smoke' / 'qualitative_1.png'}; {args.picture} left as it is")
        else:
            print(f"picture: {picture} ({picture.stat().st_size // 1024} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
