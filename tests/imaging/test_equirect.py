"""The single equirectangular convention."""

import math

import numpy as np
import pytest
import torch

from snell_bench.imaging.equirect import PanoramaCamera, direction_to_equirect, equirect_grid, equirect_to_direction


def test_round_trip_numpy_and_torch():
    uv = equirect_grid(32)
    d = equirect_to_direction(uv, 32)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0)
    np.testing.assert_allclose(direction_to_equirect(d, 32), uv, atol=1e-9)
    dt = equirect_to_direction(torch.from_numpy(uv), 32)
    np.testing.assert_allclose(dt.numpy(), d, atol=1e-12)
    np.testing.assert_allclose(direction_to_equirect(dt, 32).numpy(), uv, atol=1e-9)


@pytest.mark.parametrize(
    "d,uv",
    [
        ((0, 0, 1), (63.5, 31.5)),  # forward: the middle of the panorama
        ((1, 0, 0), (95.5, 31.5)),  # right: a quarter turn to the right
        ((-1, 0, 0), (31.5, 31.5)),  # left
        ((0, -1, 0), (None, -0.5)),  # up: the top edge
        ((0, 1, 0), (None, 63.5)),  # down: the bottom edge
    ],
)
def test_named_directions(d, uv):
    got = direction_to_equirect(np.array(d, float), 64)
    if uv[0] is not None:
        assert got[0] == pytest.approx(uv[0])
    assert got[1] == pytest.approx(uv[1])


def test_level_panorama_axes():
    up = np.array([0.0, -math.cos(0.3), -math.sin(0.3)])  # a camera pitched down by 0.3 rad
    p = PanoramaCamera.level([0, 0, 2.0], up, (0, 0, 1), 16)
    R = p.rotation
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(R[:, 1], -up)
    top = p.directions()[0]
    assert np.all(top @ up > math.cos(math.radians(180 / 16)))  # the top row looks up
    np.testing.assert_allclose(p.project_points(p.center + R[:, 2]), [15.5, 7.5], atol=1e-9)


def test_bad_rotation():
    with pytest.raises(ValueError, match="rotation"):
        PanoramaCamera(center=np.zeros(3), rotation=np.diag([1.0, 1.0, -1.0]), height=8)
