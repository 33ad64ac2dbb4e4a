"""Checks before Hydra creates its output folder or configures logging (a Hydra callback,
``hydra.callbacks.preflight`` in ``conf/config.yaml``): the config is valid
(:func:`snell_bench.config.checks.check_config`) and every folder the job writes is writable, so a
bad setting or a read-only folder fails with its key named, and no folder is created first.

A job that only prints (``job=plan``) writes nothing at all: :func:`write_nothing` turns Hydra's run
folder, its ``.hydra/`` copy of the config and its log file off before Hydra makes them."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

from snell_bench.config.checks import check_config
from snell_bench.config.choices import SWEEP_JOBS, Job

__all__ = ["Preflight", "check_writable", "output_folders", "write_nothing", "PRINT_JOBS"]

#: Jobs that write under ``runs_dir`` and ``reports_dir``.
_RUNS_JOBS = (Job.grid, Job.tradeoff)

#: Jobs that only print: no folder, no file, no log (:func:`write_nothing`).
PRINT_JOBS = (Job.plan, Job.status)


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
    """``(key, folder)`` of every folder the job of ``cfg`` writes into (Hydra's own included; none
    for a job that only prints)."""
    if cfg.get("job") in PRINT_JOBS:
        return []
    out = []
    if OmegaConf.select(cfg, "hydra.run.dir") is not None:
        out.append(("hydra.run.dir", str(OmegaConf.select(cfg, "hydra.run.dir"))))
    job = cfg.get("job")
    if job in _RUNS_JOBS:
        out.append(("runs_dir", str(cfg.runs_dir)))
    if job in SWEEP_JOBS:
        out.append(("reports_dir", str(cfg.reports_dir)))
    return out


def write_nothing(config: DictConfig) -> None:
    """Keep Hydra from writing for a job that only prints: its run folder becomes the working
    folder (which exists, so none is created), no ``.hydra/`` copy of the config
    (``hydra.output_subdir=null``), and the file handlers of ``hydra.job_logging`` are removed (the
    console stays). Changes ``config``'s ``hydra`` node in place, before Hydra's ``run_job`` reads it."""
    with read_write(config.hydra), open_dict(config.hydra):
        config.hydra.run.dir = os.getcwd()
        config.hydra.output_subdir = None
        logging = config.hydra.get("job_logging")
        handlers = logging.get("handlers") if isinstance(logging, DictConfig) else None
        if not isinstance(handlers, DictConfig):
            return
        files = [name for name, h in handlers.items() if isinstance(h, DictConfig) and "filename" in h]
        for name in files:
            del handlers[name]
        for node in [logging.get("root"), *(logging.get("loggers") or {}).values()]:
            if isinstance(node, DictConfig) and node.get("handlers") is not None:
                node.handlers = [h for h in node.handlers if h not in files]


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
        if config.get("job") in PRINT_JOBS:
            write_nothing(config)

        def check() -> None:
            check_config(config)
            for key, folder in output_folders(config):
                check_writable(folder, key)

        _exit_on_error(check)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        job = config.get("job")
        if job in PRINT_JOBS:  # one plan covers the whole grid: a sweep of plans would only make folders
            print(f"Error: job={job} prints and writes nothing: run it without -m/--multirun", file=sys.stderr)
            raise SystemExit(1)
        sweep = OmegaConf.select(config, "hydra.sweep.dir")
        if sweep is not None:
            _exit_on_error(lambda: check_writable(str(sweep), "hydra.sweep.dir"))
