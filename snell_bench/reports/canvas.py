"""What every matplotlib figure of a report shares: a white figure on the Agg canvas, written
atomically as a PNG without a ``Software`` tag, and the run's images read back."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from snell_bench.utils.io import atomic_write
from snell_bench.utils.trust import open_image as trusted_image

log = logging.getLogger(__name__)

__all__ = ["new_figure", "save_png", "open_image", "load_rgb"]


def new_figure(width_in: float, height_in: float, dpi: int):
    """A white matplotlib ``Figure`` of ``width_in`` x ``height_in`` inches on an Agg canvas (no
    pyplot, no global state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=dpi, facecolor="white")
    FigureCanvasAgg(fig)
    return fig


def save_png(fig, out_png: str | os.PathLike, **kwargs) -> Path:
    """``fig.savefig`` as a PNG at ``out_png`` (its folder made, the file replaced atomically);
    ``kwargs`` go to ``savefig``."""
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(out_png, lambda f: fig.savefig(f, format="png", metadata={"Software": None}, **kwargs))
    return out_png


def open_image(path: Path, root: Path | None = None):
    """The PIL image at ``path``, loaded; None when there is no such file, or (with a WARNING naming
    it) it is no image, a link (below the run folder ``root``, when given) or larger than a run's
    image may be (:func:`snell_bench.utils.trust.open_image`: the pixel limit is checked from the
    header, before decoding)."""
    im, problem = trusted_image(path, root=root)
    if problem is not None:
        log.warning("%s; left out of the report", problem)
    return im


def load_rgb(path: Path, root: Path | None = None) -> np.ndarray | None:
    """The image at ``path`` as float32 RGB in [0, 1], ``(H, W, 3)``; None as :func:`open_image`."""
    im = open_image(path, root)
    return None if im is None else np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
