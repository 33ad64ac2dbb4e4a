"""Scoring one generated image of an experiment: the run's scorers, built once, and every metric
of one cell with the reason for each missing one.

- :func:`load_scorers` builds the weight-backed scorers (LPIPS, CLIP, ImageReward) from the
  ``metrics`` config. A scorer that cannot be built, for any reason (weights not configured, a
  broken weights file), is kept as the :class:`~snell_bench.metrics.functional.MetricUnavailable`
  that says why: building never raises.
- :func:`score_cell` scores one image: the metrics of :func:`metric_names` against the reference
  and the prompt, and ``psnr_true`` against the true render over the object mask, under one
  evaluation protocol (config key ``metrics.protocol``: ``"paper"`` or ``"authors"``, see
  :mod:`snell_bench.metrics.functional` and :mod:`snell_bench.metrics.fidelity`), recorded in its
  result.

Convention (:func:`score_cell`):
    - With a reference, the metrics of :func:`~snell_bench.metrics.alignment.metric_names`
      (``protocol``) are those of :func:`score_all` under ``protocol`` (PSNR, MAE, LPIPS: masked;
      ``"paper"``: grayscale, histogram-matched PSNR and MAE, LPIPS of the RGB images averaged over
      the mask of its spatial map; ``"authors"``: the authors' evaluation on the 8-bit images, with
      ``lpips_box``, their bounding-box LPIPS, after ``lpips``; CLIP and ImageReward: the full image
      against the prompt), each computed as its :class:`~snell_bench.metrics.registry.MetricSpec`
      says (:func:`~snell_bench.metrics.registry.compute_metrics`). Users' metrics (``extra``)
      follow. With a true render, ``psnr_true`` is the masked PSNR (same protocol) of the image
      against it over the object mask.
    - Missing values: a metric whose scorer could not be built is None with the scorer's reason;
      without a reference, PSNR, MAE and LPIPS are None with the reason given (default
      ``"no reference"``), and CLIP and ImageReward, which need the prompt alone, are still scored.
    - Every metric is a finite float or None (never NaN or inf): every PSNR above
      :data:`PSNR_CEILING_DB` (identical pixels: ``inf``) is recorded at the ceiling with a note in
      ``notes``, so a perfect match counts in every mean; any other NaN or infinite value becomes
      None, with its reason in ``missing``.
    - ``protocol`` is recorded in the result as given (reports show it); it changes PSNR, MAE, LPIPS
      and ``psnr_true``, never CLIP or ImageReward.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import torch

from snell_bench.utils.tensors import bchw_to_hwc

from .alignment import METRIC_NAMES, CLIPScore, ImageRewardScorer, ScoreResult, metric_names
from .fidelity import MaskedLPIPS, check_box_range
from .files import check_files, evaluated_files
from .functional import MetricUnavailable, check_protocol
from .registry import ScoreInputs, compute_metrics, metrics_for

__all__ = [
    "PROMPT_METRICS",
    "PSNR_CEILING_DB",
    "REFERENCE_METRICS",
    "SCORER_METRICS",
    "SCORER_NAMES",
    "CellScores",
    "Scorers",
    "load_scorers",
    "reference_metrics",
    "score_cell",
]

#: The metrics of :data:`METRIC_NAMES` scored against the prompt alone (no reference needed).
PROMPT_METRICS = ("clip", "image_reward")

#: The metrics of :data:`METRIC_NAMES` scored against the reference over the metric mask (under
#: ``metrics.protocol=authors`` also ``lpips_box``: see :func:`reference_metrics`).
REFERENCE_METRICS = tuple(name for name in METRIC_NAMES if name not in PROMPT_METRICS)

#: The metrics each scorer computes (a scorer missing makes all of them missing with its reason).
SCORER_METRICS = {"lpips": ("lpips", "lpips_box"), "clip": ("clip",), "image_reward": ("image_reward",)}


def reference_metrics(protocol: str = "paper") -> tuple[str, ...]:
    """The metrics of :func:`~snell_bench.metrics.alignment.metric_names` (``protocol``) scored
    against the reference."""
    return tuple(name for name in metric_names(protocol) if name not in PROMPT_METRICS)


#: The metrics whose scorer needs weights or a program (built by :func:`load_scorers`).
SCORER_NAMES = ("lpips", "clip", "image_reward")


class CellScores(ScoreResult):
    """What :func:`score_cell` returns: ``metrics`` and ``missing`` as in :class:`ScoreResult`,
    ``notes`` (``{name: why the value is what it is}``: a PSNR recorded at
    :data:`PSNR_CEILING_DB`), and ``protocol``, the evaluation protocol the fidelity metrics were
    computed under."""

    notes: dict[str, str]
    protocol: str


class Scorers(dict):
    """The weight-backed scorers of one run, by metric name (:data:`SCORER_NAMES`).

    Each value is the scorer, or the :class:`MetricUnavailable` its constructor raised, or None
    (not configured). Being a dict of the :func:`score_all` keywords, ``score_all(..., **scorers)``
    works as well.
    """

    def scorer(self, name: str) -> Any | None:
        """The scorer of ``name``, or None when it is missing."""
        value = self.get(name)
        return None if isinstance(value, MetricUnavailable) else value

    @property
    def lpips(self) -> MaskedLPIPS | None:
        """The LPIPS scorer, or None."""
        return self.scorer("lpips")

    @property
    def clip(self) -> CLIPScore | None:
        """The CLIP scorer, or None."""
        return self.scorer("clip")

    @property
    def image_reward(self) -> ImageRewardScorer | None:
        """The ImageReward scorer, or None."""
        return self.scorer("image_reward")

    @property
    def reasons(self) -> dict[str, str]:
        """``{name: why it is missing}`` for the scorers that could not be built."""
        return {k: v.reason for k, v in self.items() if isinstance(v, MetricUnavailable)}


def _build(factory: Callable[[], Any]) -> Any:
    try:
        return factory()
    except MetricUnavailable as e:
        return e
    except Exception as e:  # a broken weights file must not stop the run: it becomes the reason
        return MetricUnavailable(f"{type(e).__name__}: {e}")


def load_scorers(metrics_cfg: Any = None, *, device: str | torch.device = "cpu") -> Scorers:
    """Build the weight-backed scorers of a run, once.

    The scorers are the same for every protocol; ``protocol`` is read only to reject an unknown one
    before any cell runs (scoring takes it as :func:`score_cell`'s ``protocol`` argument).

    Args:
        metrics_cfg: a config with ``lpips_weights``, ``clip_weights``, ``image_reward_python`` and
            ``protocol`` (``MetricsConfig``, a DictConfig or a mapping; a missing key or ``None``:
            unset, and the scorer looks in its default places; the protocol defaults to ``"paper"``).
        device: where LPIPS and CLIP run.

    Returns:
        :class:`Scorers` with ``"lpips"``, ``"clip"`` and ``"image_reward"``, each the scorer or
        the :class:`MetricUnavailable` saying why it is missing: its constructor's own reason
        (which names the config key to set), or ``"<exception type>: <message>"`` for any other
        error (e.g. a weights file that does not load). Never raises for a scorer that cannot be
        built.

    Raises:
        ValueError: an unknown ``protocol`` (the message names ``metrics.protocol``).
    """

    def get(key):
        if metrics_cfg is None:
            return None
        if isinstance(metrics_cfg, Mapping):
            return metrics_cfg.get(key)
        return getattr(metrics_cfg, key, None)

    protocol = get("protocol")
    check_protocol("paper" if protocol is None else protocol)
    return Scorers(
        lpips=_build(lambda: MaskedLPIPS(get("lpips_weights"), device=device)),
        clip=_build(lambda: CLIPScore(get("clip_weights"), device=device)),
        image_reward=_build(lambda: ImageRewardScorer(get("image_reward_python"), device=str(device))),
    )


#: The highest PSNR a cell records (dB): ``10 log10(1 / 1e-8)``, the PSNR of the smallest MSE the
#: authors' evaluation tells from zero (``torch.isclose(MSE, 0)``: ``MSE <= 1e-8``). Every recorded
#: PSNR is ``min(PSNR, ceiling)``, so identical pixels (``inf``) count in every mean at the ceiling,
#: and the record says so in ``notes``.
PSNR_CEILING_DB = 80.0


def _ceiling_note(value: float) -> str:
    what = "identical pixels (infinite PSNR)" if value == math.inf else f"{value:.2f} dB"
    return f"{what} after the protocol's preprocessing: recorded at the {PSNR_CEILING_DB:g} dB ceiling"


def _is_finite(x) -> bool:
    return not (isinstance(x, float) and not math.isfinite(x))


def _non_finite_reason(x: float) -> str:
    return f"not a finite value ({x!r})"


def _apply_psnr_ceiling(metrics: dict, notes: dict) -> None:
    """Clamp every PSNR (``psnr``, ``psnr_true``, ...) of ``metrics`` at :data:`PSNR_CEILING_DB`
    in place, with a note for each value clamped (NaN is left for the non-finite filter)."""
    for name, value in metrics.items():
        if name.startswith("psnr") and isinstance(value, float) and value > PSNR_CEILING_DB:
            metrics[name] = PSNR_CEILING_DB
            notes[name] = _ceiling_note(value)


def _hwc(image: Any) -> Any:
    """A torch image ``(1, 3, H, W)`` or ``(3, H, W)`` as numpy ``(H, W, 3)``; others as given."""
    if isinstance(image, torch.Tensor):
        return bchw_to_hwc(image if image.ndim == 4 else image[None])
    return image


def _as_scored(generated: Any, reference: Any, mask: Any, path: Any, files: str, reference_is_jpeg: bool) -> tuple:
    """The generated image, the reference, the mask and the generated image's file as the metrics
    read them.

    Args:
        generated: the image, numpy or torch (:func:`_hwc`).
        reference: the reference render, or None.
        mask: the metric mask, or None.
        path: the saved generated image, or None.
        files: ``"png"`` or ``"jpeg"`` (config key ``metrics.files``).
        reference_is_jpeg: the reference already decodes its JPEG.

    Returns:
        ``(generated, reference, mask, path)``: the generated image as numpy ``(H, W, 3)``; with
        ``files="jpeg"`` the three images after the authors' JPEG round trips
        (:func:`~snell_bench.metrics.files.evaluated_files`) and no path (ImageReward then reads the
        decoded JPEG, not the PNG file); else the others as given.
    """
    gen = _hwc(generated)
    if check_files(files) == "jpeg":
        gen, reference, mask = evaluated_files(gen, reference, mask, files, reference_is_jpeg=reference_is_jpeg)
        path = None
    return gen, reference, mask, path


def _finite(metrics: dict, missing: dict) -> dict[str, str]:
    """Every PSNR of ``metrics`` at most :data:`PSNR_CEILING_DB`, then every other NaN or infinite
    value None with its reason added to ``missing``, in place; returns the notes of the clamped PSNRs
    (``{name: note}``)."""
    notes: dict[str, str] = {}
    _apply_psnr_ceiling(metrics, notes)
    for name, value in metrics.items():
        if not _is_finite(value):
            metrics[name] = None
            missing.setdefault(name, _non_finite_reason(value))
    return notes


def score_cell(
    generated: Any,
    reference: np.ndarray | None,
    mask: np.ndarray | None,
    prompt: str,
    scorers: Mapping[str, Any] | None = None,
    *,
    reference_reason: str | None = None,
    true_render: np.ndarray | None = None,
    object_mask: np.ndarray | None = None,
    generated_path: str | os.PathLike | None = None,
    protocol: str = "paper",
    files: str = "png",
    lpips_box_range: str = "signed",
    reference_is_jpeg: bool = False,
    extra: Sequence[str] = (),
) -> CellScores:
    """Every metric of one generated image, each a float or None with the reason (see the module's
    conventions): those of :func:`~snell_bench.metrics.alignment.metric_names` (``protocol``) against
    the reference and the prompt, users' metrics (``extra``), then ``psnr_true`` against the true
    render over ``object_mask``.

    Args:
        generated: the image, numpy ``(H, W, 3)`` in [0, 1] or torch ``(1, 3, H, W)`` / ``(3, H, W)``.
        reference: the reference render ``(H, W, 3)``, or None when there is none.
        mask: the metric mask ``(H, W)`` of the reference.
        prompt: the text CLIP and ImageReward score the image against, as is: the caller picks the
            full prompt or the object phrase (config key ``metrics.clip_text``).
        scorers: from :func:`load_scorers` (any mapping of metric name to scorer,
            :class:`MetricUnavailable` or None); None: no scorer is configured.
        reference_reason: why there is no reference, for PSNR, MAE and LPIPS.
        true_render: the true render ``(H, W, 3)``, if any.
        object_mask: the object's pixels ``(H, W)``, where ``psnr_true`` is scored.
        generated_path: the saved image, handed to ImageReward as is.
        protocol: the evaluation protocol, ``"paper"`` or ``"authors"`` (config key
            ``metrics.protocol``).
        files: ``"png"`` (the images as given) or ``"jpeg"`` (config key ``metrics.files``): the
            generated image, the reference and the mask first go through the JPEG round trips of
            the authors' ``main.jpg``, ``blender.jpg`` and ``blender_mask.jpg``
            (:func:`~snell_bench.metrics.files.evaluated_files`), for every metric, CLIP and
            ImageReward included; the true render and ``object_mask`` stay as given.
        lpips_box_range: the input range of ``lpips_box`` (``authors`` only; config key
            ``metrics.lpips_box_range``, :func:`~snell_bench.metrics.fidelity.authors_lpips_box`).
        reference_is_jpeg: the reference already decodes the JPEG its renderer wrote (the Cycles
            reference, the authors' ``blender.jpg``): ``files="jpeg"`` does not encode it again.
        extra: users' metrics (``metrics.extra``: names of installed metrics or dotted paths,
            :func:`~snell_bench.metrics.registry.load_metric`), scored after the built-in ones.

    Returns:
        ``{"metrics": {name: float | None}, "missing": {name: reason}, "notes": {name: note},
        "protocol": protocol}``: the names of ``metric_names(protocol)`` in order (``lpips_box``
        under ``"authors"`` only), then ``psnr_true`` when ``true_render`` is given.

    Raises:
        ValueError: ``true_render`` without ``object_mask``; an unknown ``protocol``, ``files`` or
            ``lpips_box_range`` (the message names the config key and the allowed values).
    """
    check_protocol(protocol)
    check_box_range(lpips_box_range)
    if true_render is not None and object_mask is None:
        raise ValueError("score_cell: true_render needs the object_mask it is scored over")
    scorers = scorers if isinstance(scorers, Scorers) else Scorers(scorers or {})
    gen, reference, mask, path = _as_scored(generated, reference, mask, generated_path, files, reference_is_jpeg)
    inputs = ScoreInputs(
        gen,
        reference,
        mask,
        prompt,
        object_mask=object_mask,
        true_render=true_render,
        protocol=protocol,
        scorers=scorers,
        generated_path=path,
        lpips_box_range=lpips_box_range,
    )
    metrics, missing = compute_metrics(metrics_for(protocol, extra), inputs, reference_reason=reference_reason)
    notes = _finite(metrics, missing)
    return {"metrics": metrics, "missing": missing, "notes": notes, "protocol": protocol}
