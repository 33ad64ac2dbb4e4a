"""The Mitsuba back end: choosing the variant (forced by the environment, or probed in a
subprocess) and the sensor's camera conventions."""

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
