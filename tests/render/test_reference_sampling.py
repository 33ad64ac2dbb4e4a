"""The reference's window (only the object's rectangle rendered, the rest pasted), its samplers and
their sample counts, and its self-noise (two independent halves): the estimate against a converged
render and its scaling with the sample count."""

import json
import logging
import math

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")

from render_testing import far_from_object, forced_cpu_variant, make_room  # noqa: E402
from tolerances import reordering_tolerance  # noqa: E402

from snell_bench.config import ReferenceConfig, compose  # noqa: E402
from snell_bench.render import variants  # noqa: E402
from snell_bench.render.pieces import SAMPLERS, check_sampler, sample_count  # noqa: E402
from snell_bench.render.reference import ReferenceSettings, _window, halves_self_noise, render_reference  # noqa: E402
from snell_bench.scene.camera import Camera  # noqa: E402
from snell_bench.scene.objects import GlassObject  # noqa: E402

LUMA = np.array([0.299, 0.587, 0.114])


@pytest.fixture(scope="module", autouse=True)
def cpu_variant():
    with forced_cpu_variant():
        yield


@pytest.fixture(scope="module")
def room():
    return make_room()


def gray_psnr(a, b, m) -> float:
    return float(10 * np.log10(1.0 / np.mean(((a - b) @ LUMA)[m] ** 2)))


def holed_scene():
    """A random texture on a tilted plane with a depth step and two holes of unknown depth, one far
    from the object; a small sphere in front: (i_minus, depth, camera, object)."""
    h, w = 64, 96
    cam = Camera(K=np.array([[80.0, 0.0, 0.43 * w], [0.0, 80.0, 0.58 * h], [0.0, 0.0, 1.0]]), width=w, height=h)
    x, y = np.meshgrid(np.arange(w), np.arange(h))
    depth = np.where(x < 50, 2.0 + 0.02 * x, 5.0 + 0.01 * y).astype(np.float64)
    depth[40:52, 70:85] = np.nan  # far from the object
    depth[20:24, 14:18] = 0.0  # next to it
    img = np.random.default_rng(0).random((h, w, 3)).astype(np.float32)
    T = np.eye(4)
    T[:3, :3] *= 0.2
    T[:3, 3] = cam.pixel_rays(np.array([14.0, 14.0]), normalize=False) * 1.5 - [0.0, 0.1, 0.0]
    return img, depth, cam, GlassObject.sphere(subdivisions=2).transformed(T)


# ============================================================================ the window
class TestWindow:
    def test_window_holds_the_object(self, room):
        ref = render_reference(
            room.image, room.depth, room.camera, room.obj, ReferenceSettings(spp=8, crop_margin_px=3)
        )
        x0, y0, x1, y1 = ref.window
        H, W = room.camera.shape
        ys, xs = np.nonzero(ref.object_mask)
        assert 0 < x1 - x0 < W and 0 < y1 - y0 < H
        assert x0 + 3 <= xs.min() and xs.max() < x1 - 3 and y0 + 3 <= ys.min() and ys.max() < y1 - 3
        assert render_reference(
            room.image, room.depth, room.camera, room.obj, ReferenceSettings(spp=2, crop=False)
        ).window == (0, 0, W, H)

    def test_window_falls_back_to_the_whole_frame(self):
        """An object reaching in front of the near clip plane (here behind the camera) has no bounded
        projection; an object outside the image nothing to crop to."""
        cam = Camera.from_fov(96, 64, 60.0)
        T = np.eye(4)
        T[:3, 3] = (0.0, 0.0, -0.2)
        behind = GlassObject.sphere(subdivisions=1).transformed(T)
        assert _window(cam, behind, (10, 10, 20, 20), 4, 1e-3, True) == (0, 0, 96, 64)
        T[:3, 3] = (0.0, 0.0, 3.0)
        ahead = GlassObject.sphere(subdivisions=1).transformed(T)
        assert _window(cam, ahead, (10, 10, 20, 20), 4, 1e-3, True) == (6, 6, 24, 24)
        assert _window(cam, ahead, (96, 64, 96, 64), 0, 1e-3, True) == (0, 0, 96, 64)
        assert _window(cam, ahead, (10, 10, 20, 20), 4, 1e-3, False) == (0, 0, 96, 64)

    def test_crop_matches_the_full_frame(self, room):
        """Same seed and sampler, with and without the window. Outside it the pasted background is
        the full-frame render up to float rounding, except where a full-frame sample slips through a
        crack between background triangles (a few pixels, a little darker). Inside, the pixels
        that see the background directly agree likewise; the object's pixels draw other random
        numbers in a window (the sampler's stream follows the window's pixels), so they agree within
        the noise: two independent references differ by their self-noise minus 3 dB."""
        args = (room.image, room.depth, room.camera, room.obj)
        c = render_reference(*args, ReferenceSettings(spp=18, seed=0))
        f = render_reference(*args, ReferenceSettings(spp=18, seed=0, crop=False))
        x0, y0, x1, y1 = c.window
        inside = np.zeros(c.mask.shape, bool)
        inside[y0:y1, x0:x1] = True
        d_lin = np.abs(c.linear - f.linear).max(axis=-1)
        assert np.mean(d_lin[~inside] < 1e-5) > 0.995
        assert np.abs(c.image - f.image)[~inside].mean() < 0.1 / 255
        assert np.mean(c.unobserved[~inside] == f.unobserved[~inside]) > 0.999
        background = inside & far_from_object(c.object_mask) & (f.unobserved == 0)
        assert background.sum() > 200 and np.mean(d_lin[background] < 1e-5) > 0.99
        assert np.array_equal(c.object_mask, f.object_mask)
        assert (c.mask != f.mask).sum() <= 0.01 * c.mask.sum()
        m = c.mask & f.mask
        expected = 0.5 * (c.self_noise_db + f.self_noise_db) - 10 * math.log10(2)
        assert gray_psnr(c.image, f.image, m) == pytest.approx(expected, abs=1.5)

    def test_holes_outside_the_window(self):
        """Pixels of unknown depth show nothing in the full-frame render (their rays leave through
        the hole and end on the unobserved box): the paste keeps that, black and unobserved."""
        img, depth, cam, obj = holed_scene()
        c = render_reference(img, depth, cam, obj, ReferenceSettings(spp=8))
        f = render_reference(img, depth, cam, obj, ReferenceSettings(spp=8, crop=False))
        x0, y0, x1, y1 = c.window
        assert x1 <= 70 and c.object_mask.sum() > 10  # the far hole lies outside the window
        hole = np.zeros(depth.shape, bool)
        hole[40:52, 70:85] = True
        for r in (c, f):
            assert np.abs(r.linear[hole]).max() < 1e-6 and np.all(r.unobserved[hole] == 1)
        near_hole = np.zeros(depth.shape, bool)
        near_hole[20:24, 14:18] = True
        assert np.all(c.unobserved[near_hole] > 0.95)  # inside the window, rendered


# ============================================================================ samplers
class TestSampler:
    def test_unknown_sampler_names_the_key(self, room):
        with pytest.raises(ValueError, match="reference.sampler='sobol'"):
            check_sampler("sobol")
        with pytest.raises(ValueError, match="reference.sampler"):
            render_reference(room.image, room.depth, room.camera, room.obj, ReferenceSettings(spp=2, sampler="sobol"))
        with pytest.raises(ValueError, match="sample_count"):
            check_sampler({"type": "stratified", "sample_count": 4})
        assert check_sampler({"type": "stratified", "jitter": False}) == {"type": "stratified", "jitter": False}

    def test_sample_counts_are_mitsubas(self):
        m = variants.set_variant()
        assert sample_count(m, "independent", 7) == 7
        assert sample_count(m, "stratified", 8) == 9
        assert sample_count(m, "orthogonal", 16) == 25
        assert sample_count(m, "orthogonal", 121) == 121
        assert sample_count(m, "ldsampler", 8) == 16
        assert sample_count(m, "multijitter", 16) >= 16

    def test_rounding_is_logged(self, room, caplog):
        with caplog.at_level(logging.WARNING, logger="snell_bench.render.reference"):
            ref = render_reference(
                room.image, room.depth, room.camera, room.obj, ReferenceSettings(spp=16, unobserved_spp=2)
            )
        assert ref.sampler == "orthogonal" and ref.spp == 18 and ref.halves == (9, 9) and ref.unobserved_spp == 4
        assert "spp=16 rendered as 9 + 9 = 18" in caplog.text
        ref = render_reference(
            room.image, room.depth, room.camera, room.obj, ReferenceSettings(spp=7, sampler="independent")
        )
        assert ref.spp == 7 and ref.halves == (3, 4)

    @pytest.mark.parametrize("preset", [None, "fast", "balanced", "paper"])
    def test_configured_counts_need_no_rounding(self, preset):
        """The schema's and the presets' ``reference.spp`` split into halves the sampler takes."""
        cfg = compose(["output_dir=/tmp/x"] + ([f"preset={preset}"] if preset else []))
        r = cfg.reference
        assert r.sampler in SAMPLERS and r.sampler == ReferenceConfig().sampler
        m = variants.set_variant()
        assert r.spp % 2 == 0 and sample_count(m, r.sampler, r.spp // 2) == r.spp // 2
        assert sample_count(m, r.sampler, r.unobserved_spp) == r.unobserved_spp


# ============================================================================ self-noise
class TestSelfNoise:
    def test_halves_formula(self):
        """Independent halves with noise of standard deviation s per pixel (the same in every
        channel, so also in gray): the halves differ by 2 s², the mean of equal halves has s² / 2."""
        rng = np.random.default_rng(0)
        x = rng.random((200, 300, 1)) * np.ones(3)
        s = 0.01
        a, b = x + s * rng.standard_normal((200, 300, 1)), x + s * rng.standard_normal((200, 300, 1))
        m = np.ones((200, 300), bool)
        full, rgb, halves = halves_self_noise(a, b, m, 8, 8)
        assert halves == pytest.approx(10 * math.log10(1 / (2 * s**2)), abs=0.05)
        assert full - halves == pytest.approx(10 * math.log10(4)) and rgb == pytest.approx(full)
        assert full == pytest.approx(10 * math.log10(1 / np.mean(((a + b) / 2 - x)[..., 0] ** 2)), abs=0.05)
        assert halves_self_noise(a, b, m, 3, 4)[0] - halves == pytest.approx(10 * math.log10(49 / 12))
        assert halves_self_noise(a, a, m, 1, 1)[0] == math.inf
        with pytest.raises(ValueError, match="empty"):
            halves_self_noise(a, b, ~m, 1, 1)

    def test_estimate_matches_a_converged_reference(self, room):
        """The 32-spp reference's estimated self-noise is its PSNR against a 1024-spp one (whose own
        noise costs 0.14 dB at most)."""
        args = (room.image, room.depth, room.camera, room.obj)
        ref = render_reference(*args, ReferenceSettings(spp=32, sampler="independent", seed=1))
        conv = render_reference(*args, ReferenceSettings(spp=1024, sampler="independent", seed=2, unobserved_spp=4))
        m = ref.mask & conv.mask
        assert m.sum() > 500 and ref.halves == (16, 16)
        assert gray_psnr(ref.image, conv.image, m) == pytest.approx(ref.self_noise_db, abs=0.75)
        assert ref.self_noise_db - ref.self_noise_halves_db == pytest.approx(10 * math.log10(4))
        assert conv.self_noise_db > ref.self_noise_db + 13

    def test_scales_with_the_sample_count(self, room):
        """Independent sampler: 16 times the samples, 10 log10(16) = 12 dB less noise; the orthogonal
        sampler gains more at the same count."""
        args = (room.image, room.depth, room.camera, room.obj)
        lo = render_reference(*args, ReferenceSettings(spp=8, sampler="independent", unobserved_spp=4))
        hi = render_reference(*args, ReferenceSettings(spp=128, sampler="independent", unobserved_spp=4))
        assert hi.self_noise_db - lo.self_noise_db == pytest.approx(10 * math.log10(16), abs=1.0)
        ortho = render_reference(*args, ReferenceSettings(spp=98, unobserved_spp=4))
        assert ortho.self_noise_db > hi.self_noise_db + 3

    def test_without_halves_there_is_none(self, room):
        args = (room.image, room.depth, room.camera, room.obj)
        one = render_reference(*args, ReferenceSettings(spp=1, sampler="independent", unobserved_spp=1))
        assert one.self_noise_db is None and one.halves is None and one.spp == 1
        off = render_reference(*args, ReferenceSettings(spp=8, self_noise=False))
        assert off.self_noise_db is None and off.halves is None and off.spp == 9

    def test_summary_is_json(self, room):
        ref = render_reference(room.image, room.depth, room.camera, room.obj, ReferenceSettings(spp=8))
        rec = json.loads(json.dumps(ref.summary()))
        assert rec["sampler"] == "orthogonal" and rec["spp"] == 8 and rec["halves"] == [4, 4]
        assert rec["self_noise_db"] == pytest.approx(ref.self_noise_db, abs=1e-3)
        assert rec["self_noise_db"] - rec["self_noise_halves_db"] == pytest.approx(6.02, abs=0.01)
        assert rec["window"] == list(ref.window) and rec["variant"] == ref.variant


# ============================================================================ LLVM
@pytest.mark.slow
class TestLLVM:
    def test_deterministic_up_to_float_rounding(self, room, monkeypatch):
        """Two LLVM renders with one seed agree to float rounding: with several Dr.Jit threads the
        samples of a pixel whose samples fall in two threads' blocks are summed in either order (a
        few pixels, 1-2 ulp); on one thread they are equal bit for bit. The scalar variant draws
        other samples: it agrees within the noise."""
        import drjit as dr

        if not variants._probe("llvm_ad_rgb"):
            pytest.skip("the llvm_ad_rgb variant does not work here (libLLVM missing or incompatible)")
        args = (room.image, room.depth, room.camera, room.obj)
        scalar = render_reference(*args, ReferenceSettings(spp=50, seed=3))
        monkeypatch.setenv(variants.VARIANT_ENV, "llvm_ad_rgb")
        a, b = (render_reference(*args, ReferenceSettings(spp=50, seed=3)) for _ in range(2))
        assert a.variant == "llvm_ad_rgb" and a.window == scalar.window
        # a pixel is the mean of its a.spp positive samples: summed in any order, it is within
        # (spp - 1) u of the exact mean times its magnitude (box filter: no other pixel's samples)
        atol = reordering_tolerance(a.spp, a.linear)
        np.testing.assert_allclose(a.linear, b.linear, rtol=0, atol=atol)
        assert np.array_equal(a.unobserved, b.unobserved) and np.array_equal(a.mask, b.mask)
        threads = dr.thread_count()
        dr.set_thread_count(1)
        try:
            c, d = (render_reference(*args, ReferenceSettings(spp=50, seed=3)) for _ in range(2))
        finally:
            dr.set_thread_count(threads)
        assert np.array_equal(c.linear, d.linear) and np.array_equal(c.unobserved, d.unobserved)
        np.testing.assert_allclose(c.linear, a.linear, rtol=0, atol=atol)
        m = a.mask & scalar.mask
        expected = 0.5 * (a.self_noise_db + scalar.self_noise_db) - 10 * math.log10(2)
        assert gray_psnr(a.image, scalar.image, m) == pytest.approx(expected, abs=1.5)
