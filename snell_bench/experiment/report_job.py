"""The errors a job raises (:class:`JobError`, :class:`CellsFailed`) and the report step of
``job=report`` and of a grid's end (:func:`write_report`, :func:`grid_report`): a report the
operating system refuses to write (a full disk, a folder without write permission) is one line
naming the folder, the system's reason and the fix: ``job=report`` raises it as
:class:`ReportNotWritten` (exit status 1); a grid logs it as an error and keeps the exit status its
cells decided."""

from __future__ import annotations

import errno
import logging
from pathlib import Path

from hydra.errors import CompactHydraException

__all__ = ["CellsFailed", "JobError", "ReportNotWritten", "grid_report", "write_report"]

log = logging.getLogger(__name__)


class JobError(CompactHydraException):
    """A job cannot do what it was asked (nothing to report, cells of other settings): the message
    says what to run. Hydra prints a ``CompactHydraException`` as its message alone."""


class CellsFailed(CompactHydraException):
    """Cells of a sweep failed (their records and the report say why): raised by a job of a
    multirun, so that Hydra runs every other job first and then exits non-zero."""


class ReportNotWritten(JobError):
    """The operating system refused to write the report (or to read a record): the message names
    the folder and the file, the system's reason and the fix (:func:`write_report`)."""


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _report_os_problem(e: OSError, root: Path, out: Path) -> str:
    """One line for an ``OSError`` while building the report of ``root`` into ``out``."""
    reason = e.strerror or str(e) or type(e).__name__
    path = Path(e.filename).absolute() if e.filename else None
    out_abs, root_abs = out.absolute(), root.absolute()
    if path is not None and _inside(path, root_abs) and not _inside(path, out_abs):
        return f"cannot read {e.filename}: {reason}; make the cell records under {root} readable"
    if path is None or path == out_abs:
        where = f"the report folder {out}"
    else:
        inner = path.relative_to(out_abs) if _inside(path, out_abs) else e.filename
        where = f"the report folder {out} ({inner})"
    if e.errno in (errno.ENOSPC, errno.EDQUOT):
        fix = "free space on its disk, or set reports_dir=<a folder on another disk>"
    elif e.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        fix = f"make {out.parent} writable, or set reports_dir=<a folder you can write>"
    else:
        fix = "set reports_dir=<another folder>"
    return f"cannot write {where}: {reason}; {fix}"


def write_report(root: Path, out: Path, name: str) -> list[Path]:
    """Build the report of the cells under ``root`` into ``out``
    (:func:`~snell_bench.reports.build_reports`) and print its summary line.

    Args:
        root: the experiment's runs folder (``runs_dir/experiment_name``).
        out: its report folder (``reports_dir/experiment_name``).
        name: ``experiment_name``.

    Returns:
        The files written.

    Raises:
        snell_bench.reports.NoCells: no cell records under ``root``.
        ReportNotWritten: an ``OSError`` while writing the report or reading a record; one line
            naming the folder, the file, the system's reason and the fix.
    """
    from snell_bench.reports import build_reports, summary_line

    try:
        paths = build_reports(root, out, name)
    except OSError as e:
        raise ReportNotWritten(_report_os_problem(e, root, out)) from e
    print(summary_line(out, paths))
    return paths


def grid_report(root: Path, out: Path, name: str) -> list[str]:
    """The report at the end of a grid (:func:`write_report`); one that cannot be written is one
    ERROR line (the grid's exit status stays the one its cells decided).

    Returns:
        The files written, as strings; ``[]`` when the report could not be written.
    """
    try:
        return [str(p) for p in write_report(root, out, name)]
    except ReportNotWritten as e:
        log.error("report: %s; then build it with job=report experiment_name=%s", e, name)
        return []
