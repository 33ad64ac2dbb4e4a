"""Choosing the Mitsuba variant: forced by the environment, or probed in a subprocess (CUDA where
its driver loads, then LLVM), with the scalar variant as the fallback."""

import pytest

mi = pytest.importorskip("mitsuba")

from render_testing import forced_cpu_variant  # noqa: E402

from snell_bench.render import variants  # noqa: E402
from snell_bench.render.probe import probe_render  # noqa: E402
from snell_bench.render.variants import VARIANT_ENV, mitsuba_variant  # noqa: E402


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
        monkeypatch.setattr(variants, "_probed_variant", None)
        variant = mitsuba_variant()
        assert variant in ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
        assert variants.probed_variant() == variant

        def no_second_probe(v):
            raise AssertionError("the probe result is memoized")

        monkeypatch.setattr(variants, "_probe", no_second_probe)
        assert mitsuba_variant() == variant
        # and it renders here, in this process
        monkeypatch.setenv(VARIANT_ENV, variant)
        probe_render()


class TestFallback:
    """Without a working LLVM back end (no libLLVM, or one that aborts the process), the probe
    fails and ``scalar_rgb`` renders; the probe is mocked here, or run on a variant that fails.
    No CUDA driver here: ``cuda_ad_rgb`` is not probed."""

    @pytest.fixture
    def unprobed(self, monkeypatch):
        monkeypatch.delenv(VARIANT_ENV, raising=False)
        monkeypatch.setattr(variants, "_probed_variant", None)
        monkeypatch.setattr(variants, "cuda_driver", lambda: False)
        assert variants.probed_variant() is None

    def test_failed_probe_falls_back_to_scalar(self, unprobed, monkeypatch):
        tried = []
        monkeypatch.setattr(variants, "_probe", lambda v: tried.append(v) or False)
        assert mitsuba_variant() == "scalar_rgb" and tried == ["llvm_ad_rgb"]
        assert mitsuba_variant() == "scalar_rgb" and tried == ["llvm_ad_rgb"]  # memoized

    def test_working_probe_picks_llvm(self, unprobed, monkeypatch):
        monkeypatch.setattr(variants, "_probe", lambda v: True)
        assert mitsuba_variant() == "llvm_ad_rgb"

    def test_build_without_llvm_falls_back_without_probing(self, unprobed, monkeypatch):
        def no_probe(v):
            raise AssertionError("no LLVM variant to probe")

        monkeypatch.setattr(variants, "_probe", no_probe)
        monkeypatch.setattr(mi, "variants", lambda: ["scalar_rgb", "scalar_spectral"])
        assert mitsuba_variant() == "scalar_rgb"

    def test_probe_of_a_failing_variant_is_false(self):
        """The probe's subprocess exits with an error (here: no such variant); this process goes on."""
        assert variants._probe("no_such_variant") is False


class TestCuda:
    """Where the CUDA driver loads, ``cuda_ad_rgb`` is probed first (in a subprocess, like the LLVM
    variant), then ``llvm_ad_rgb``; the environment still wins. The driver and the probe are mocked:
    the order is what is tested, on any machine."""

    @pytest.fixture
    def tried(self, monkeypatch):
        monkeypatch.delenv(VARIANT_ENV, raising=False)
        monkeypatch.setattr(variants, "_probed_variant", None)
        monkeypatch.setattr(variants, "cuda_driver", lambda: True)
        monkeypatch.setattr(mi, "variants", lambda: ["scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb", "cuda_ad_mono"])
        return []

    def probe(self, monkeypatch, tried, works):
        monkeypatch.setattr(variants, "_probe", lambda v: tried.append(v) or v in works)

    def test_a_working_cuda_variant_comes_first(self, tried, monkeypatch):
        self.probe(monkeypatch, tried, {"cuda_ad_rgb", "llvm_ad_rgb"})
        assert mitsuba_variant() == "cuda_ad_rgb" and tried == ["cuda_ad_rgb"]
        assert mitsuba_variant() == "cuda_ad_rgb" and tried == ["cuda_ad_rgb"]  # memoized
        assert variants.probed_variant() == "cuda_ad_rgb"

    def test_a_failing_cuda_probe_falls_back_to_llvm_then_scalar(self, tried, monkeypatch):
        self.probe(monkeypatch, tried, {"llvm_ad_rgb"})
        assert mitsuba_variant() == "llvm_ad_rgb" and tried == ["cuda_ad_rgb", "llvm_ad_rgb"]
        monkeypatch.setattr(variants, "_probed_variant", None)
        tried.clear()
        self.probe(monkeypatch, tried, set())
        assert mitsuba_variant() == "scalar_rgb" and tried == ["cuda_ad_rgb", "llvm_ad_rgb"]

    def test_no_driver_or_no_cuda_build_is_not_probed(self, tried, monkeypatch):
        self.probe(monkeypatch, tried, {"cuda_ad_rgb", "llvm_ad_rgb"})
        monkeypatch.setattr(variants, "cuda_driver", lambda: False)
        assert mitsuba_variant() == "llvm_ad_rgb" and tried == ["llvm_ad_rgb"]
        monkeypatch.setattr(variants, "_probed_variant", None)
        monkeypatch.setattr(variants, "cuda_driver", lambda: True)
        monkeypatch.setattr(mi, "variants", lambda: ["scalar_rgb", "llvm_ad_rgb"])  # a build without CUDA
        tried.clear()
        assert mitsuba_variant() == "llvm_ad_rgb" and tried == ["llvm_ad_rgb"]

    def test_the_environment_overrides_cuda(self, tried, monkeypatch):
        def no_probe(v):
            raise AssertionError("a forced variant is not probed")

        monkeypatch.setattr(variants, "_probe", no_probe)
        monkeypatch.setenv(VARIANT_ENV, "llvm_ad_rgb")
        assert mitsuba_variant() == "llvm_ad_rgb" and variants.probed_variant() is None

    def test_the_driver_is_found_by_loading_its_library(self, monkeypatch):
        import ctypes

        loaded = []

        def cdll(name, only=None):
            loaded.append(name)
            if name != only:
                raise OSError(f"{name}: cannot open shared object file")

        monkeypatch.setattr(ctypes, "CDLL", lambda name: cdll(name, "libcuda.so"))
        assert variants.cuda_driver() and loaded == ["libcuda.so.1", "libcuda.so"]
        monkeypatch.setattr(ctypes, "CDLL", lambda name: cdll(name))
        assert not variants.cuda_driver()
