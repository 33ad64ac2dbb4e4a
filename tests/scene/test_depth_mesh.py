"""Depth map to background mesh."""

import logging

import numpy as np
import pytest

from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import bounding_box_mesh, build_background, depth_to_mesh


@pytest.fixture
def cam():
    return Camera.from_fov(40, 30, 60)


def test_plane_mesh(cam):
    v, f, info = depth_to_mesh(np.full(cam.shape, 2.0), cam)
    assert v.shape == (30 * 40, 3) and len(f) == 2 * 29 * 39
    assert info == {"invalid_pixels": 0, "excluded_pixels": 0, "cut_triangles": 0}
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    n = np.cross(b - a, c - a)
    assert np.all(n[:, 2] < 0)  # every triangle faces the camera
    np.testing.assert_allclose(v[:, 2], 2.0)


def test_cut_at_depth_discontinuity(cam):
    depth = np.full(cam.shape, 2.0)
    depth[:, 20:] = 4.0  # a step: 29 quads straddle it, 2 triangles each
    _, f, info = depth_to_mesh(depth, cam, edge_threshold=0.05)
    assert info["cut_triangles"] == 2 * 29
    _, f2, info2 = depth_to_mesh(depth, cam, edge_threshold=1.5)  # a threshold above the jump keeps them
    assert info2["cut_triangles"] == 0 and len(f2) == len(f) + 58


def test_invalid_depth_is_dropped_and_counted(cam, caplog):
    depth = np.full(cam.shape, 2.0)
    depth[5, 5], depth[6, 6], depth[7, 7], depth[8, 8] = np.nan, np.inf, 0.0, -3.0
    with caplog.at_level(logging.WARNING):
        v, f, info = depth_to_mesh(depth, cam)
    assert info["invalid_pixels"] == 4 and "4 of 1200 pixels are invalid" in caplog.text
    bad = [5 * 40 + 5, 6 * 40 + 6, 7 * 40 + 7, 8 * 40 + 8]
    assert not np.isin(f, bad).any()
    assert np.isfinite(v).all()


def test_bad_depth_inputs(cam):
    with pytest.raises(ValueError, match="no valid pixel"):
        depth_to_mesh(np.zeros(cam.shape), cam)
    with pytest.raises(ValueError, match="camera's"):
        depth_to_mesh(np.ones((3, 3)), cam)
    with pytest.raises(ValueError, match="2-D"):
        depth_to_mesh(np.ones((30, 40, 1)), cam)


def test_bounding_box_is_closed_and_contains_everything(cam):
    import trimesh

    v, f = bounding_box_mesh(np.array([[0, 0, 0], [1, 2, 3.0]]), margin=0.1)
    box = trimesh.Trimesh(v, f)
    assert box.is_watertight
    bg = build_background(np.full(cam.shape, 2.0), cam, extra_points=np.array([[5.0, 0, 1]]))
    lo, hi = bg.box_vertices.min(0), bg.box_vertices.max(0)
    assert np.all(lo < [0, 0, 0]) and hi[0] > 5.0 and hi[2] > 2.0
