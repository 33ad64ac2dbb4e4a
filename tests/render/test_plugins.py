"""The Mitsuba plugins written in Python: the pinhole sensor's camera conventions (square and
non-square pixels, crop windows) and the refraction-only glass's choice of lobes."""

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


class TestRefractionOnlyBSDF:
    @staticmethod
    def _sample(m, origin_z, sample1):
        """A ray along +z that hits the surface z = 3 (normal towards the camera) from the outside,
        started at ``z = origin_z``: whether the plugin transmits it, the weight, the direction."""
        from snell_bench.render.plugins import REFRACTION_ONLY_BSDF

        bsdf = m.load_dict({"type": REFRACTION_ONLY_BSDF, "int_ior": 1.5, "ext_ior": 1.0, "camera_z": 1.0})
        si = m.SurfaceInteraction3f()
        si.p = m.Point3f(0.1, 0.2, 3.0)
        si.n = m.Normal3f(0.0, 0.0, -1.0)
        si.sh_frame = m.Frame3f(si.n)
        si.wi = m.Vector3f(0.0, 0.0, 1.0)  # local: back along the ray, towards -z
        si.t = 3.0 - origin_z
        bs, weight = bsdf.sample(m.BSDFContext(), si, sample1, m.Point2f(0.5, 0.5))
        return m.has_flag(bs.sampled_type, m.BSDFFlags.DeltaTransmission), np.array(weight), np.array(bs.wo)

    @pytest.mark.parametrize("sample1", [0.0, 0.01, 0.5, 0.999])
    def test_camera_rays_always_transmit_with_unit_weight(self, sample1):
        """A ray from the near clip plane (z = 0.01 < camera_z): transmitted whatever the sample,
        weight 1 up to the radiance's solid-angle factor 1 / 1.5^2 (undone on the way out)."""
        m = set_variant()
        transmitted, weight, wo = self._sample(m, 0.01, sample1)
        assert transmitted
        np.testing.assert_allclose(weight, 1.0 / 1.5**2, rtol=1e-6)
        np.testing.assert_allclose(wo, [0.0, 0.0, -1.0], atol=1e-7)

    def test_other_rays_meet_the_dielectric(self):
        """A ray from a surface (z = 2.5 > camera_z): Mitsuba's dielectric, which reflects iff the
        sample is below F(0) = ((1.5 - 1) / (1.5 + 1))^2 = 0.04."""
        m = set_variant()
        F0 = ((1.5 - 1.0) / (1.5 + 1.0)) ** 2
        assert not self._sample(m, 2.5, F0 - 1e-3)[0]
        assert self._sample(m, 2.5, F0 + 1e-3)[0]
