"""Checks before Hydra creates its output folder or configures logging (a Hydra callback,
``hydra.callbacks.preflight`` in ``conf/config.yaml``): the config is valid
(:func:`snell_bench.config.checks.check_config`) and every folder the job writes is writable, so a
bad setting or a read-only folder fails with its key named, and no folder is created first."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from snell_bench.config.checks import check_config
from snell_bench.config.choices import SWEEP_JOBS, Job

__all__ = ["Preflight", "check_writable", "output_folders"]

#: Jobs that write under ``runs_dir`` and ``reports_dir``.
_RUNS_JOBS = (Job.grid, Job.tradeoff)


def check_writable(folder: str | os.PathLike, key: str) -> None:
    """Raise ``PermissionError`` naming ``key`` unless ``folder`` exists as a writable folder or
    can be created (its nearest existing parent is a writable folder). Creates nothing."""
    path = Path(folder).absolute()
    probe = path
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise NotADirectoryError(f"{key}={str(folder)!r}: {probe} is a file, not a folder; set {key} to a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        what = "is" if probe == path else f"would be created in {probe}, which is"
        raise PermissionError(
            f"{key}={str(folder)!r}: the folder {what} not writable by this user; set {key} to a writable folder "
            f"(e.g. {key}=/tmp/snell_bench) or change its permissions"
        )


def output_folders(cfg: DictConfig) -> list[tuple[str, str]]:
    """``(key, folder)`` of every folder the job of ``cfg`` writes into (Hydra's own included)."""
    out = []
    if OmegaConf.select(cfg, "hydra.run.dir") is not None:
        out.append(("hydra.run.dir", str(OmegaConf.select(cfg, "hydra.run.dir"))))
    job = cfg.get("job")
    if job in _RUNS_JOBS:
        out.append(("runs_dir", str(cfg.runs_dir)))
    if job in SWEEP_JOBS:
        out.append(("reports_dir", str(cfg.reports_dir)))
    return out


def _exit_on_error(check) -> None:
    """Run ``check()``; on a bad setting print it and exit with status 1 (Hydra turns an exception
    raised by a callback into a warning and goes on, so a callback stops the run this way)."""
    try:
        check()
    except (ValueError, OSError) as e:
        print(f"Error: {type(e).__name__}: {e}", file=sys.stderr)
        raise SystemExit(1) from None


class Preflight(Callback):
    """Validate the config and the output folders before Hydra touches the file system."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        def check() -> None:
            check_config(config)
            for key, folder in output_folders(config):
                check_writable(folder, key)

        _exit_on_error(check)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        sweep = OmegaConf.select(config, "hydra.sweep.dir")
        if sweep is not None:
            _exit_on_error(lambda: check_writable(str(sweep), "hydra.sweep.dir"))
