"""Experiment tracking: each finished grid cell also logged to MLflow, TensorBoard or Weights &
Biases, one run per cell (``tracker=mlflow | tensorboard | wandb``, ``conf/tracker/``; the
default ``tracker=none`` logs nothing). The cell's folder stays the record; a tracker holds a copy
for browsing, logged after the record is written (:func:`log_cell`: a tracker that fails on a cell
only warns), so tracking cannot change a result. A missing library stops the run before any work
(``tracker.requires``, checked with the config).

What a run holds is :mod:`.base`'s; each back-end is a module (:mod:`.mlflow`, :mod:`.tensorboard`,
:mod:`.wandb`) found by ``tracker.name`` in :data:`TRACKERS`, unless ``tracker.backend`` names a
class (``_target_``). Only the cells this process computes are logged (not those skipped on
resume; a failed cell computed again is a new run); each process of a sweep logs its own cells,
into stores that take several writers at once (a folder per run for MLflow and W&B, an event file
per writer for TensorBoard).
"""

from __future__ import annotations

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from snell_bench.config import ConfigError
from snell_bench.experiment.tracking.base import (
    IMAGE_FILES,
    METRIC_SECTIONS,
    Tracker,
    cell_images,
    cell_metrics,
    cell_params,
    cell_tags,
    log_cell,
    run_notes,
)
from snell_bench.experiment.tracking.mlflow import MlflowTracker, store_uri
from snell_bench.experiment.tracking.tensorboard import TensorBoardTracker
from snell_bench.experiment.tracking.wandb import WandbTracker

__all__ = [
    "Tracker",
    "MlflowTracker",
    "TensorBoardTracker",
    "WandbTracker",
    "TRACKERS",
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

#: The back-ends, by ``tracker.name``.
TRACKERS: dict[str, type[Tracker]] = {t.name: t for t in (MlflowTracker, TensorBoardTracker, WandbTracker)}


def make_tracker(cfg: DictConfig) -> Tracker | None:
    """The tracker of a run's config: ``instantiate(cfg.tracker.backend)`` when that node names a
    class (``_target_``), else the :data:`TRACKERS` entry of ``cfg.tracker.name`` built with the
    node's keys; ``None`` for ``tracker=none`` (no ``backend``).

    Raises:
        ConfigError: a library the back-end needs is not installed (``tracker.requires``), or
            no back-end has the tracker's name.
    """
    node = cfg.get("tracker")
    if node is None or node.get("backend") is None:
        return None
    OmegaConf.to_object(node)  # the node's checks (the libraries it needs), as check_config runs them
    if "_target_" in node.backend:
        return instantiate(node.backend)
    if node.name not in TRACKERS:
        choices = ", ".join([*TRACKERS, "none"])
        raise ConfigError([f"tracker={node.name!r}: no such tracker; one of {choices}, or a tracker.backend._target_"])
    return TRACKERS[node.name](**OmegaConf.to_container(node.backend, resolve=True))
