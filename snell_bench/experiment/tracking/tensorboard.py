"""``tracker=tensorboard``: a run folder per cell,
``runs/<experiment>/tensorboard/<scene>-<variation>/<object>/<method>/``, an event file per writer
(host, process and time in its name, so processes never share one)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from snell_bench.experiment.tracking.base import Tracker, as_text, import_library


def _hparam(value: Any) -> Any:
    """A setting as an HParams value: numbers and strings as they are, anything else as text."""
    if isinstance(value, (int, float, str)) and not isinstance(value, bool):
        return value
    return as_text(value)


class TensorBoardTracker(Tracker):
    """TensorBoard: a run folder per cell, ``<dir>/<cell name>/``, written with
    :class:`torch.utils.tensorboard.SummaryWriter`. Metrics are scalars at step 0 (stored as
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
        import_library("tensorboard", self.name)
        from torch.utils.tensorboard import SummaryWriter

        self._new_writer = SummaryWriter
        self.dir = Path(dir).absolute()
        self.dir.mkdir(parents=True, exist_ok=True)
        self._writer = None
        self._params: dict[str, Any] = {}
        self._metrics: dict[str, float] = {}

    @property
    def where(self) -> str:
        return str(self.dir)

    def start_run(self, name: str, tags: Mapping[str, str]) -> None:
        self._writer = self._new_writer(log_dir=str(self.dir / name))
        self._params, self._metrics = {"status": tags["status"]}, {}
        rows = "\n".join(f"| {k} | {str(v).replace('|', '/')} |" for k, v in tags.items())
        self._writer.add_text("tags", f"| tag | value |\n|---|---|\n{rows}", 0)

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
