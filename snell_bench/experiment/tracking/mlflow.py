"""``tracker=mlflow``: one MLflow run per cell.

A local folder is MLflow's file store, ``runs/<experiment>/mlruns/<experiment id>/<run id>/``
(``params/``, ``metrics/``, ``tags/``, ``artifacts/images/``): a folder per run, so several
processes write at once; the store is opened and the experiment created under a claim on its
folder. MLflow itself is imported when a tracker is made (it is an optional dependency).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from snell_bench.experiment.tracking.base import Tracker, as_text, clip, import_library, run_notes
from snell_bench.utils.locks import hold


def store_uri(uri: str) -> tuple[str, Path | None]:
    """A tracking URI and, for a local file store, its folder: a plain path or a ``file:`` URI
    becomes an absolute ``file://`` URI (the same store from any working folder); any other URI
    (``http(s)://``, ``sqlite:///``, ...) is kept, without a folder. Needs MLflow.

    Examples:
        >>> store_uri("file:/data/mlruns")
        ('file:///data/mlruns', PosixPath('/data/mlruns'))
        >>> store_uri("http://localhost:5000")
        ('http://localhost:5000', None)
    """
    from mlflow.utils.file_utils import get_local_path_or_none, path_to_local_file_uri

    local = get_local_path_or_none(str(uri))
    if local is None:
        return str(uri), None
    return path_to_local_file_uri(local), Path(os.path.abspath(local))


class MlflowTracker(Tracker):
    """MLflow: one run per cell in the experiment ``experiment`` (created, or restored if deleted)
    of the store at ``uri``.

    MLflow 3 asks for an opt-in to its file store: ``MLFLOW_ALLOW_FILE_STORE=true`` is set for
    this process unless already set; MLflow's usage telemetry is switched off the same way
    (``MLFLOW_DISABLE_TELEMETRY``). Params and tags longer than MLflow's limits are cut.

    Args:
        experiment: the MLflow experiment.
        uri: the tracking URI (``file:PATH``, a plain path, or a server's address).
        log_images: log the images (as artifacts under ``images/``).
    """

    name = "mlflow"

    def __init__(self, experiment: str, uri: str, *, log_images: bool = True) -> None:
        super().__init__(experiment, log_images=log_images)
        os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
        import_library("mlflow", self.name)
        from mlflow import MlflowClient

        self.uri, folder = store_uri(uri)
        if folder is not None:
            os.environ.setdefault("MLFLOW_ALLOW_FILE_STORE", "true")
            folder.mkdir(parents=True, exist_ok=True)
        # in a local folder, one process at a time opens the store and finds or creates the
        # experiment: the file store checks a name is free and then creates it, so two processes
        # starting together would otherwise both create it (or read a half-written one)
        with hold(folder) if folder is not None else contextlib.nullcontext():
            self.client = MlflowClient(tracking_uri=self.uri)
            self.experiment_id = self._experiment_id()
        self._run_id: str | None = None

    @property
    def where(self) -> str:
        return f"{self.uri} (experiment {self.experiment})"

    def _experiment_id(self) -> str:
        """The experiment's id: looked up, restored if deleted, or created (a server that finds
        the name taken by a creation at the same time says so; it is then looked up)."""
        from mlflow.exceptions import MlflowException

        client = self.client
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
        from mlflow.utils.mlflow_tags import MLFLOW_RUN_NOTE
        from mlflow.utils.validation import MAX_TAG_VAL_LENGTH

        tags = {k: clip(v, MAX_TAG_VAL_LENGTH) for k, v in tags.items()}
        notes = run_notes(tags)
        if notes:
            tags[MLFLOW_RUN_NOTE] = clip(notes, MAX_TAG_VAL_LENGTH)
        self._run_id = self.client.create_run(self.experiment_id, run_name=name, tags=tags).info.run_id

    def log_params(self, params: Mapping[str, Any]) -> None:
        from mlflow.entities import Param
        from mlflow.utils.validation import MAX_PARAM_VAL_LENGTH

        batch = [Param(k, clip(as_text(v), MAX_PARAM_VAL_LENGTH)) for k, v in params.items()]
        self.client.log_batch(self._run_id, params=batch)

    def log_metrics(self, metrics: Mapping[str, float]) -> None:
        from mlflow.entities import Metric
        from mlflow.utils.time import get_current_time_millis

        now = get_current_time_millis()
        self.client.log_batch(self._run_id, metrics=[Metric(k, float(v), now, 0) for k, v in metrics.items()])

    def log_images(self, images: Mapping[str, Path]) -> None:
        for path in images.values():
            self.client.log_artifact(self._run_id, str(path), "images")

    def end_run(self, status: str) -> None:
        run_id, self._run_id = self._run_id, None
        if run_id is not None:
            self.client.set_terminated(run_id, "FAILED" if status == "failed" else "FINISHED")
