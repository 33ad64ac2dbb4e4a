"""Checks before Hydra creates its output folder or configures logging (a Hydra callback,
``hydra.callbacks.preflight`` in ``conf/config.yaml``): the config is valid
(:func:`snell_bench.config.checks.check_config`) and every folder the job writes is writable
(:func:`check_output_folders`: Hydra's run folder, the experiment's folders under ``runs_dir``
and ``reports_dir``, the caches, the tracker's folder), so a bad setting or a read-only folder
fails with its key named, and no folder is created first.

A job that only prints (``job=plan``) writes nothing at all: :func:`write_nothing` turns Hydra's run
folder, its ``.hydra/`` copy of the config and its log file off before Hydra makes them."""

from __future__ import annotations

import os
import sys
import tempfile
import urllib.parse
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

from snell_bench.config.checks import check_config
from snell_bench.config.choices import Job, Source
from snell_bench.config.errors import ConfigError
from snell_bench.config.names import folder_name_problem

__all__ = [
    "Preflight",
    "check_writable",
    "check_output_folders",
    "has_records",
    "nothing_to_report",
    "output_folders",
    "output_folder_problems",
    "write_nothing",
    "PRINT_JOBS",
]

#: Jobs that write under ``runs_dir`` and ``reports_dir``.
_RUNS_JOBS = (Job.grid,)

#: Jobs that only print: no folder, no file, no log (:func:`write_nothing`).
PRINT_JOBS = (Job.plan, Job.status)


def _nearest_existing(path: Path) -> Path:
    """``path`` or its nearest ancestor that exists (a link counts, even a broken one)."""
    probe = path
    while not (probe.exists() or probe.is_symlink()) and probe != probe.parent:
        probe = probe.parent
    return probe


def check_writable(folder: str | os.PathLike, key: str, value: Any = None) -> None:
    """Raise an ``OSError`` naming ``key`` unless ``folder`` exists as a writable folder or can be
    created (its nearest existing ancestor is a folder this user can create files in).

    ``os.access`` alone is not enough: it reads the permission bits, which root passes everywhere
    and which say nothing of procfs or sysfs (``/proc`` takes no new files even from root), of an
    NFS export that maps root to nobody, or of a full disk. So a probe file is created and removed
    in that nearest existing folder (``folder`` itself when it exists); nothing else is created.

    Args:
        folder: the folder the job writes into.
        key: the setting it comes from, named in the message (``runs_dir``).
        value: the setting's value, when ``folder`` is derived from it (``runs_dir`` for
            ``<runs_dir>/<experiment_name>``); default ``folder``.

    Raises:
        NotADirectoryError: a file stands where a folder is needed.
        PermissionError: the folder cannot be created or written.
    """
    shown = f"{key}={str(folder if value is None else value)!r}"
    where = "" if value is None else f" (the folder {folder})"
    fix = f"set {key} to a writable folder (e.g. {key}=/tmp/snell_bench) or change its permissions"
    path = Path(folder).absolute()
    try:
        probe = _nearest_existing(path)
        if probe.is_symlink() and not probe.exists():
            raise FileNotFoundError(f"{probe} is a link to {os.readlink(probe)}, which does not exist")
        if not probe.is_dir():
            raise NotADirectoryError(f"{shown}{where}: {probe} is a file, not a folder; set {key} to a folder")
    except NotADirectoryError:
        raise
    except OSError as e:
        raise PermissionError(f"{shown}{where}: cannot be looked up ({e.strerror or e}); {fix}") from None
    what = "is" if probe == path else f"would be created in {probe}, which is"
    if not os.access(probe, os.W_OK | os.X_OK):
        raise PermissionError(f"{shown}{where}: the folder {what} not writable by this user; {fix}")
    try:
        fd, name = tempfile.mkstemp(prefix=".snell_bench-probe-", dir=probe)
        os.close(fd)
        os.unlink(name)
    except OSError as e:
        raise PermissionError(
            f"{shown}{where}: the folder {what} not writable: no file can be created there ({e.strerror or e}); {fix}"
        ) from None


def _scene_sources(cfg: DictConfig) -> set[str]:
    """The ``scene.source`` values of the run: the run's own scene's, and for a sweep those of the
    scenes its cells compose (read from each scene's config file; ``generated`` where one cannot be
    read, so that its cache folder is checked)."""
    sources = {str(OmegaConf.select(cfg, "scene.source"))}
    job = cfg.get("job")
    names = OmegaConf.select(cfg, "grid.scenes")
    if job not in (*_RUNS_JOBS, Job.export) or not names:
        return sources
    from hydra.core.global_hydra import GlobalHydra

    from snell_bench.config.compose import config_context

    for name in names:
        try:
            with config_context():
                loaded = GlobalHydra.instance().config_loader().repository.load_config(f"scene/{name}")
            sources.add(str(loaded.config.get("source", "procedural")))
        except Exception:  # noqa: BLE001 - an unreadable scene file is named by check_config
            sources.add(str(Source.generated))
    return sources


def output_folders(cfg: DictConfig) -> list[tuple[str, Any, str]]:
    """``(key, value, folder)`` of every folder the job of ``cfg`` writes into (none for a job
    that only prints): Hydra's run folder, the experiment's folders under ``runs_dir`` and
    ``reports_dir``, the caches (``warps.cache_dir``, and ``scene.cache_dir`` for generated scenes)
    and the tracker's local folder (``tracker.dir``, an MLflow file store's ``tracker.uri``)."""
    job = cfg.get("job")
    if job in PRINT_JOBS:
        return []
    out: list[tuple[str, Any, str]] = []

    def add(key: str, folder: Any, value: Any = None) -> None:
        if folder is not None and str(folder).strip():
            out.append((key, value, str(folder)))

    add("hydra.run.dir", OmegaConf.select(cfg, "hydra.run.dir"))
    name = str(cfg.get("experiment_name"))
    if job in _RUNS_JOBS:
        add("runs_dir", Path(cfg.runs_dir) / name, cfg.runs_dir)
    if job == Job.report or (job == Job.grid and OmegaConf.select(cfg, "grid.report") is not False):
        add("reports_dir", Path(cfg.reports_dir) / name, cfg.reports_dir)
    if job == Job.export:
        add("export.dir", Path(cfg.export.dir) / name, cfg.export.dir)
    if job in (Job.preview, Job.generate, Job.grid, Job.export):
        method_warps = OmegaConf.select(cfg, "method.warps") or {}
        key = "method.warps.cache_dir" if "cache_dir" in method_warps else "warps.cache_dir"
        add(key, OmegaConf.select(cfg, key))
    if str(Source.generated) in _scene_sources(cfg):
        add("scene.cache_dir", OmegaConf.select(cfg, "scene.cache_dir"))
    if job == Job.grid and OmegaConf.select(cfg, "tracker.backend") is not None:
        add("tracker.dir", OmegaConf.select(cfg, "tracker.dir"))
        uri = OmegaConf.select(cfg, "tracker.uri")
        if uri is not None and urllib.parse.urlparse(str(uri)).scheme in ("", "file"):
            parsed = urllib.parse.urlparse(str(uri))
            add("tracker.uri", urllib.parse.unquote(parsed.path) if parsed.scheme else str(uri), uri)
    return out


def output_folder_problems(cfg: DictConfig) -> list[str]:
    """One line per folder of :func:`output_folders` that cannot be written (:func:`check_writable`)."""
    problems = []
    for key, value, folder in output_folders(cfg):
        try:
            check_writable(folder, key, value)
        except OSError as e:
            problems.append(str(e))
    return problems


def check_output_folders(cfg: DictConfig) -> None:
    """Raise :class:`~snell_bench.config.errors.ConfigError` listing every folder the job of
    ``cfg`` writes into that cannot be written (:func:`output_folders`), before any work; creates
    nothing."""
    problems = output_folder_problems(cfg)
    if problems:
        raise ConfigError(problems)


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


def has_records(folder: Path) -> bool:
    """Whether ``folder`` holds a cell record (``metrics.json``)."""
    return next(folder.rglob("metrics.json"), None) is not None


def nothing_to_report(runs_dir: str | Path, name: str, why: str) -> str:
    """The one-line error of ``job=report`` for an experiment without cells.

    Args:
        runs_dir: the ``runs_dir`` setting.
        name: the ``experiment_name`` setting.
        why: what is missing (the folder, or any cell record in it).

    Returns:
        The line: what is missing, the command that makes the cells, and the experiments of
        ``runs_dir`` that have some (a misspelt name is then seen at once).
    """
    runs = Path(runs_dir)
    others = (
        [p.name for p in sorted(runs.iterdir()) if p.is_dir() and p.name != name and has_records(p)]
        if runs.is_dir()
        else []
    )
    have = f"; other experiments with cells in {runs}: {', '.join(others)}" if others else ""
    return (
        f"job=report: nothing to report for experiment_name={name}: {why}. Run its cells first "
        f"(python -m snell_bench +experiment=<experiment> experiment_name={name}), or "
        f"choose another experiment_name{have}"
    )


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
            check_output_folders(config)

        _exit_on_error(check)
        if config.get("job") == "report":  # before Hydra makes the log folder inside runs/<name>
            runs, name = str(config.get("runs_dir")), str(config.get("experiment_name"))
            if not has_records(Path(runs) / name):
                print(
                    f"Error: {nothing_to_report(runs, name, f'no cell records below {Path(runs) / name}')}",
                    file=sys.stderr,
                )
                raise SystemExit(1)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        job = config.get("job")
        if job in PRINT_JOBS:  # one plan covers the whole grid: a sweep of plans would only make folders
            print(f"Error: job={job} prints and writes nothing: run it without -m/--multirun", file=sys.stderr)
            raise SystemExit(1)
        name = config.get("experiment_name")
        if isinstance(name, str):  # the sweep folder is <runs_dir>/<experiment_name>/logs/...
            _exit_on_error(lambda: _raise_if(folder_name_problem(name, "experiment_name", suffix=".log")))
        sweep = OmegaConf.select(config, "hydra.sweep.dir")
        if sweep is not None:
            _exit_on_error(lambda: check_writable(str(sweep), "hydra.sweep.dir"))


def _raise_if(problem: str | None) -> None:
    if problem is not None:
        raise ConfigError([problem])
