"""The relighting scores against hand-built truths: a shadow disc and a caustic spot."""

import math

import numpy as np
import pytest

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear
from snell_bench.metrics.relighting import relight_region, relight_scores

H, W = 40, 60


def _scene(shadow_at=(20, 20), spot_at=(20, 40)):
    before = np.full((H, W, 3), 0.5, np.float32)
    lin = srgb_to_linear(before).astype(np.float64)
    v, u = np.mgrid[0:H, 0:W]
    lin[(v - shadow_at[0]) ** 2 + (u - shadow_at[1]) ** 2 <= 36] *= 0.3  # a shadow: 70 % darker
    lin[(v - spot_at[0]) ** 2 + (u - spot_at[1]) ** 2 <= 4] *= 1.8  # a caustic: 80 % brighter
    return before, linear_to_srgb(lin.astype(np.float32))


def test_the_truth_itself_scores_perfectly():
    before, truth = _scene()
    s = relight_scores(truth, before, truth, before, np.ones((H, W), bool))
    assert s["psnr_region"] == math.inf and s["psnr_ratio"] == math.inf
    assert s["shadow_iou"] == 1.0 and s["caustic_energy_error"] == 0.0 and s["caustic_centroid_px"] == 0.0
    assert s["region_px"] == int(relight_region(truth, before, np.ones((H, W), bool)).sum()) > 100


def test_no_relighting_misses_shadow_and_caustic_and_a_shift_moves_the_centroid():
    before, truth = _scene()
    none = relight_scores(before, before, truth, before, np.ones((H, W), bool))
    assert none["shadow_iou"] == 0.0 and none["caustic_energy_error"] == 1.0 and none["caustic_centroid_px"] is None
    _, shifted = _scene(shadow_at=(20, 23), spot_at=(20, 43))
    s = relight_scores(shifted, before, truth, before, np.ones((H, W), bool))
    assert s["caustic_centroid_px"] == pytest.approx(3.0, abs=1e-9)
    assert s["caustic_energy_error"] == pytest.approx(0.0, abs=1e-9)
    # the discs of radius 6 shifted by 3: the intersection over union of two lattice discs
    v, u = np.mgrid[0:H, 0:W]
    a, b = (v - 20) ** 2 + (u - 20) ** 2 <= 36, (v - 20) ** 2 + (u - 23) ** 2 <= 36
    assert s["shadow_iou"] == pytest.approx((a & b).sum() / (a | b).sum())


def test_an_empty_region_is_refused():
    before, _ = _scene()
    with pytest.raises(ValueError, match="nothing to score"):
        relight_scores(before, before, before, before, np.ones((H, W), bool))
