"""Image metrics: masked fidelity (PSNR, MAE, LPIPS) and text-image alignment (CLIP, ImageReward).

- :mod:`~snell_bench.metrics.functional`: masked PSNR and MAE as pure functions, grayscale, masked
  histogram matching, the protocols; :mod:`~snell_bench.metrics.authors` (the authors' evaluation)
  and :mod:`~snell_bench.metrics.common` (the protocol check, :class:`MetricUnavailable`) behind it.
- :mod:`~snell_bench.metrics.fidelity`: their class forms (batch accumulators) and masked LPIPS.
- :mod:`~snell_bench.metrics.alignment`: CLIP score, ImageReward and :func:`score_all`.
- :mod:`~snell_bench.metrics.registry`: one :class:`MetricSpec` per metric (label, direction, format,
  what it needs, how it is computed), read by scoring, every table, page and plot; users' metrics
  plug in by the ``snell_bench.metrics`` entry point or a dotted path (``metrics.extra``).
- :mod:`~snell_bench.metrics.scoring`: the scorers of a run and :func:`score_cell`.
- :mod:`~snell_bench.metrics.refraction`: the object region against π^R(I⁻).

Conventions:
    - Images: float tensors ``(B, 3, H, W)`` (``B == 1`` for the functional forms) or numpy
      ``(H, W, 3)``, sRGB-encoded, in [0, 1]. Masks: bool ``(H, W)`` or ``(B, 1, H, W)``.
    - Protocol (config key ``metrics.protocol``): ``"paper"`` (the paper's text, the default):
      grayscale ``0.299 R + 0.587 G + 0.114 B``; inside the mask the generated image's histogram is
      matched to the reference's; PSNR ``= 10 log10(1 / MSE)`` and MAE over the mask; LPIPS (VGG) of
      the RGB images, its spatial map averaged over the mask. ``"authors"`` (the authors' released
      ``eval/masked_metrics.py``, reproduced on the 8-bit images snell_bench writes): their 256-bin
      matching in float32 (:func:`authors_metrics`), ``lpips`` the spatial LPIPS of the images
      multiplied by the mask averaged over the mask, and ``lpips_box`` (this protocol only) the plain
      LPIPS of the mask's bounding box. Both: CLIP score
      ``= 100 max(cos, 0)`` with ViT-B/16 and ImageReward, on the text the caller passes (the full
      prompt or the object phrase, config key ``metrics.clip_text``).
    - Every metric returns a ``float`` or raises :class:`MetricUnavailable` with a reason (empty
      mask; weights or program not configured, naming the config key). :func:`score_all` collects
      them as ``{"metrics": {name: float | None}, "missing": {name: reason}}``; :func:`score_cell`
      adds ``"protocol"``.
    - An experiment builds its scorers once with :func:`load_scorers` (a scorer that cannot be
      built is kept with its reason) and scores each cell with :func:`score_cell` (also without a
      reference, and against the true render).
"""

from .alignment import (
    AUTHORS_ONLY_METRICS,
    IMAGE_REWARD_WORKER,
    METRIC_NAMES,
    CLIPScore,
    ImageRewardScorer,
    ScoreResult,
    metric_names,
    resolve_clip_checkpoint,
    score_all,
)
from .fidelity import MaskedLPIPS, MaskedMAE, MaskedPSNR, authors_lpips, authors_lpips_box, masked_lpips
from .functional import (
    EMPTY_MASK_REASON,
    GRAY_WEIGHTS,
    NON_FINITE_REASON,
    PROTOCOL_CONFIG_KEY,
    PROTOCOLS,
    AuthorsScores,
    MetricUnavailable,
    authors_histogram_matching,
    authors_metrics,
    check_protocol,
    masked_mae,
    masked_psnr,
    match_histogram_masked,
    quantize_8bit,
    to_gray,
)
from .registry import (
    BUILTIN_METRICS,
    MetricSpec,
    ScoreInputs,
    compute_metrics,
    installed_metrics,
    load_metric,
    metric_spec,
    metrics_for,
)
from .scoring import (
    PROMPT_METRICS,
    PSNR_CEILING_DB,
    REFERENCE_METRICS,
    SCORER_NAMES,
    CellScores,
    Scorers,
    load_scorers,
    reference_metrics,
    score_cell,
)

__all__ = [
    "AUTHORS_ONLY_METRICS",
    "BUILTIN_METRICS",
    "MetricSpec",
    "ScoreInputs",
    "compute_metrics",
    "installed_metrics",
    "load_metric",
    "metric_spec",
    "metrics_for",
    "AuthorsScores",
    "CLIPScore",
    "CellScores",
    "EMPTY_MASK_REASON",
    "GRAY_WEIGHTS",
    "IMAGE_REWARD_WORKER",
    "ImageRewardScorer",
    "METRIC_NAMES",
    "MaskedLPIPS",
    "MaskedMAE",
    "MaskedPSNR",
    "MetricUnavailable",
    "NON_FINITE_REASON",
    "PROMPT_METRICS",
    "PROTOCOLS",
    "PSNR_CEILING_DB",
    "PROTOCOL_CONFIG_KEY",
    "REFERENCE_METRICS",
    "SCORER_NAMES",
    "ScoreResult",
    "Scorers",
    "authors_histogram_matching",
    "authors_lpips",
    "authors_lpips_box",
    "authors_metrics",
    "check_protocol",
    "load_scorers",
    "masked_lpips",
    "masked_mae",
    "masked_psnr",
    "match_histogram_masked",
    "metric_names",
    "quantize_8bit",
    "reference_metrics",
    "resolve_clip_checkpoint",
    "score_all",
    "score_cell",
    "to_gray",
]
