"""What a tracker logs of a finished cell, from its record, config and files only, and the
interface every back-end implements. A cell's run:

- name ``<scene>-<variation>/<object>/<method>`` (the cell's folder), grouped by
  ``tracker.experiment`` (the MLflow experiment, the W&B group, TensorBoard's log folder);
- params: every resolved key that can change its result, flattened (:func:`cell_params`);
- tags: the status and its reason, the cell's identity, seed and settings hash, and why any score
  is missing (:func:`cell_tags`);
- metrics: every number of the record's :data:`METRIC_SECTIONS`, as ``<section>/<key>`` at step 0
  (:func:`cell_metrics`);
- images: the :data:`IMAGE_FILES` the cell has (``tracker.log_images``).
"""

from __future__ import annotations

import contextlib
import importlib
import json
import logging
import os
import time
from abc import ABC, abstractmethod
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from snell_bench.experiment.cells import Cell
from snell_bench.experiment.plan import result_settings

log = logging.getLogger(__package__)

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
    its result, flattened (:func:`~snell_bench.experiment.plan.result_settings`):
    ``{"sampler.steps": 20, "scene.name": "kitchen", ...}`` (numbers, strings, booleans, ``None``, lists)."""
    return result_settings(config)


def cell_metrics(record: Mapping[str, Any]) -> dict[str, float]:
    """Every number of a cell record's :data:`METRIC_SECTIONS`, nested keys joined with ``/``;
    ``None`` (a score that could not be computed), booleans, strings and lists left out.

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
    """A cell's status, identity and notes as a tracker's tags, as strings: ``status`` and, where
    the record has them, ``reason``, the identity fields (experiment, scene, variation, object,
    method, model, recipe, protocol), ``seed`` (the config's), ``settings_hash`` and
    ``missing.<metric>`` (why a score is missing)."""
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
    """The tags that explain a run (its status's reason, why scores are missing), one line each,
    for a tracker's run description; empty when there is none.

    Examples:
        >>> run_notes({"status": "ok", "missing.lpips": "no weights"})
        'missing lpips: no weights'
    """
    lines = [f"reason: {tags['reason']}"] if tags.get("reason") else []
    lines += [f"missing {k.removeprefix('missing.')}: {v}" for k, v in tags.items() if k.startswith("missing.")]
    return "\n".join(lines)


def cell_images(folder: str | os.PathLike) -> dict[str, Path]:
    """The :data:`IMAGE_FILES` a cell's folder has, by name without the suffix
    (``{"image": path, "reference": path, ...}``)."""
    folder = Path(folder)
    return {Path(name).stem: folder / name for name in IMAGE_FILES if (folder / name).is_file()}


def as_text(value: Any) -> str:
    """A param's value as text: strings as they are, anything else as JSON (``null``, ``true``, ``[0.2, 0.8]``)."""
    return value if isinstance(value, str) else json.dumps(value)


def clip(text: str, limit: int) -> str:
    """``text``, cut to ``limit`` characters (a back-end's length limit) with a trailing ``...``."""
    return text if len(text) <= limit else text[: limit - 3] + "..."


def import_library(module: str, tracker: str):
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


def log_cell(tracker: Tracker, cell: Cell, record: Mapping[str, Any]) -> bool:
    """Log a finished cell (its name, config and folder) and its ``metrics.json`` as one run of
    ``tracker``, after its record is written.

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
        msg = "tracker=%s could not log cell %s (its result is kept in %s): %s: %s"
        log.warning(msg, tracker.name, cell.name, cell.folder, type(e).__name__, e)
        tracker.failures += 1
        if started:
            with contextlib.suppress(Exception):
                tracker.end_run("failed")
        return False
    finally:
        tracker.seconds += time.perf_counter() - t0
