"""Experiment tracking: each finished grid cell also logged to MLflow, TensorBoard or Weights &
Biases, one run per cell (``tracker=mlflow | tensorboard | wandb``, ``conf/tracker/``; the
default ``tracker=none`` logs nothing).

A tracker holds a copy for browsing and comparing; the cell's folder stays the record
(``metrics.json``, ``config.yaml``, the images). A cell is logged after its record is written,
from that record, its config and its files only, so tracking cannot change a result; a tracker
that fails on a cell logs a warning and the sweep goes on (:func:`log_cell`). A library that is
missing stops the run before any work (``tracker.requires``, checked with the config).

A cell's run:

- name ``<scene>-<variation>/<object>/<method>`` (the cell's folder under the experiment),
  grouped by ``tracker.experiment`` (``experiment_name``): the MLflow experiment, the W&B group,
  TensorBoard's log folder;
- params: the cell's settings, every resolved key that can change its result, flattened
  (:func:`cell_params`: the keys the settings hash of a resumed run covers);
- tags: the status (``ok``, ``failed``, ``skipped``) and its reason, the cell's identity, the
  seed, the settings hash, and ``missing.<metric>``: why a score is missing (:func:`cell_tags`);
- metrics: every number of the record's scores, timings, model calls, reference, warps,
  decisions and relighting, as ``<section>/<key>`` at step 0 (:func:`cell_metrics`);
- images: ``image.png``, ``reference.png``, ``mask.png``, ``panorama.png`` where the cell has them
  (``tracker.log_images``).

Only the cells this process computes are logged: cells finished before (skipped on resume) and
cells another process computes are not; a failed cell that a later run computes again is logged
again, as a new run. Each process of a sweep (Hydra's joblib or submitit launchers, the jobs of a
Slurm array) logs its own cells, into stores that take several writers at once:

- ``mlflow``: MLflow's file store, ``runs/<experiment>/mlruns/<experiment id>/<run id>/``
  (``params/``, ``metrics/``, ``tags/``, ``artifacts/images/``), a folder per run; the store is
  opened and the experiment created under a claim on its folder;
- ``tensorboard``: ``runs/<experiment>/tensorboard/<scene>-<variation>/<object>/<method>/``, an
  event file per writer (host, process and time in its name);
- ``wandb`` (offline): ``runs/<experiment>/wandb/offline-run-<time>-<id>/``, a folder per run
  (its ``run-<id>.wandb`` log holds the config, the metrics and the summary; ``files/media/`` the
  images).
"""

from __future__ import annotations

import contextlib
import importlib
import json
import logging
import os
import time
import urllib.parse
from abc import ABC, abstractmethod
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from snell_bench.experiment.cells import Cell
from snell_bench.experiment.locks import choose_lock, claim
from snell_bench.experiment.plan import result_settings

log = logging.getLogger(__name__)

__all__ = [
    "Tracker",
    "MlflowTracker",
    "TensorBoardTracker",
    "WandbTracker",
    "make_tracker",
    "log_cell",
    "cell_params",
    "cell_metrics",
    "cell_tags",
    "cell_images",
    "run_notes",
    "store_uri",
    "IMAGE_FILES",
    "METRIC_SECTIONS",
]

#: The images of a cell a tracker logs (where the cell has them).
IMAGE_FILES = ("image.png", "reference.png", "mask.png", "panorama.png")

#: The sections of a cell's record whose numbers are logged as metrics (``<section>/<key>``).
METRIC_SECTIONS = (
    "metrics",
    "timings_s",
    "sampler_timings_s",
    "model_calls",
    "reference",
    "warps",
    "decisions",
    "relight",
)

#: The record's fields that name a cell, logged as tags.
_IDENTITY = ("experiment", "scene", "variation", "object", "method", "model", "recipe", "protocol")


# ---------------------------------------------------------------------------- what a run holds
def cell_params(config: DictConfig) -> dict[str, Any]:
    """A cell's settings as a tracker's params: every resolved key of its config that can change
    its result, flattened (:func:`~snell_bench.experiment.plan.result_settings`).

    Args:
        config: the cell's composed config.

    Returns:
        ``{"sampler.steps": 20, "scene.name": "kitchen", ...}`` (values as the config holds them:
        numbers, strings, booleans, ``None``, lists).
    """
    return result_settings(config)


def cell_metrics(record: Mapping[str, Any]) -> dict[str, float]:
    """Every number of a cell record's :data:`METRIC_SECTIONS`, nested keys joined with ``/``;
    ``None`` (a score that could not be computed), booleans, strings and lists left out.

    Args:
        record: a cell's ``metrics.json``.

    Returns:
        ``{"metrics/psnr": 23.98, "timings_s/sampling": 9.8, "model_calls/main": 32.0, ...}``.

    Examples:
        >>> cell_metrics({"metrics": {"psnr": 24.5, "lpips": None}, "decisions": {"roi": True, "encode": {"n": 2}}})
        {'metrics/psnr': 24.5, 'decisions/encode/n': 2.0}
    """
    out: dict[str, float] = {}

    def walk(key: str, value: Any) -> None:
        if isinstance(value, Mapping):
            for k, v in value.items():
                walk(f"{key}/{k}", v)
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            out[key] = float(value)

    for section in METRIC_SECTIONS:
        walk(section, record.get(section))
    return out


def cell_tags(record: Mapping[str, Any], config: DictConfig) -> dict[str, str]:
    """A cell's status, identity and notes as a tracker's tags.

    Args:
        record: the cell's ``metrics.json``.
        config: the cell's composed config (its ``seed``).

    Returns:
        ``status`` and, where the record has them, ``reason``, the identity fields (experiment,
        scene, variation, object, method, model, recipe, protocol), ``seed``, ``settings_hash``
        and ``missing.<metric>`` (why a score is missing), as strings.
    """
    tags = {"status": str(record.get("status"))}
    tags.update({k: str(record[k]) for k in _IDENTITY if record.get(k) is not None})
    seed = OmegaConf.select(config, "seed", default=None)
    if seed is not None:
        tags["seed"] = str(seed)
    if record.get("settings_hash"):
        tags["settings_hash"] = str(record["settings_hash"])
    if record.get("reason"):
        tags["reason"] = str(record["reason"])
    for metric, why in (record.get("missing") or {}).items():
        tags[f"missing.{metric}"] = str(why)
    return tags


def run_notes(tags: Mapping[str, str]) -> str:
    """The tags that explain a run (its status's reason, why scores are missing) as lines of text,
    for a tracker's run description.

    Args:
        tags: a cell's tags (:func:`cell_tags`).

    Returns:
        One line per explaining tag; empty when there is none.

    Examples:
        >>> run_notes({"status": "ok", "missing.lpips": "no weights"})
        'missing lpips: no weights'
    """
    lines = [f"reason: {tags['reason']}"] if tags.get("reason") else []
    lines += [f"missing {k.removeprefix('missing.')}: {v}" for k, v in tags.items() if k.startswith("missing.")]
    return "\n".join(lines)


def cell_images(folder: str | os.PathLike) -> dict[str, Path]:
    """The images of a cell's folder a tracker logs.

    Args:
        folder: the cell's folder.

    Returns:
        ``{"image": path, "reference": path, ...}``: the :data:`IMAGE_FILES` it has, by name
        without the suffix.
    """
    folder = Path(folder)
    return {Path(name).stem: folder / name for name in IMAGE_FILES if (folder / name).is_file()}


def _text(value: Any) -> str:
    """A param's value as text: strings as they are, anything else as JSON (``null``, ``true``, ``[0.2, 0.8]``)."""
    return value if isinstance(value, str) else json.dumps(value)


def _clip(text: str, limit: int) -> str:
    """``text``, cut to ``limit`` characters (a back-end's length limit) with a trailing ``...``."""
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _import(module: str, tracker: str):
    """Import a back-end's library, or raise ``ImportError`` naming the fix."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise ImportError(
            f"tracker={tracker} needs {module}: pip install 'snell_bench[track]' or set tracker=none ({e})"
        ) from e


# ---------------------------------------------------------------------------- the interface
class Tracker(ABC):
    """One experiment's runs in a tracking back-end, one run at a time: :meth:`start_run`, then
    :meth:`log_params`, :meth:`log_metrics`, :meth:`log_images`, then :meth:`end_run`;
    :meth:`close` at the end of the sweep.

    Args:
        experiment: the name the runs are grouped under.
        log_images: whether :func:`log_cell` logs the cells' images.
    """

    #: The back-end's name (``tracker.name``).
    name = ""

    def __init__(self, experiment: str, *, log_images: bool = True) -> None:
        self.experiment = str(experiment)
        self.with_images = bool(log_images)
        self.runs = 0  #: runs logged by :func:`log_cell`
        self.failures = 0  #: cells :func:`log_cell` could not log
        self.seconds = 0.0  #: time spent logging them

    @property
    @abstractmethod
    def where(self) -> str:
        """Where the runs go (a URI or a folder), for people."""

    @abstractmethod
    def start_run(self, name: str, tags: Mapping[str, str]) -> None:
        """Start the run ``name`` with these tags."""

    @abstractmethod
    def log_params(self, params: Mapping[str, Any]) -> None:
        """Log the run's settings (:func:`cell_params`)."""

    @abstractmethod
    def log_metrics(self, metrics: Mapping[str, float]) -> None:
        """Log the run's numbers (:func:`cell_metrics`), at step 0."""

    @abstractmethod
    def log_images(self, images: Mapping[str, Path]) -> None:
        """Log PNG files, by name (:func:`cell_images`)."""

    @abstractmethod
    def end_run(self, status: str) -> None:
        """End the run; ``status`` is the cell's (``ok``, ``failed``, ``skipped``)."""

    def close(self) -> None:  # noqa: B027 - a back-end with nothing to release keeps this
        """Release what the back-end holds (after the last run)."""

    def summary(self) -> dict[str, Any]:
        """``{"name", "where", "runs", "failures", "seconds_per_run"}`` of this process's logging."""
        n = self.runs + self.failures
        return {
            "name": self.name,
            "where": self.where,
            "runs": self.runs,
            "failures": self.failures,
            "seconds_per_run": round(self.seconds / n, 4) if n else None,
        }


def make_tracker(cfg: DictConfig) -> Tracker | None:
    """The tracker of a run's config.

    Args:
        cfg: the run's composed config.

    Returns:
        ``instantiate(cfg.tracker.backend)``, or ``None`` for ``tracker=none``.

    Raises:
        ConfigError: a library the back-end needs is not installed (``tracker.requires``).
    """
    node = cfg.get("tracker")
    if node is None or node.get("backend") is None:
        return None
    OmegaConf.to_object(node)  # the node's checks (the libraries it needs), as check_config runs them
    return instantiate(node.backend)


def log_cell(tracker: Tracker, cell: Cell, record: Mapping[str, Any]) -> bool:
    """Log a finished cell as one run of ``tracker`` (see the module docs), after its record is
    written.

    Args:
        tracker: where to log.
        cell: the cell (its name, config and folder).
        record: its ``metrics.json``.

    Returns:
        Whether the run was logged; a failure is logged as a warning, never raised.
    """
    t0 = time.perf_counter()
    started = False
    try:
        tags = cell_tags(record, cell.config)
        tracker.start_run(cell.name, tags)
        started = True
        tracker.log_params(cell_params(cell.config))
        tracker.log_metrics(cell_metrics(record))
        if tracker.with_images:
            tracker.log_images(cell_images(cell.folder))
        tracker.end_run(tags["status"])
        tracker.runs += 1
        return True
    except Exception as e:  # noqa: BLE001 - a warning, not a failed cell
        # The cell's files and record are written and complete when it is logged: failing it (or
        # stopping the sweep) would discard a valid result, and a resumed run would compute it
        # again. The tracker only misses this run.
        log.warning(
            "tracker=%s could not log cell %s (its result is kept in %s): %s: %s",
            tracker.name,
            cell.name,
            cell.folder,
            type(e).__name__,
            e,
        )
        tracker.failures += 1
        if started:
            with contextlib.suppress(Exception):
                tracker.end_run("failed")
        return False
    finally:
        tracker.seconds += time.perf_counter() - t0


# ---------------------------------------------------------------------------- MLflow
def store_uri(uri: str) -> tuple[str, Path | None]:
    """A tracking URI and, for a local file store, its folder: a plain path or a ``file:`` URI
    becomes an absolute ``file://`` URI (the same store from any working folder); any other URI
    (``http(s)://``, ``sqlite:///``, ...) is kept, without a folder.

    Args:
        uri: ``tracker.uri``.

    Returns:
        ``(URI, folder)``; the folder is ``None`` for a store that is not a local folder.

    Examples:
        >>> store_uri("file:/data/mlruns")
        ('file:///data/mlruns', PosixPath('/data/mlruns'))
        >>> store_uri("http://localhost:5000")
        ('http://localhost:5000', None)
    """
    parsed = urllib.parse.urlparse(str(uri))
    if parsed.scheme not in ("", "file"):
        return str(uri), None
    folder = Path(urllib.parse.unquote(parsed.path) if parsed.scheme else str(uri)).absolute()
    return folder.as_uri(), folder


class MlflowTracker(Tracker):
    """MLflow: one run per cell in the experiment ``experiment`` (created if missing) of the store
    at ``uri``.

    A local folder is MLflow's file store (a folder per run, so several processes write at once;
    the store is opened and the experiment looked up or created under a claim on the folder,
    :func:`~snell_bench.experiment.locks.claim`). MLflow 3 asks for an
    opt-in to it: ``MLFLOW_ALLOW_FILE_STORE=true`` is set for this process unless already set;
    MLflow's usage telemetry is switched off the same way (``MLFLOW_DISABLE_TELEMETRY``). Params
    longer than MLflow's limits are cut.

    Args:
        experiment: the MLflow experiment.
        uri: the tracking URI (``file:PATH``, a plain path, or a server's address).
        log_images: log the images (as artifacts under ``images/``).
    """

    name = "mlflow"

    def __init__(self, experiment: str, uri: str, *, log_images: bool = True) -> None:
        super().__init__(experiment, log_images=log_images)
        self.uri, folder = store_uri(uri)
        os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
        if folder is not None:
            os.environ.setdefault("MLFLOW_ALLOW_FILE_STORE", "true")
        _import("mlflow", self.name)
        from mlflow import MlflowClient
        from mlflow.entities import Metric, Param
        from mlflow.utils.validation import MAX_PARAM_VAL_LENGTH, MAX_TAG_VAL_LENGTH

        self._metric, self._param = Metric, Param
        self._limits = (MAX_PARAM_VAL_LENGTH, MAX_TAG_VAL_LENGTH)

        def open_store():
            client = MlflowClient(tracking_uri=self.uri)
            return client, self._experiment_id(client)

        # in a local folder, one process at a time opens the store and finds or creates the
        # experiment: the file store checks a name is free and then creates it, so two processes
        # starting together would otherwise both create it (or read a half-written one)
        self.client, self.experiment_id = self._locked(folder, open_store) if folder is not None else open_store()
        self._run_id: str | None = None

    @property
    def where(self) -> str:
        return f"{self.uri} (experiment {self.experiment})"

    @staticmethod
    def _locked(folder: Path, fn, timeout_s: float = 120.0):
        """``fn()`` while holding the claim on ``folder`` (waiting for it up to ``timeout_s``)."""
        folder.mkdir(parents=True, exist_ok=True)
        kind = choose_lock("auto", folder)
        deadline = time.monotonic() + timeout_s
        while True:
            with claim(folder, kind=kind) as mine:
                if mine:
                    return fn()
            if time.monotonic() > deadline:
                raise TimeoutError(
                    f"{folder} stayed locked for {timeout_s:.0f} s (another process creating the experiment)"
                )
            time.sleep(0.05)

    def _experiment_id(self, client) -> str:
        """The experiment's id: looked up, restored if deleted, or created (a server that finds
        the name taken by a creation at the same time says so; it is then looked up)."""
        from mlflow.exceptions import MlflowException

        exp = client.get_experiment_by_name(self.experiment)
        if exp is None:
            try:
                return client.create_experiment(self.experiment)
            except MlflowException as e:
                if e.error_code != "RESOURCE_ALREADY_EXISTS":
                    raise
                exp = client.get_experiment_by_name(self.experiment)
        if exp.lifecycle_stage == "deleted":
            client.restore_experiment(exp.experiment_id)
        return exp.experiment_id

    def start_run(self, name: str, tags: Mapping[str, str]) -> None:
        limit = self._limits[1]
        tags = {k: _clip(v, limit) for k, v in tags.items()}
        notes = run_notes(tags)
        if notes:
            tags["mlflow.note.content"] = _clip(notes, limit)
        self._run_id = self.client.create_run(self.experiment_id, run_name=name, tags=tags).info.run_id

    def log_params(self, params: Mapping[str, Any]) -> None:
        limit = self._limits[0]
        self.client.log_batch(self._run_id, params=[self._param(k, _clip(_text(v), limit)) for k, v in params.items()])

    def log_metrics(self, metrics: Mapping[str, float]) -> None:
        now = int(time.time() * 1000)
        self.client.log_batch(self._run_id, metrics=[self._metric(k, float(v), now, 0) for k, v in metrics.items()])

    def log_images(self, images: Mapping[str, Path]) -> None:
        for path in images.values():
            self.client.log_artifact(self._run_id, str(path), "images")

    def end_run(self, status: str) -> None:
        run_id, self._run_id = self._run_id, None
        if run_id is not None:
            self.client.set_terminated(run_id, "FAILED" if status == "failed" else "FINISHED")


# ---------------------------------------------------------------------------- TensorBoard
def _hparam(value: Any) -> Any:
    """A setting as an HParams value: numbers and strings as they are, anything else as text."""
    if isinstance(value, (int, float, str)) and not isinstance(value, bool):
        return value
    return _text(value)


class TensorBoardTracker(Tracker):
    """TensorBoard: a run folder per cell, ``<dir>/<cell name>/``, written with
    :class:`torch.utils.tensorboard.SummaryWriter` (its event file is named after the host, the
    process and the time, so processes never share one). Metrics are scalars at step 0 (stored as
    float32), settings and status are HParams (the HParams tab compares the cells), tags and
    notes a text table, images the PNG files themselves.

    Args:
        experiment: the experiment's name (in the tags; ``dir`` is the grouping).
        dir: the log folder (``tensorboard --logdir DIR``).
        log_images: log the images.
    """

    name = "tensorboard"

    def __init__(self, experiment: str, dir: str, *, log_images: bool = True) -> None:  # noqa: A002 - tracker.dir
        super().__init__(experiment, log_images=log_images)
        _import("tensorboard", self.name)
        from torch.utils.tensorboard import SummaryWriter

        self._writer_type = SummaryWriter
        self.dir = Path(dir).absolute()
        self.dir.mkdir(parents=True, exist_ok=True)
        self._writer = None
        self._params: dict[str, Any] = {}
        self._metrics: dict[str, float] = {}

    @property
    def where(self) -> str:
        return str(self.dir)

    def start_run(self, name: str, tags: Mapping[str, str]) -> None:
        self._writer = self._writer_type(log_dir=str(self.dir / name))
        self._params, self._metrics = {}, {}
        rows = "\n".join(f"| {k} | {str(v).replace('|', '/')} |" for k, v in tags.items())
        self._writer.add_text("tags", f"| tag | value |\n|---|---|\n{rows}", 0)
        self._params["status"] = tags["status"]

    def log_params(self, params: Mapping[str, Any]) -> None:
        self._params.update({k: _hparam(v) for k, v in params.items()})

    def log_metrics(self, metrics: Mapping[str, float]) -> None:
        for k, v in metrics.items():
            self._writer.add_scalar(k, float(v), 0)
        self._metrics.update(metrics)

    def log_images(self, images: Mapping[str, Path]) -> None:
        """Log the PNG files as they are (an image summary holds an encoded PNG: the file's bytes,
        not decoded and encoded again)."""
        from PIL import Image
        from tensorboard.compat.proto.summary_pb2 import Summary

        for stem, path in images.items():
            with Image.open(path) as im:  # reads the header only: size and bands
                width, height, bands = im.width, im.height, len(im.getbands())
            image = Summary.Image(
                height=height, width=width, colorspace=bands, encoded_image_string=Path(path).read_bytes()
            )
            self._writer.file_writer.add_summary(Summary(value=[Summary.Value(tag=f"images/{stem}", image=image)]), 0)

    def end_run(self, status: str) -> None:
        from torch.utils.tensorboard.summary import hparams

        writer, self._writer = self._writer, None
        if writer is None:
            return
        try:
            self._params["status"] = status
            for summary in hparams(self._params, self._metrics):  # experiment, session start, session end
                writer.file_writer.add_summary(summary)
        finally:
            writer.close()


# ---------------------------------------------------------------------------- Weights & Biases
class WandbTracker(Tracker):
    """Weights & Biases: one run per cell (``wandb.init`` ... ``finish``), grouped by
    ``experiment``, in ``project``. ``mode="offline"`` (the default) writes each run to its own
    ``<dir>/wandb/offline-run-<time>-<id>/`` folder and sends nothing (``wandb sync`` uploads it
    later); another mode is the user's choice. Settings are the run's config, metrics and images
    are logged once at step 0 (so they are also its summary), the short tags (``status:ok``,
    ``method:t2i``, ...) W&B tags and the reasons its notes; a failed cell's run exits with 1.
    W&B's system metrics and console capture are off.

    Args:
        experiment: the W&B group.
        dir: the folder W&B writes its ``wandb/`` folder into.
        project: the W&B project.
        entity: the W&B entity (``None``: the account's default).
        mode: ``offline``, ``online``, ``shared`` or ``disabled``.
        log_images: log the images.
    """

    name = "wandb"

    #: The tags that become W&B tags, as ``key:value`` (W&B keeps a tag to 64 characters).
    SHORT_TAGS = ("status", "scene", "variation", "object", "method", "model", "recipe", "seed")

    def __init__(
        self,
        experiment: str,
        dir: str,  # noqa: A002 - tracker.dir
        *,
        project: str = "snell_bench",
        entity: str | None = None,
        mode: str = "offline",
        log_images: bool = True,
    ) -> None:
        super().__init__(experiment, log_images=log_images)
        self._wandb = _import("wandb", self.name)
        self.dir = Path(dir).absolute()
        self.dir.mkdir(parents=True, exist_ok=True)
        self.project, self.entity, self.mode = str(project), entity, str(mode)
        self._run = None
        self._pending: dict[str, Any] = {}

    @property
    def where(self) -> str:
        return f"{self.dir / 'wandb'} (project {self.project}, group {self.experiment}, mode {self.mode})"

    def start_run(self, name: str, tags: Mapping[str, str]) -> None:
        wandb = self._wandb
        self._pending = {}
        self._run = wandb.init(
            project=self.project,
            entity=self.entity,
            group=self.experiment,
            name=name,
            job_type="cell",
            dir=str(self.dir),
            mode=self.mode,
            tags=[_clip(f"{k}:{tags[k]}", 64) for k in self.SHORT_TAGS if k in tags],
            notes=run_notes(tags) or None,
            settings=wandb.Settings(silent=True, console="off", x_disable_stats=True),
            reinit="create_new",
        )

    def log_params(self, params: Mapping[str, Any]) -> None:
        self._run.config.update(dict(params), allow_val_change=True)

    def log_metrics(self, metrics: Mapping[str, float]) -> None:
        self._pending.update({k: float(v) for k, v in metrics.items()})

    def log_images(self, images: Mapping[str, Path]) -> None:
        self._pending.update({f"images/{stem}": self._wandb.Image(str(path)) for stem, path in images.items()})

    def end_run(self, status: str) -> None:
        run, self._run = self._run, None
        if run is None:
            return
        try:
            if self._pending:
                run.log(self._pending, step=0)
        finally:
            self._pending = {}
            run.finish(exit_code=1 if status == "failed" else 0)

    def close(self) -> None:
        """Stop the W&B service process this process started (a failure only warns: the runs are
        finished)."""
        try:
            self._wandb.teardown()
        except Exception as e:  # noqa: BLE001 - every run was finished before
            log.warning("tracker=wandb: stopping the W&B service failed: %s: %s", type(e).__name__, e)
