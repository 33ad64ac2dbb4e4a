"""Writing tables: Markdown (:meth:`pandas.DataFrame.to_markdown`, one pipe-table writer for every
report, the speed/accuracy part's included, :mod:`.tradeoff_text`), LaTeX (booktabs, through
:meth:`pandas.io.formats.style.Styler.to_latex`) and CSV (every CSV of the package through
:func:`csv_safe`, so that a spreadsheet reads no cell as a formula).

The Markdown and LaTeX versions of a table from :mod:`.tables` carry a provenance line (which model
and scene source produced the numbers, how many cells) and notes listing every failed or skipped
cell with its reason and every metric without a value in some averaged cells. The best value is
**bold** (``\\textbf``), the second best _italic_ (``\\underline``), as ranked by
:func:`~snell_bench.reports.ranking.rank_marks`; a missing value is "—".

Every string that comes from the cells (names, labels, reasons, the experiment's name) is escaped
for the format it goes into: :func:`~.text.md_escape` for Markdown (one line; ``|``, backticks,
``*``, ``[``, ``<``, ``&``... backslash-escaped, so that it reads back as written and never becomes
a table cell, a link, emphasis or HTML) and :func:`~.text.tex_escape` for LaTeX.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import pandas as pd
from pandas.api.types import is_object_dtype, is_string_dtype

from snell_bench.utils.io import write_text

from .ranking import column_metric, rank_marks
from .spec import MEASURES, MISSING, metric_spec
from .text import md_code, md_escape, tex_escape

__all__ = [
    "pipe_table",
    "to_markdown",
    "plain_markdown",
    "to_latex",
    "to_csv",
    "csv_safe",
    "rank_scope",
    "skipped_markdown",
]

_ALIGNS = (None, "left", "right", "center")


def pipe_table(
    header: Sequence[str], rows: Iterable[Sequence[str]], align: Sequence[str | None] | None = None
) -> list[str]:
    """A Markdown pipe table (:meth:`pandas.DataFrame.to_markdown`), one string per line.

    Cells are written as given (no number is parsed or reformatted), padded with spaces to their
    column's width; a column aligned None is not padded. A table without rows has no alignment
    colons (tabulate writes none there).

    Args:
        header: the column headers.
        rows: the cells of each row, already formatted and escaped (one line each).
        align: per column ``"left"``, ``"right"``, ``"center"`` or None (the renderer's default);
            None for all columns if not given.

    Returns:
        The header line, the alignment line and one line per row.

    Raises:
        KeyError: an unknown alignment.

    Examples:
        >>> print("\\n".join(pipe_table(["a", "b"], [["x", "1.50"], ["yy", "2"]], ["left", "right"])))
        | a   |    b |
        |:----|-----:|
        | x   | 1.50 |
        | yy  |    2 |
    """
    align = [None] * len(header) if align is None else list(align)
    for a in align:
        if a not in _ALIGNS:
            raise KeyError(a)
    frame = pd.DataFrame(list(rows), columns=range(len(header)), dtype=object)
    text = frame.to_markdown(index=False, headers=list(header), colalign=align, disable_numparse=True)
    return text.splitlines()


def _cell_text(table: pd.DataFrame, i: int, j: int) -> str:
    col = table.columns[j]
    v = table.iat[i, j]
    if col == "n":
        return MISSING if pd.isna(v) else str(int(v))
    spec = column_metric(table, col) or MEASURES.get(col) or metric_spec(str(col))
    return spec.fmt(None if pd.isna(v) else float(v))


def _header(table: pd.DataFrame, col) -> str:
    """A value column's header as text (not escaped: the writers escape it for their format)."""
    if col == "n":
        return "n"
    if col in MEASURES:
        return MEASURES[col].label
    spec = column_metric(table, col)
    if spec is not None and not table.attrs.get("metric"):
        return f"{spec.label} {spec.arrow}"
    return str(col)


def _index_header(table: pd.DataFrame) -> list[str]:
    """The row header(s): one per index level."""
    return [str(n or "") for n in table.index.names]


def _index_cells(table: pd.DataFrame) -> list[list[str]]:
    """The row labels, one cell per index level; within a block (rows sharing the leading levels)
    a repeated leading label is left blank."""
    rows, prev = [], None
    for key in table.index:
        key = list(key) if isinstance(key, tuple) else [key]
        cells = [str(k) for k in key]
        if prev is not None and len(key) > 1:
            for lvl in range(len(key) - 1):
                if key[: lvl + 1] != prev[: lvl + 1]:
                    break
                cells[lvl] = ""
        rows.append(cells)
        prev = key
    return rows


def _block_starts(table: pd.DataFrame) -> list[int]:
    """Row positions (after the first) where a block starts: any index level but the last changes."""
    if table.index.nlevels < 2:
        return []
    first = [k[:-1] for k in table.index]
    return [i for i in range(1, len(first)) if first[i] != first[i - 1]]


def rank_scope(table: pd.DataFrame) -> str:
    """Where best and second best are ranked, for a legend: ``"column"``, ``"scene"`` (scene
    tables) or ``"column within each <leading index levels>"`` (``"... within each IOR and scene"``)."""
    heads = _index_header(table)
    return {
        "rows": "scene",
        "blocks": "column within each "
        + (" and ".join(h if h == "IOR" else h.lower() for h in heads[:-1] if h) or "block"),
    }.get(table.attrs.get("highlight"), "column")


def _resolve(table: pd.DataFrame, provenance: str | None, notes: Sequence[str] | None) -> tuple[str, list[str]]:
    provenance = table.attrs.get("provenance", "") if provenance is None else provenance
    notes = list(table.attrs.get("notes", [])) if notes is None else list(notes)
    return provenance, notes


def _marked_cells(table: pd.DataFrame, mark) -> list[list[str]]:
    """The value cells as text, ``mark(text, rank)`` applied where :func:`rank_marks` ranks one."""
    ranks = rank_marks(table)
    return [
        [mark(_cell_text(table, i, j), ranks.get((i, j))) for j in range(len(table.columns))] for i in range(len(table))
    ]


def to_markdown(
    table: pd.DataFrame, title: str, provenance: str | None = None, notes: Sequence[str] | None = None
) -> str:
    """The table as Markdown.

    Args:
        table: a table of :mod:`.tables` (or any DataFrame of metric columns).
        title: the ``##`` heading.
        provenance: the line under the heading; default ``table.attrs["provenance"]``.
        notes: the "Notes" list; default ``table.attrs["notes"]``.

    Returns:
        A ``##`` heading, the provenance line, a pipe table (best value **bold**, second best
        _italic_, missing "—"), the caption with the legend, and a "Notes" section listing the
        failed and skipped cells with their reasons and the metrics missing in averaged cells;
        every text from the table (title, labels, provenance, notes) escaped (:func:`~.text.md_escape`).
    """
    provenance, notes = _resolve(table, provenance, notes)
    cols = list(table.columns)
    index_head = _index_header(table)
    head = [md_escape(h) for h in index_head + [_header(table, c) for c in cols]]
    cells = _marked_cells(table, lambda t, r: f"**{t}**" if r == 1 else f"_{t}_" if r == 2 else t)
    lines = [f"## {md_escape(title)}", "", f"_{md_escape(provenance)}_" if provenance else "", ""]
    lines += pipe_table(
        head,
        ([md_escape(k) for k in idx] + row for idx, row in zip(_index_cells(table), cells)),
        ["left"] * len(index_head) + ["right"] * len(cols),
    )
    lines.append("")
    caption = table.attrs.get("caption")
    where = rank_scope(table)
    lines.append(
        (md_escape(caption) + " " if caption else "")
        + f"**Bold**: best per {md_escape(where)}; _italic_: second best; {MISSING}: no value."
    )
    lines += ["", "### Notes", ""]
    lines += (
        [f"- {md_escape(n)}" for n in notes]
        if notes
        else ["- All cells ok; every metric shown has a value in every cell."]
    )
    return "\n".join(lines) + "\n"


def plain_markdown(table: pd.DataFrame, title: str, note: str = "") -> str:
    """Any DataFrame as Markdown, without ranking.

    Args:
        table: the rows to write (the index is not written).
        title: the ``##`` heading.
        note: a paragraph under the heading.

    Returns:
        The heading, the note and a pipe table: floats with 3 decimals ("—" if not finite),
        everything else as ``str``, escaped (:func:`~.text.md_escape`), as are the title and the note.
    """

    def fmt(v):
        if isinstance(v, (float, np.floating)):
            return MISSING if not np.isfinite(v) else f"{v:.3f}"
        return md_escape(v)

    lines = [f"## {md_escape(title)}", ""] + ([md_escape(note), ""] if note else [])
    lines += pipe_table(
        [md_escape(c) for c in table.columns], ([fmt(v) for v in row] for row in table.itertuples(index=False))
    )
    return "\n".join(lines) + "\n"


_LATEX_MARKS = {1: "textbf: --rwrap;", 2: "underline: --rwrap;"}


def to_latex(
    table: pd.DataFrame,
    title: str,
    provenance: str | None = None,
    notes: Sequence[str] | None = None,
    label: str | None = None,
) -> str:
    """The table as a LaTeX ``table`` float (booktabs).

    Args:
        table: a table of :mod:`.tables` (or any DataFrame of metric columns).
        title: the caption's first sentence.
        provenance: appended to the caption; default ``table.attrs["provenance"]``.
        notes: written under the tabular in ``\\footnotesize``; default ``table.attrs["notes"]``.
        label: the ``\\label``, if any.

    Returns:
        The float: the caption is ``title`` and the provenance line, one left-aligned column per
        index level (a ``\\midrule`` between blocks of a two-level index), the best value per
        column (per scene for scene tables, per column within a block for block tables) is in
        ``\\textbf{}``, the second best in ``\\underline{}`` (ties
        share the mark), missing values are "—" (UTF-8, the LaTeX default input encoding), and the
        notes (failed and skipped cells, missing metrics) follow the tabular.
    """
    provenance, notes = _resolve(table, provenance, notes)
    cols = list(table.columns)
    caption = tex_escape(title.rstrip("."))
    if provenance:
        caption += ". " + tex_escape(provenance)
    index_head = _index_header(table)
    nidx = len(index_head)
    header = [tex_escape(h) for h in index_head] + [tex_escape(_header(table, c)) if c != "n" else "$n$" for c in cols]
    ranks = rank_marks(table)
    # positional labels: the Styler needs unique ones, the header text comes from format_index
    text = pd.DataFrame(
        [
            [tex_escape(k) for k in idx] + [_cell_text(table, i, j) for j in range(len(cols))]
            for i, idx in enumerate(_index_cells(table))
        ],
        columns=range(len(header)),
    )
    marks = pd.DataFrame("", index=text.index, columns=text.columns)
    for (i, j), r in ranks.items():
        marks.iat[i, j + nidx] = _LATEX_MARKS[r]
    styler = text.style.hide(axis="index").format_index(lambda k: header[k], axis=1)
    styler = styler.apply(lambda _: marks, axis=None)
    tex = styler.to_latex(
        environment="table",
        position="t",
        position_float="centering",
        caption=caption + ".",
        label=label,
        hrules=True,
        column_format="l" * nidx + "r" * len(cols),
    )
    starts = _block_starts(table)
    if starts:  # a rule between blocks
        head, sep, rest = tex.partition("\\midrule\n")
        body, sep2, tail = rest.partition("\\bottomrule")
        rows = body.splitlines(keepends=True)
        for i in reversed(starts):
            rows.insert(i, "\\midrule\n")
        tex = head + sep + "".join(rows) + sep2 + tail
    if notes:
        end = "\\end{table}\n"
        block = "\n".join([r"\par\smallskip{\footnotesize"] + [tex_escape(n) + r"\\" for n in notes] + ["}"])
        tex = tex.removesuffix(end) + block + "\n" + end
    return tex


#: What a spreadsheet reads as the start of a formula (OWASP, "CSV Injection").
_FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def _defused(value: Any) -> Any:
    """``value`` with a ``'`` in front if it is a string that starts like a formula, else as it is;
    a carriage return inside a string becomes a line feed (which the CSV writer quotes; a bare CR it
    does not, and a spreadsheet would start a new row, and a formula, after it)."""
    if not isinstance(value, str):
        return value
    if "\r" in value[1:]:
        value = value[0] + value[1:].replace("\r\n", "\n").replace("\r", "\n")
    return "'" + value if value.startswith(_FORMULA_STARTS) else value


def _is_text(dtype: Any) -> bool:
    """Whether a column or index of this dtype holds strings (object, string or categorical)."""
    return is_object_dtype(dtype) or is_string_dtype(dtype) or isinstance(dtype, pd.CategoricalDtype)


def _defused_labels(labels: pd.Index) -> pd.Index:
    """An index or the column labels, with every string label and name :func:`_defused`."""
    if isinstance(labels, pd.MultiIndex):
        levels = [_defused_labels(labels.get_level_values(i)) for i in range(labels.nlevels)]
        return pd.MultiIndex.from_arrays(levels, names=[_defused(n) for n in labels.names])
    out = labels.map(_defused) if _is_text(labels.dtype) else labels
    return out.rename(_defused(labels.name))


def csv_safe(table: pd.DataFrame) -> pd.DataFrame:
    """A copy of ``table`` that a spreadsheet opens without evaluating any cell as a formula.

    The rule of OWASP's "CSV Injection" (https://owasp.org/www-community/attacks/CSV_Injection):
    every string that begins with ``=``, ``+``, ``-``, ``@``, a tab or a carriage return gets a
    single quote ``'`` in front, so that ``=2+5+cmd|' /C calc'!A0`` is written as
    ``'=2+5+cmd|' /C calc'!A0`` and shown as text. That holds for the cells, the index and the
    column labels (and their names). Numbers are left as they are (a negative number is a number,
    not a formula): only the values of object, string and categorical columns are changed, and of
    those only the strings.

    Args:
        table: any DataFrame; it is not changed.

    Returns:
        The neutralised copy, to write with :meth:`pandas.DataFrame.to_csv`.
    """
    out = table.copy()
    for i in range(out.shape[1]):  # by position: column labels may repeat
        column = out.iloc[:, i]
        if _is_text(column.dtype):
            out.isetitem(i, column.astype(object).map(_defused))
    out.index = _defused_labels(out.index)
    out.columns = _defused_labels(out.columns)
    return out


def to_csv(table: pd.DataFrame, path: str | os.PathLike | None = None) -> str:
    """The table's numbers as CSV: index first, NaN as an empty field, full precision; every string
    that starts like a formula with a ``'`` in front (:func:`csv_safe`).

    Args:
        table: any DataFrame.
        path: where to write it (atomically), if given; ``pandas.read_csv(path, index_col=0)``
            reads it back.

    Returns:
        The CSV text.
    """
    text = csv_safe(table).to_csv(index=True, float_format=None, lineterminator="\n")
    if path is not None:
        write_text(path, text)
    return text


# --------------------------------------------------------------------------------------------
# Speed/accuracy sweeps
# --------------------------------------------------------------------------------------------


def skipped_markdown(skipped: Sequence[tuple[str, str]], level: str = "##") -> list[str]:
    """The "Files skipped" section of a report's Markdown: every record file left out (not a cell
    record, :func:`~.records.load_record`) with what is wrong with it.

    Args:
        skipped: ``(path relative to the run folder, problem)`` pairs (:func:`~.collect.skipped_files`).
        level: the heading's ``#`` marks.

    Returns:
        The section's lines (a blank line first), none when nothing was skipped.
    """
    if not skipped:
        return []
    n = len(skipped)
    lines = [
        "",
        f"{level} Files skipped",
        "",
        f"{n} record file{'s are' if n != 1 else ' is'} not a cell record and left out of every table and figure:",
        "",
    ]
    return lines + [f"- {md_code(path)}: {md_escape(problem)}" for path, problem in skipped]
