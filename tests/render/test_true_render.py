"""The true render of procedural scenes (our tracer, no Mitsuba), and its agreement with the
Mitsuba reference render."""

import importlib.util
import sys

import numpy as np
import pytest
from render_testing import (
    H,
    W,
    far_from_object,
    forced_cpu_variant,
    make_non_square_room,
    make_room,
    metric_pixels,
    psnr,
)

from snell_bench.render.true_render import render_true


@pytest.fixture(scope="module")
def room():
    return make_room()


class TestTrueRender:
    def test_outside_object_equals_procedural_render(self, room):
        true = render_true(room.scene, room.camera, room.obj, spp=4, jitter=False)
        out = far_from_object(room.ws.object_mask)
        assert true.shape == (H, W, 3) and true.dtype == np.float32
        assert np.abs(true - room.image)[out].max() < 1e-5

    def test_non_square_pixels_outside_object_equals_i_minus(self, room):
        ns = make_non_square_room(room)
        true = render_true(ns.scene, ns.camera, ns.obj, spp=4, jitter=False)
        out = far_from_object(ns.ws.object_mask)
        assert ns.ws.object_mask.sum() > 1000
        assert np.abs(true - ns.image)[out].max() < 1e-5

    def test_inside_agrees_with_reference(self, room):
        pytest.importorskip("mitsuba")
        from snell_bench.render.reference import ReferenceSettings, render_reference

        with forced_cpu_variant():
            reference = render_reference(
                room.image, room.depth, room.camera, room.obj, ReferenceSettings(spp=16, seed=0)
            )
        true = render_true(room.scene, room.camera, room.obj, spp=4, seed=0)
        m = metric_pixels(reference, room.ws)
        assert psnr(true, reference.image, m) > 25

    def test_tinted_glass_darkens_only_its_absorbed_channels(self, room):
        """Absorption in red alone: green and blue are the clear render's bit for bit, red is darker
        inside the object and unchanged outside it."""
        tinted = room.obj.with_absorption((6.0, 0.0, 0.0))
        clear = render_true(room.scene, room.camera, room.obj, spp=4, jitter=False)
        red = render_true(room.scene, room.camera, tinted, spp=4, jitter=False)
        assert np.array_equal(red[..., 1:], clear[..., 1:])
        inside, outside = room.ws.object_mask, far_from_object(room.ws.object_mask)
        assert np.array_equal(red[outside], clear[outside])
        assert (red[inside, 0] <= clear[inside, 0]).all() and (red[inside, 0] < clear[inside, 0] - 0.05).mean() > 0.5

    def test_tinted_glass_agrees_with_the_reference(self, room):
        """Two renderers of the tinted sphere (our tracer with exp(-sigma L), Mitsuba's medium): as
        close as the clear ones (the test above), at more samples: a colour-dependent extinction
        makes the reference noisier (docs/materials.md)."""
        pytest.importorskip("mitsuba")
        from snell_bench.render.reference import ReferenceSettings, render_reference

        tinted = room.obj.with_absorption((3.0, 1.0, 0.3))
        with forced_cpu_variant():
            reference = render_reference(room.image, room.depth, room.camera, tinted, ReferenceSettings(spp=64, seed=0))
        true = render_true(room.scene, room.camera, tinted, spp=4, seed=0)
        assert psnr(true, reference.image, metric_pixels(reference, room.ws)) > 25

    def test_deterministic_and_sample_patterns(self, room):
        cam = room.camera.scaled(0.25)
        a = render_true(room.scene, cam, room.obj, spp=2, seed=1)
        b = render_true(room.scene, cam, room.obj, spp=2, seed=1)
        assert np.array_equal(a, b)
        with pytest.raises(ValueError, match="square spp"):
            render_true(room.scene, cam, room.obj, spp=2, jitter=False)

    def test_needs_no_mitsuba(self, room, monkeypatch):
        """The module imports and renders with Mitsuba unavailable."""
        for name in ("mitsuba", "drjit"):
            monkeypatch.setitem(sys.modules, name, None)
        spec = importlib.util.find_spec("snell_bench.render.true_render")
        fresh = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(fresh)
        cam = room.camera.scaled(0.25)
        args = (room.scene, cam, room.obj)
        assert np.array_equal(fresh.render_true(*args, spp=1), render_true(*args, spp=1))
