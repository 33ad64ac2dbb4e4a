"""The metric registry: one spec per metric, read by scoring and every table; users' metrics by a
dotted path or an entry point."""

import math

import numpy as np
import pytest

from snell_bench.metrics import MetricUnavailable, masked_mae, masked_psnr, score_cell
from snell_bench.metrics.registry import (
    BUILTIN_METRICS,
    MetricSpec,
    ScoreInputs,
    compute_metrics,
    load_metric,
    metric_spec,
    metrics_for,
)


def _mean_abs(x):
    return float(np.abs(np.asarray(x.generated) - np.asarray(x.reference))[np.asarray(x.mask, bool)].mean())


#: A user's metric, named by its dotted path in metrics.extra.
ABS = MetricSpec("abs_rgb", "|RGB| error", False, "{:.5f}", _mean_abs, description="mean |RGB error| in the mask")


def _empty(x):
    raise MetricUnavailable("nothing to score here")


EMPTY = MetricSpec("never", "Never", True, compute=_empty)


@pytest.fixture
def pair():
    rng = np.random.default_rng(0)
    gen, ref = rng.random((24, 32, 3)), rng.random((24, 32, 3))
    mask = np.zeros((24, 32), bool)
    mask[4:20, 6:26] = True
    return gen, ref, mask


def test_the_built_in_metrics_in_record_order():
    assert [m.name for m in BUILTIN_METRICS] == [
        "psnr",
        "mae",
        "lpips",
        "lpips_box",
        "clip",
        "image_reward",
        "psnr_true",
    ]
    assert [m.name for m in metrics_for("paper")] == ["psnr", "mae", "lpips", "clip", "image_reward", "psnr_true"]
    assert "lpips_box" in [m.name for m in metrics_for("authors")]
    assert metric_spec("psnr").fmt(24.123) == "24.12" and metric_spec("mae").arrow == "↓"
    assert metric_spec("psnr").fmt(None) == metric_spec("psnr").fmt(math.nan) == "—"


def test_derived_and_unknown_columns_get_a_spec():
    conv = metric_spec("psnr_converged")
    assert conv.label == "PSNR (conv.)" and conv.higher_is_better and conv.compute is None
    other = metric_spec("something_else")
    assert other.label == "something_else" and other.source == "unknown"


def test_a_users_metric_is_scored_after_the_built_in_ones(pair):
    gen, ref, mask = pair
    res = score_cell(gen, ref, mask, "p", {}, extra=[f"{__name__}:ABS", f"{__name__}:EMPTY"])
    assert list(res["metrics"])[-2:] == ["abs_rgb", "never"]
    assert res["metrics"]["abs_rgb"] == float(np.abs(gen - ref)[mask].mean())  # an independent reference
    assert res["metrics"]["never"] is None and res["missing"]["never"] == "nothing to score here"
    assert res["metrics"]["psnr"] == masked_psnr(gen, ref, mask) and res["metrics"]["mae"] == masked_mae(gen, ref, mask)


def test_a_users_metric_without_the_reference_it_needs_is_missing_with_the_reason(pair):
    gen, _, _ = pair
    res = score_cell(gen, None, None, "p", {}, reference_reason="reference.enabled=false", extra=[f"{__name__}:ABS"])
    assert res["metrics"]["abs_rgb"] is None and res["missing"]["abs_rgb"] == "reference.enabled=false"


def test_bad_entries_name_metrics_extra():
    with pytest.raises(ValueError, match="metrics.extra: unknown metric 'nope'"):
        load_metric("nope")
    with pytest.raises(ValueError, match="metrics.extra: 'no_such_module:X' cannot be loaded"):
        load_metric("no_such_module:X")
    with pytest.raises(ValueError, match="not a snell_bench.metrics.MetricSpec"):
        load_metric(f"{__name__}:_mean_abs")


def test_specs_are_checked_when_made():
    with pytest.raises(ValueError, match="unknown needs"):
        MetricSpec("x", "X", True, needs=("weights",))
    with pytest.raises(ValueError, match="is not a column name"):
        MetricSpec("x y", "X", True)
    with pytest.raises(ValueError, match="cannot print a number"):
        MetricSpec("x", "X", True, format="{:d}")


def test_a_metric_needing_the_true_render_is_left_out_without_one(pair):
    gen, ref, mask = pair
    specs = metrics_for("paper")
    metrics, _ = compute_metrics(specs, ScoreInputs(gen, ref, mask, "p"))
    assert "psnr_true" not in metrics
    metrics, _ = compute_metrics(specs, ScoreInputs(gen, ref, mask, "p", object_mask=mask, true_render=gen))
    assert metrics["psnr_true"] == math.inf  # identical pixels (score_cell records the ceiling)


def test_an_installed_metric_is_found_by_its_entry_point(tmp_path, monkeypatch):
    """An entry point of snell_bench.metrics, as a pip-installed plugin declares it."""
    from plugins import installed_plugin

    from snell_bench.metrics import registry

    source = (
        "from snell_bench.metrics import MetricSpec\n"
        "SPEC = MetricSpec('tmp_name', 'Plugged', False, '{:.1f}', lambda x: 1.5)\n"
    )
    caches = [registry._entry_points, registry.load_metric]
    with installed_plugin(
        tmp_path, monkeypatch, "plug_metrics", source, {"snell_bench.metrics": "plugged = plug_metrics:SPEC"}, caches
    ):
        assert "plugged" in registry.installed_metrics()
        spec = load_metric("plugged")
        assert spec.name == "plugged" and spec.label == "Plugged" and "entry point" in spec.source
        assert metric_spec("plugged").label == "Plugged"
