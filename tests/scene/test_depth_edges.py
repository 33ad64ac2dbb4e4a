"""MoGe's depth-edge cut (``depth.edge_rtol``, the authors' rtol 0.1) on depth maps with known steps."""

import itertools

import numpy as np
import pytest

from snell_bench.models.depth_base import cut_depth_edges, depth_edge_mask


def columns(values, rows=6):
    """A depth map whose every row is ``values``."""
    return np.tile(np.asarray(values, np.float64), (rows, 1))


def brute_force_edges(depth, rtol, k=3):
    """The rule written out pixel by pixel: spread over the window cut at the border, a missing
    neighbour infinitely far, relative to the pixel's own depth."""
    H, W = depth.shape
    r = k // 2
    out = np.zeros((H, W), bool)
    for y, x in itertools.product(range(H), range(W)):
        z = depth[y, x]
        if not (np.isfinite(z) and z > 0):
            continue
        win = depth[max(0, y - r) : y + r + 1, max(0, x - r) : x + r + 1]
        win = np.where(np.isfinite(win) & (win > 0), win, np.inf)
        out[y, x] = (win.max() - win.min()) / z > rtol
    return out


def test_a_small_step_cuts_only_its_near_side():
    """2.0 | 2.21: the near side's spread is 0.21 / 2 = 0.105 > 0.1, the far side's 0.21 / 2.21 =
    0.095 (both 5 % from the threshold, far beyond rounding)."""
    depth = columns([2.0] * 5 + [2.21] * 5)
    edge = depth_edge_mask(depth, 0.1)
    assert np.array_equal(edge, columns([0, 0, 0, 0, 1, 0, 0, 0, 0, 0]).astype(bool))


def test_a_large_step_cuts_both_sides():
    depth = columns([2.0] * 5 + [3.0] * 5)
    edge = depth_edge_mask(depth, 0.1)
    assert np.array_equal(edge, columns([0, 0, 0, 0, 1, 1, 0, 0, 0, 0]).astype(bool))


def test_a_steep_ramp_is_cut_where_it_changes_by_more_than_half_the_tolerance_per_pixel():
    """depth = 1 + 0.12 x: an interior pixel's spread is 0.24, cut while 0.24 > 0.1 (1 + 0.12 x),
    i.e. x < 11.67; the first column sees one neighbour (spread 0.12 > 0.1); the last, at depth
    4.48, is not cut (margins: 1.6 % at x = 12, 3 % at x = 11)."""
    x = np.arange(30)
    edge = depth_edge_mask(columns(1 + 0.12 * x), 0.1)
    assert np.array_equal(edge[0], x < 12)
    assert np.array_equal(edge, np.tile(edge[0], (6, 1)))


def test_missing_depth_cuts_its_neighbours_and_stays_missing():
    depth = np.full((7, 9), 2.0)
    depth[3, 4] = np.nan
    depth[0, 8] = 0.0  # not positive: missing too
    edge = depth_edge_mask(depth, 0.1)
    expect = np.zeros((7, 9), bool)
    expect[2:5, 3:6] = True
    expect[0:2, 7:9] = True
    expect[3, 4] = expect[0, 8] = False  # missing pixels are never edges
    assert np.array_equal(edge, expect)
    cut = cut_depth_edges(depth, 0.1)
    assert cut.dtype == np.float32
    assert np.array_equal(np.isnan(cut), edge | np.isnan(depth))
    assert cut[0, 8] == 0.0  # left as it was: already missing
    assert np.array_equal(cut_depth_edges(depth, None), depth.astype(np.float32), equal_nan=True)


@pytest.mark.parametrize("rtol", [0.02, 0.1, 0.5])
def test_it_matches_the_rule_written_out(rtol):
    rng = np.random.default_rng(3)
    depth = 2.0 + np.cumsum(rng.normal(0, 0.03, (23, 31)), axis=1)  # a rough surface
    depth[rng.random(depth.shape) < 0.05] *= 1.8  # scattered steps
    depth[rng.random(depth.shape) < 0.03] = np.nan
    assert np.array_equal(depth_edge_mask(depth, rtol), brute_force_edges(depth, rtol))


def test_bad_arguments_name_the_key():
    with pytest.raises(ValueError, match="depth.edge_rtol"):
        depth_edge_mask(np.ones((4, 4)), 0.0)
    with pytest.raises(ValueError, match="odd"):
        depth_edge_mask(np.ones((4, 4)), 0.1, kernel_size=2)
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        depth_edge_mask(np.ones(4), 0.1)
