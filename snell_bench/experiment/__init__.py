"""Jobs run by ``python -m snell_bench``: scene inputs, the refraction preview."""

from __future__ import annotations

from omegaconf import DictConfig

__all__ = ["run_job", "JOBS"]


def _preview(cfg: DictConfig) -> None:
    from snell_bench.experiment.preview import run_preview

    run_preview(cfg)


JOBS = {"preview": _preview}


def run_job(cfg: DictConfig) -> None:
    job = cfg.job
    if job not in JOBS:
        raise ValueError(f"unknown job {job!r}; set job= one of {sorted(JOBS)}")
    JOBS[job](cfg)
