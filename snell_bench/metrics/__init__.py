"""Image metrics: masked fidelity (PSNR, MAE, LPIPS) and text-image alignment (CLIP, ImageReward).

Conventions:
    - Images: float tensors ``(B, 3, H, W)`` (``B == 1`` for the functional forms) or numpy
      ``(H, W, 3)``, sRGB-encoded, in [0, 1]. Masks: bool ``(H, W)`` or ``(B, 1, H, W)``.
    - Protocol: grayscale ``0.299 R + 0.587 G + 0.114 B``; inside the mask the generated image's
      histogram is matched to the reference's; PSNR ``= 10 log10(1 / MSE)`` and MAE over the mask;
      LPIPS (VGG) averaged over the mask of its spatial map; CLIP score ``= 100 max(cos, 0)`` with
      ViT-B/16 on the full prompt; ImageReward on the full prompt.
    - Every metric returns a ``float`` or raises :class:`MetricUnavailable` with a reason (empty
      mask; weights or program not configured, naming the config key). :func:`score_all` collects
      them as ``{"metrics": {name: float | None}, "missing": {name: reason}}``.
    - An experiment builds its scorers once with :func:`load_scorers` (a scorer that cannot be
      built is kept with its reason) and scores each cell with :func:`score_cell` (also without a
      reference, and against the true render).
"""

from .alignment import (
    IMAGE_REWARD_WORKER,
    METRIC_NAMES,
    CLIPScore,
    ImageRewardScorer,
    ScoreResult,
    resolve_clip_checkpoint,
    score_all,
)
from .fidelity import (
    EMPTY_MASK_REASON,
    GRAY_WEIGHTS,
    MaskedLPIPS,
    MaskedMAE,
    MaskedPSNR,
    MetricUnavailable,
    masked_mae,
    masked_psnr,
    match_histogram_masked,
    to_gray,
)
from .scoring import PROMPT_METRICS, REFERENCE_METRICS, SCORER_NAMES, Scorers, load_scorers, score_cell

__all__ = [
    "CLIPScore",
    "EMPTY_MASK_REASON",
    "GRAY_WEIGHTS",
    "IMAGE_REWARD_WORKER",
    "ImageRewardScorer",
    "METRIC_NAMES",
    "MaskedLPIPS",
    "MaskedMAE",
    "MaskedPSNR",
    "MetricUnavailable",
    "PROMPT_METRICS",
    "REFERENCE_METRICS",
    "SCORER_NAMES",
    "ScoreResult",
    "Scorers",
    "load_scorers",
    "masked_mae",
    "masked_psnr",
    "match_histogram_masked",
    "resolve_clip_checkpoint",
    "score_all",
    "score_cell",
    "to_gray",
]
