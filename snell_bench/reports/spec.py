"""What the report tables show: table layouts; the metrics' labels, directions and print formats come
from the metric registry (:mod:`snell_bench.metrics.registry`)."""

from __future__ import annotations

from snell_bench.metrics.registry import BUILTIN_METRICS, MISSING, MetricSpec, metric_spec

__all__ = [
    "Metric",
    "METRICS",
    "TABLE1_METRICS",
    "ABLATION_METRICS",
    "ABLATION_ROWS",
    "ABLATION_TABLE2_METRICS",
    "SCENE_METRICS",
    "OPTIONAL_METRICS",
    "TIME_TRAVEL_ROWS",
    "TIME_TRAVEL_VARIANTS",
    "MODEL_DESCRIPTIONS",
    "MEASURES",
    "MISSING",
    "metric_spec",
]

Metric = MetricSpec
"""How a metric is labelled, compared and printed: :class:`~snell_bench.metrics.registry.MetricSpec`."""

METRICS: dict[str, Metric] = {m.name: m for m in BUILTIN_METRICS}
"""The built-in metrics of ``metrics.json`` (:data:`~snell_bench.metrics.registry.BUILTIN_METRICS`):
label, direction and print format; a user's metric is found by :func:`metric_spec`."""

MEASURES: dict[str, Metric] = {
    m.name: m
    for m in (
        Metric("model_calls.main", "model calls", False, "{:.0f}"),
        Metric("timings_s.sampling", "sampling (s)", False, "{:.1f}"),
    )
}
"""Columns shown beside the metrics that are costs, not scores: printed, never ranked."""

TABLE1_METRICS = ("clip", "image_reward", "psnr", "lpips")
"""Columns of the paper's Table 1, in its order."""

ABLATION_METRICS = ("mae", "psnr", "lpips", "clip", "image_reward")
"""Columns of the ablation with every metric (Table 4), in the paper's order."""

ABLATION_TABLE2_METRICS = ("mae", "psnr", "lpips")
"""Columns of the paper's ablation table (Table 2), in its order."""

SCENE_METRICS = ("clip", "image_reward", "psnr", "lpips")
"""Columns of the per-scene table (Table 3), in the paper's order."""

OPTIONAL_METRICS = ("lpips_box", "mae", "psnr_true")
"""Metrics added after a table's own columns where the cells record them: ``lpips_box`` (the
bounding-box LPIPS of the authors' protocol) wherever any cell records the key, ``mae`` and
``psnr_true`` where any ``ok`` cell has a value."""

ABLATION_ROWS: tuple[tuple[str, str], ...] = (
    ("snellcaster", "Full"),
    ("no_reflection", "w/o reflection"),
    ("no_pano", "w/o panorama"),
    ("no_dpa", "w/o DPA"),
    ("no_lpw", "w/o LPW"),
    ("no_tt", "w/o time travel"),
    ("snellcaster_relit", "w/ relighting"),
)
"""Ablation rows in the paper's order: (method name, row label)."""

TIME_TRAVEL_VARIANTS: tuple[tuple[str, str], ...] = (
    ("joint", "joint (R_pano = R_main)"),
    ("main_only", "main only (R_pano = 1)"),
)
"""The time-travel experiment's variants: (key, legend label)."""

TIME_TRAVEL_ROWS: tuple[tuple[str, tuple[str, ...], int], ...] = (
    ("tt_r1", ("joint", "main_only"), 1),
    ("tt_joint_r3", ("joint",), 3),
    ("tt_joint_r5", ("joint",), 5),
    ("tt_joint_r8", ("joint",), 8),
    ("tt_main_r3", ("main_only",), 3),
    ("tt_main_r5", ("main_only",), 5),
    ("tt_main_r8", ("main_only",), 8),
)
"""The time-travel experiment's methods: (method name, the variants it belongs to, R_main). R = 1
(no repeat) is the same run for both variants."""

MODEL_DESCRIPTIONS = {
    "analytic": "CPU stand-in for FLUX",
    "tiny_flux": "tiny random-weight FLUX, outputs meaningless",
    "flux": "FLUX.1-dev",
}
"""What each ``model`` value of ``metrics.json`` is, for provenance lines."""
