"""Jobs run by ``python -m snell_bench``: the refraction preview, generation, the experiment grid,
the speed/accuracy sweep, the report, the plan of a grid (what it will do here, before doing it) and
its status across the jobs working on it."""

from __future__ import annotations

from omegaconf import DictConfig

from snell_bench.config import Job, check_config

__all__ = ["run_job", "JOBS"]


def _preview(cfg: DictConfig) -> None:
    from snell_bench.experiment.preview import run_preview

    run_preview(cfg)


def _generate(cfg: DictConfig) -> None:
    from snell_bench.experiment.generate import run_generate

    run_generate(cfg)


def _grid(cfg: DictConfig) -> None:
    from snell_bench.experiment.runner import run_grid

    run_grid(cfg)


def _tradeoff(cfg: DictConfig) -> None:
    from snell_bench.experiment.tradeoff import run_tradeoff

    run_tradeoff(cfg)


def _report(cfg: DictConfig) -> None:
    from pathlib import Path

    from snell_bench.experiment.reports import build_reports

    name = str(cfg.experiment_name)
    out = Path(cfg.reports_dir) / name
    root = Path(cfg.runs_dir) / name
    if next(root.rglob("result.json"), None) is not None and next(root.rglob("metrics.json"), None) is None:
        from snell_bench.experiment.tradeoff import build_tradeoff_report  # a speed/accuracy sweep

        paths = build_tradeoff_report(root, out)
    else:
        from snell_bench.experiment.runner import check_same_settings

        check_same_settings(root)
        paths = build_reports(root, out, name)
    print(f"reports: {out} ({len(paths)} files); open {out / 'index.html'}")


def _plan(cfg: DictConfig) -> None:
    from snell_bench.experiment.estimate import run_plan

    run_plan(cfg)


def _status(cfg: DictConfig) -> None:
    from snell_bench.experiment.status import run_status

    run_status(cfg)


JOBS = {
    Job.preview: _preview,
    Job.generate: _generate,
    Job.grid: _grid,
    Job.tradeoff: _tradeoff,
    Job.report: _report,
    Job.plan: _plan,
    Job.status: _status,
}


def run_job(cfg: DictConfig) -> None:
    """Run ``cfg.job`` (:data:`JOBS`) after checking every key and value of ``cfg``
    (:func:`snell_bench.config.check_config`)."""
    check_config(cfg)
    JOBS[Job(cfg.job)](cfg)
