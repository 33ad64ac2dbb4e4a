"""Scene pieces: the sensor of a camera (field of view, principal point, crop window, sampler) and
the choice between Mitsuba's perspective sensor and the pinhole plugin."""

import math

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")

from render_testing import forced_cpu_variant  # noqa: E402

from snell_bench.render.pieces import sensor  # noqa: E402
from snell_bench.render.variants import set_variant  # noqa: E402
from snell_bench.scene.camera import Camera  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def cpu_variant():
    with forced_cpu_variant():
        yield


class TestSensor:
    def test_field_of_view_principal_point_and_crop(self):
        K = np.array([[80.0, 0.0, 40.0], [0.0, 80.0, 20.0], [0.0, 0.0, 1.0]])
        cam = Camera(K=K, width=96, height=64)
        m = set_variant()
        d = sensor(m, cam, 4, 0.01, 100.0, rect=(1, 2, 5, 9))
        assert d["fov"] == pytest.approx(math.degrees(2 * math.atan(96 / 160)))
        assert d["principal_point_offset_x"] == pytest.approx((47.5 - 40.0) / 96)
        assert d["principal_point_offset_y"] == pytest.approx((31.5 - 20.0) / 64)
        film = d["film"]
        assert (film["width"], film["height"]) == (96, 64)
        assert (film["crop_offset_x"], film["crop_offset_y"], film["crop_width"], film["crop_height"]) == (1, 2, 4, 7)
        assert d["sampler"]["sample_count"] == 4
        assert "crop_width" not in sensor(m, cam, 4, 0.01, 100.0)["film"]

    def test_square_pixels_use_perspective_others_the_pinhole(self):
        m = set_variant()
        K = np.array([[80.0, 0.0, 40.0], [0.0, 80.0, 20.0], [0.0, 0.0, 1.0]])
        assert sensor(m, Camera(K=K, width=96, height=64), 4, 0.01, 100.0)["type"] == "perspective"
        for i, j, v in ((1, 1, 80.001), (0, 1, 0.5)):
            K2 = K.copy()
            K2[i, j] = v
            d = sensor(m, Camera(K=K2, width=96, height=64), 4, 0.01, 100.0, rect=(1, 2, 5, 9))
            assert d["type"] == "snell_pinhole" and d["film"]["crop_width"] == 4
