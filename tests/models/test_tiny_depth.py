"""The tiny depth stand-in's floor: a level plane below the camera in front of the random network."""

import numpy as np
import pytest

from snell_bench.models.tiny_depth import TinyDepthWithFloor, floor_depth, tiny_depth_pro


def test_floor_depth_back_projects_onto_the_plane_y_equals_floor_m():
    K = (80.0, 70.0, 47.5, 31.5)
    z = floor_depth(64, 96, K, 0.5)
    v = np.arange(64, dtype=np.float64)[:, None].repeat(96, axis=1)
    below = v > K[3]
    assert np.isinf(z[~below]).all()  # on and above the horizon the floor is never seen
    y = (v[below] - K[3]) * z[below].astype(np.float64) / K[1]
    # float32 depth: relative error <= 2^-24 per value, so y within 0.5 * 2^-23 of 0.5
    np.testing.assert_allclose(y, 0.5, rtol=2.0**-23)


def test_the_floor_stands_in_front_of_the_network_and_keeps_its_intrinsics():
    img = np.random.default_rng(0).random((64, 96, 3)).astype(np.float32)
    plain, floored = tiny_depth_pro(seed=0)(img), tiny_depth_pro(seed=0, floor_m=0.5)(img)
    assert floored.intrinsics == plain.intrinsics
    expected = np.fmin(plain.depth, floor_depth(64, 96, plain.intrinsics, 0.5))
    np.testing.assert_array_equal(floored.depth, expected)
    assert (floored.depth < plain.depth).any()  # some rows see the floor


def test_a_floor_must_lie_below_the_camera():
    with pytest.raises(ValueError, match="floor_m"):
        tiny_depth_pro(seed=0, floor_m=0.0)
    assert issubclass(TinyDepthWithFloor, object)
