"""``tracker=wandb``: one Weights & Biases run per cell; offline by default, each run in its own
``runs/<experiment>/wandb/offline-run-<time>-<id>/`` folder (its ``run-<id>.wandb`` log holds the
config, the metrics and the summary; ``files/media/`` the images)."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from snell_bench.experiment.tracking.base import Tracker, clip, import_library, run_notes

log = logging.getLogger(__package__)


class WandbTracker(Tracker):
    """Weights & Biases: one run per cell (``wandb.init`` ... ``finish``), grouped by
    ``experiment``, in ``project``. ``mode="offline"`` (the default) sends nothing (``wandb sync``
    uploads the runs later); another mode is the user's choice. Settings are the run's config,
    metrics and images are logged once at step 0 (so they are also its summary), the short tags
    (``status:ok``, ``method:t2i``, ...) W&B tags and the reasons its notes; a failed cell's run
    exits with 1. W&B's system metrics and console capture are off.

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
        self._wandb = import_library("wandb", self.name)
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
            tags=[clip(f"{k}:{tags[k]}", 64) for k in self.SHORT_TAGS if k in tags],
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
