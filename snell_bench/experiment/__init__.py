"""Jobs run by ``python -m snell_bench``: the refraction preview, generation, the experiment grid
(the speed/accuracy sweep is one), the report, the plan of a grid (what it will do here, before doing it),
its status across the jobs working on it, and the benchmark kit of its groups (``job=export``).

:func:`run_job` returns the job's exit status: 0, or 3 when cells of a sweep failed (unless
``grid.allow_failures``; :data:`~.cells.CELLS_FAILED_EXIT`). A job
that cannot do what it was asked raises :class:`JobError`, one line saying what to run instead;
:class:`CellsFailed` is what a job of a multirun raises for its failed cells
(:mod:`snell_bench.__main__` turns both into the process's exit status).

The report (:func:`write_report`, by ``job=report`` and at the end of a grid) that the operating
system refuses to write (a full disk, a folder without write permission) is one line naming the
folder, the system's reason and the fix: ``job=report`` raises it as :class:`ReportNotWritten`
(exit status 1); a grid logs it as an error and keeps the exit status its cells decided."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from snell_bench.config import Job, check_config
from snell_bench.config.preflight import check_output_folders, nothing_to_report
from snell_bench.experiment.report_job import CellsFailed, JobError, ReportNotWritten, grid_report, write_report

__all__ = [
    "run_job",
    "JOBS",
    "JobError",
    "CellsFailed",
    "ReportNotWritten",
    "grid_report",
    "nothing_to_report",
    "write_report",
]


def _preview(cfg: DictConfig) -> None:
    from snell_bench.experiment.memory import check_memory
    from snell_bench.experiment.preview import run_preview

    check_memory([cfg])
    run_preview(cfg)


def _generate(cfg: DictConfig) -> None:
    from snell_bench.experiment.generate import run_generate
    from snell_bench.experiment.memory import check_memory

    check_memory([cfg])
    run_generate(cfg)


def _grid(cfg: DictConfig) -> int:
    from snell_bench.experiment.runner import run_grid

    return int(run_grid(cfg)["exit_status"])


def _report(cfg: DictConfig) -> None:
    from snell_bench.reports import NoCells

    name = cfg.experiment_name
    out = Path(cfg.reports_dir) / name
    root = Path(cfg.runs_dir) / name
    try:
        from snell_bench.experiment.runner import check_same_settings

        try:
            check_same_settings(root)
        except ValueError as e:  # cells of other settings: the message says what to run
            raise JobError(f"job=report: {e}") from None
        write_report(root, out, name)
    except NoCells as e:
        raise JobError(nothing_to_report(cfg.runs_dir, name, str(e))) from None
    except ReportNotWritten as e:
        raise ReportNotWritten(f"job=report: {e}") from e.__cause__


def _plan(cfg: DictConfig) -> None:
    from snell_bench.experiment.estimate import run_plan

    run_plan(cfg)


def _status(cfg: DictConfig) -> None:
    from snell_bench.experiment.status import run_status

    run_status(cfg)


def _export(cfg: DictConfig) -> int:
    from snell_bench.experiment.export import run_export

    return int(run_export(cfg)["exit_status"])


def _relight(cfg: DictConfig) -> int:
    from snell_bench.experiment.relighting import run_relighting

    return run_relighting(cfg)


JOBS = {
    Job.preview: _preview,
    Job.generate: _generate,
    Job.grid: _grid,
    Job.report: _report,
    Job.plan: _plan,
    Job.status: _status,
    Job.export: _export,
    Job.relight: _relight,
}


def run_job(cfg: DictConfig) -> int:
    """Run ``cfg.job`` (:data:`JOBS`) after checking every key and value of ``cfg``
    (:func:`snell_bench.config.check_config`).

    Args:
        cfg: the composed config.

    Returns:
        The job's exit status: 0, or :data:`~snell_bench.experiment.cells.CELLS_FAILED_EXIT` when
        cells of a grid failed and its ``allow_failures`` is false.

    Raises:
        JobError: the job cannot do what it was asked (e.g. ``job=report`` without cells).
        snell_bench.config.ConfigError: a setting is unusable.
    """
    check_config(cfg)
    if cfg.job not in (Job.plan, Job.status):  # those write nothing
        check_output_folders(cfg)
    return int(JOBS[cfg.job](cfg) or 0)
