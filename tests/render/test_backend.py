"""The Mitsuba back end: choosing the variant (forced by the environment, or probed in a
subprocess) and the sensors' camera conventions (square and non-square pixels)."""

import math

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")

from render_testing import forced_cpu_variant  # noqa: E402

from snell_bench.render import backend  # noqa: E402
from snell_bench.render.backend import VARIANT_ENV, mitsuba_variant  # noqa: E402
from snell_bench.scene.camera import Camera  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def cpu_variant():
    with forced_cpu_variant():
        yield


class TestVariant:
    def test_environment_forces_a_variant(self, monkeypatch):
        monkeypatch.setenv(VARIANT_ENV, "scalar_rgb")
        assert mitsuba_variant() == "scalar_rgb"
        monkeypatch.setenv(VARIANT_ENV, "no_such_variant")
        with pytest.raises(ValueError, match="not a Mitsuba variant"):
            mitsuba_variant()

    def test_probe_returns_a_working_variant(self, monkeypatch):
        """The LLVM variant is tried in a subprocess: a broken JIT backend aborts that process, not
        this one, and the scalar variant is used instead."""
        monkeypatch.delenv(VARIANT_ENV, raising=False)
        monkeypatch.setattr(backend, "_probed_variant", None)
        variant = mitsuba_variant()
        assert variant in ("llvm_ad_rgb", "scalar_rgb")

        def no_second_probe(v):
            raise AssertionError("the probe result is memoized")

        monkeypatch.setattr(backend, "_probe", no_second_probe)
        assert mitsuba_variant() == variant
        # and it renders here, in this process
        monkeypatch.setenv(VARIANT_ENV, variant)
        backend.probe_render()


class TestSensor:
    def test_field_of_view_principal_point_and_crop(self):
        K = np.array([[80.0, 0.0, 40.0], [0.0, 80.0, 20.0], [0.0, 0.0, 1.0]])
        cam = Camera(K=K, width=96, height=64)
        m = backend.set_variant()
        d = backend.sensor(m, cam, 4, 0.01, 100.0, rect=(1, 2, 5, 9))
        assert d["fov"] == pytest.approx(math.degrees(2 * math.atan(96 / 160)))
        assert d["principal_point_offset_x"] == pytest.approx((47.5 - 40.0) / 96)
        assert d["principal_point_offset_y"] == pytest.approx((31.5 - 20.0) / 64)
        film = d["film"]
        assert (film["width"], film["height"]) == (96, 64)
        assert (film["crop_offset_x"], film["crop_offset_y"], film["crop_width"], film["crop_height"]) == (1, 2, 4, 7)
        assert d["sampler"]["sample_count"] == 4
        assert "crop_width" not in backend.sensor(m, cam, 4, 0.01, 100.0)["film"]

    def test_square_pixels_use_perspective_others_the_pinhole(self):
        m = backend.set_variant()
        K = np.array([[80.0, 0.0, 40.0], [0.0, 80.0, 20.0], [0.0, 0.0, 1.0]])
        assert backend.sensor(m, Camera(K=K, width=96, height=64), 4, 0.01, 100.0)["type"] == "perspective"
        for i, j, v in ((1, 1, 80.001), (0, 1, 0.5)):
            K2 = K.copy()
            K2[i, j] = v
            d = backend.sensor(m, Camera(K=K2, width=96, height=64), 4, 0.01, 100.0, rect=(1, 2, 5, 9))
            assert d["type"] == "snell_pinhole" and d["film"]["crop_width"] == 4

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
        m = backend.set_variant()
        samples = np.random.default_rng(0).random((200, 2))
        for rect in (None, (5, 7, 30, 20)):
            args = (m, cam, 4, 0.01, 100.0, rect)
            o0, d0, t0 = self._rays(m, backend.perspective_sensor(*args), samples)
            o1, d1, t1 = self._rays(m, backend.pinhole_sensor(*args), samples)
            np.testing.assert_allclose(d1, d0, atol=1e-6)
            np.testing.assert_allclose(o1, o0, atol=1e-8)
            np.testing.assert_allclose(t1, t0, rtol=1e-6)

    def test_pinhole_rays_are_those_of_the_camera(self):
        """fx != fy, skew, off-centre principal point, crop window: the film sample at the centre of
        pixel (x, y) casts ``Camera.pixel_rays((x, y))``, from z = near_clip to z = far_clip."""
        K = np.array([[80.0, 3.0, 41.7], [0.0, 93.5, 27.2], [0.0, 0.0, 1.0]])
        cam = Camera(K=K, width=96, height=64)
        m = backend.set_variant()
        x0, y0, x1, y1 = rect = (5, 7, 30, 20)
        px = np.random.default_rng(1).uniform([x0 - 0.5, y0 - 0.5], [x1 - 0.5, y1 - 0.5], (200, 2))
        samples = (px + 0.5 - [x0, y0]) / [x1 - x0, y1 - y0]
        o, d, t = self._rays(m, backend.pinhole_sensor(m, cam, 4, 0.01, 100.0, rect), samples)
        np.testing.assert_allclose(d, cam.pixel_rays(px), atol=1e-6)
        np.testing.assert_allclose(o[:, 2], 0.01, rtol=1e-6)
        np.testing.assert_allclose(o, d * (0.01 / d[:, 2:]), atol=1e-8)
        np.testing.assert_allclose((o + t[:, None] * d)[:, 2], 100.0, rtol=1e-5)


class TestFallback:
    """Without a working LLVM back end (no libLLVM, or one that aborts the process), the probe
    fails and ``scalar_rgb`` renders; the probe is mocked here, or run on a variant that fails."""

    @pytest.fixture
    def unprobed(self, monkeypatch):
        monkeypatch.delenv(VARIANT_ENV, raising=False)
        monkeypatch.setattr(backend, "_probed_variant", None)

    def test_failed_probe_falls_back_to_scalar(self, unprobed, monkeypatch):
        tried = []
        monkeypatch.setattr(backend, "_probe", lambda v: tried.append(v) or False)
        assert mitsuba_variant() == "scalar_rgb" and tried == ["llvm_ad_rgb"]
        assert mitsuba_variant() == "scalar_rgb" and tried == ["llvm_ad_rgb"]  # memoized

    def test_working_probe_picks_llvm(self, unprobed, monkeypatch):
        monkeypatch.setattr(backend, "_probe", lambda v: True)
        assert mitsuba_variant() == "llvm_ad_rgb"

    def test_build_without_llvm_falls_back_without_probing(self, unprobed, monkeypatch):
        def no_probe(v):
            raise AssertionError("no LLVM variant to probe")

        monkeypatch.setattr(backend, "_probe", no_probe)
        monkeypatch.setattr(mi, "variants", lambda: ["scalar_rgb", "scalar_spectral"])
        assert mitsuba_variant() == "scalar_rgb"

    def test_probe_of_a_failing_variant_is_false(self):
        """The probe's subprocess exits with an error (here: no such variant); this process goes on."""
        assert backend._probe("no_such_variant") is False
