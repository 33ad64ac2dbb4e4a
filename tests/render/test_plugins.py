"""The Mitsuba plugins written in Python: the pinhole sensor's camera conventions (square and
non-square pixels, crop windows)."""

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")

from render_testing import forced_cpu_variant  # noqa: E402
from tolerances import reordering_tolerance  # noqa: E402

from snell_bench.render.pieces import perspective_sensor, pinhole_sensor  # noqa: E402
from snell_bench.render.variants import set_variant  # noqa: E402
from snell_bench.scene.camera import Camera  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def cpu_variant():
    with forced_cpu_variant():
        yield


class TestPinholeSensor:
    @staticmethod
    def _rays(m, sensor_dict, samples):
        s = m.load_dict(sensor_dict)
        rays = [s.sample_ray_differential(0.0, 0.5, m.Point2f(*p), m.Point2f(0.5)) for p in samples]
        return (np.array([np.array(getattr(r, k)) for r, _ in rays]) for k in ("o", "d", "maxt"))

    def test_pinhole_with_square_pixels_casts_the_perspective_rays(self):
        """The same film samples (whole film and a crop window) give the same rays, up to float
        rounding, as Mitsuba's perspective sensor."""
        K = np.array([[80.0, 0.0, 40.3], [0.0, 80.0, 20.6], [0.0, 0.0, 1.0]])
        cam = Camera(K=K, width=96, height=64)
        m = set_variant()
        samples = np.random.default_rng(0).random((200, 2))
        for rect in (None, (5, 7, 30, 20)):
            args = (m, cam, 4, 0.01, 100.0, rect)
            o0, d0, t0 = self._rays(m, perspective_sensor(*args), samples)
            o1, d1, t1 = self._rays(m, pinhole_sensor(*args), samples)
            # two float32 paths to one unit direction: a 3x3 projection, a normalisation and the
            # sensor-to-world transform, each of at most 4 terms: 16 roundings of values <= 1
            np.testing.assert_allclose(d1, d0, atol=reordering_tolerance(16, d0))
            np.testing.assert_allclose(o1, o0, atol=reordering_tolerance(16, o0))
            np.testing.assert_allclose(t1, t0, rtol=1e-6)

    def test_pinhole_rays_are_those_of_the_camera(self):
        """fx != fy, skew, off-centre principal point, crop window: the film sample at the centre of
        pixel (x, y) casts ``Camera.pixel_rays((x, y))``, from z = near_clip to z = far_clip."""
        K = np.array([[80.0, 3.0, 41.7], [0.0, 93.5, 27.2], [0.0, 0.0, 1.0]])
        cam = Camera(K=K, width=96, height=64)
        m = set_variant()
        x0, y0, x1, y1 = rect = (5, 7, 30, 20)
        px = np.random.default_rng(1).uniform([x0 - 0.5, y0 - 0.5], [x1 - 0.5, y1 - 0.5], (200, 2))
        samples = (px + 0.5 - [x0, y0]) / [x1 - x0, y1 - y0]
        o, d, t = self._rays(m, pinhole_sensor(m, cam, 4, 0.01, 100.0, rect), samples)
        np.testing.assert_allclose(d, cam.pixel_rays(px), atol=reordering_tolerance(16, d))  # float32 vs float64
        np.testing.assert_allclose(o[:, 2], 0.01, rtol=1e-6)
        np.testing.assert_allclose(o, d * (0.01 / d[:, 2:]), atol=1e-8)
        np.testing.assert_allclose((o + t[:, None] * d)[:, 2], 100.0, rtol=1e-5)
