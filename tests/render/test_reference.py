"""The Mitsuba reference render: camera and texture conventions, the cross-check against our own
tracer (π^R, Fresnel, the unobserved mask) with square and non-square pixels, and its properties."""

import math
import os
import sys

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")

import scipy.ndimage as nd  # noqa: E402
from render_testing import (  # noqa: E402
    H,
    W,
    far_from_object,
    forced_cpu_variant,
    make_non_square_room,
    make_room,
    metric_pixels,
    psnr,
    warp,
)

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear  # noqa: E402
from snell_bench.optics import HitKind  # noqa: E402
from snell_bench.render.reference import ReferenceSettings, render_reference  # noqa: E402
from snell_bench.render.variants import VARIANT_ENV  # noqa: E402
from snell_bench.scene.camera import Camera  # noqa: E402
from snell_bench.scene.objects import GlassObject  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def cpu_variant():
    with forced_cpu_variant():
        yield


@pytest.fixture(scope="module")
def room():
    return make_room()


@pytest.fixture(scope="module")
def reference(room):
    return render_reference(room.image, room.depth, room.camera, room.obj, ReferenceSettings(spp=18, seed=0))


@pytest.fixture(scope="module")
def geometric(room):
    return render_reference(
        room.image, room.depth, room.camera, room.obj, ReferenceSettings(spp=18, seed=0, fresnel=False)
    )


@pytest.fixture(scope="module")
def non_square_room(room):
    """The room seen with ``fy = 1.12 fx`` and an off-centre principal point."""
    return make_non_square_room(room)


@pytest.fixture(scope="module")
def non_square_geometric(non_square_room):
    r = non_square_room
    return render_reference(r.image, r.depth, r.camera, r.obj, ReferenceSettings(spp=18, seed=0, fresnel=False))


# ============================================================================ conventions
class TestConventions:
    @pytest.mark.parametrize(
        "fy,skew",
        [(80.0, 0.0), (89.6, 0.0), (80.0 / 1.12, 0.0), (89.6, 6.0)],
        ids=["square", "fy>fx", "fy<fx", "skew"],
    )
    def test_background_reproduces_texture_exactly(self, fy, skew):
        """Random texture (any flip or shift shows), off-centre principal point, a tilted plane and a
        depth step (cut edge): outside the object the render is I⁻, texel for texel, for square and
        non-square pixels (``fx = 80``) and a skewed ``K``."""
        h, w = 64, 96
        K = np.array([[80.0, skew, 0.43 * w], [0.0, fy, 0.58 * h], [0.0, 0.0, 1.0]])
        cam = Camera(K=K, width=w, height=h)
        x, y = np.meshgrid(np.arange(w), np.arange(h))
        depth = np.where(x < 50, 2.0 + 0.02 * x, 5.0 + 0.01 * y)
        img = np.random.default_rng(0).random((h, w, 3)).astype(np.float32)
        T = np.eye(4)
        T[:3, :3] *= 0.2
        T[:3, 3] = cam.pixel_rays(np.array([10.0, 10.0]), normalize=False) * 1.5 - [0.0, 0.1, 0.0]
        obj = GlassObject.sphere(subdivisions=2).transformed(T)
        # the whole frame rendered (crop=False), and the object's window alone (the rest pasted);
        # fresnel=False renders the object's rectangle apart (crop windows of the same film)
        for fresnel, crop in ((True, False), (False, False), (True, True)):
            ref = render_reference(img, depth, cam, obj, ReferenceSettings(spp=8, fresnel=fresnel, crop=crop))
            out = far_from_object(ref.object_mask)
            err = np.abs(ref.image - img).max(axis=-1)[out]
            assert ref.object_mask.sum() > 10
            assert err.mean() < 0.1 / 255
            assert np.mean(err < 1 / 255) > 0.999
            # the camera sees only observed surfaces there (flaps cover the cut edge)
            assert np.mean(ref.unobserved[out] == 0) > 0.999

    def test_outside_object_equals_i_minus(self, room, reference):
        out = far_from_object(reference.object_mask)
        assert np.abs(reference.image - room.image)[out].mean() < 1 / 255

    def test_object_mask_matches_warps(self, room, reference):
        assert np.mean(reference.object_mask == room.ws.object_mask) > 0.999
        assert reference.mask.sum() > 0.5 * reference.object_mask.sum()
        assert not (reference.mask & ~reference.object_mask).any()

    def test_non_square_outside_object_equals_i_minus(self, non_square_room, non_square_geometric):
        r, ref = non_square_room, non_square_geometric
        out = far_from_object(ref.object_mask)
        assert np.abs(ref.image - r.image)[out].mean() < 1 / 255
        assert np.mean(ref.object_mask == r.ws.object_mask) > 0.999
        assert ref.object_mask.sum() > 1000

    def test_outputs(self, reference):
        assert reference.image.shape == (H, W, 3) and reference.image.dtype == np.float32
        assert reference.image.min() >= 0 and reference.image.max() <= 1
        assert reference.unobserved.shape == (H, W) and reference.unobserved.dtype == np.float32
        assert reference.unobserved.min() >= 0 and reference.unobserved.max() <= 1
        assert reference.variant == os.environ[VARIANT_ENV] and reference.spp == 18
        assert reference.sampler == "orthogonal" and reference.halves == (9, 9) and reference.unobserved_spp == 25
        assert math.isfinite(reference.self_noise_db) and reference.self_noise_db > 30


# ============================================================================ cross-checks
class TestCrossCheck:
    def test_refraction_matches_self_warp(self, room, geometric):
        """Mitsuba's refraction path (Fresnel off) against π^R(I⁻) from our tracer."""
        m = metric_pixels(geometric, room.ws)
        assert m.sum() > 500
        assert psnr(geometric.image, warp(room.image, room.ws.refraction), m) > 30

    def test_non_square_refraction_matches_self_warp(self, non_square_room, non_square_geometric):
        """As above with ``fy = 1.12 fx`` and an off-centre principal point: the reference's own
        pinhole sensor casts the rays of ``K⁻¹``, as our tracer does."""
        m = metric_pixels(non_square_geometric, non_square_room.ws)
        assert m.sum() > 500
        assert psnr(non_square_geometric.image, warp(non_square_room.image, non_square_room.ws.refraction), m) > 30

    def test_physical_render_matches_fresnel_combination(self, room, reference):
        """Mitsuba's dielectric against ``R π^-R + (1 - R) π^R`` in linear RGB (our Fresnel)."""
        ws = room.ws
        lin = srgb_to_linear(room.image)
        refl = warp(lin, np.where(ws.reflection_valid[..., None], ws.reflection, np.nan))
        F = ws.fresnel[..., None]
        expected = linear_to_srgb(F * refl + (1 - F) * warp(lin, ws.refraction))
        m = metric_pixels(reference, ws)
        assert psnr(reference.image, expected, m) > 28

    def test_unobserved_share_matches_warp_validity(self, room, reference):
        """~0 where our refracted ray reaches observed surfaces, ~1 where it hits the box. Compared
        away from the borders between the two (a footprint there mixes both)."""
        ws = room.ws
        valid = nd.binary_erosion(ws.object_mask & ws.refraction_valid)
        unobserved = nd.binary_erosion(ws.object_mask & (ws.refraction_kind == HitKind.UNOBSERVED))
        assert valid.sum() > 500 and unobserved.sum() > 50
        share = reference.unobserved
        agree = np.concatenate([share[valid] < 0.05, share[unobserved] > 0.95])
        assert agree.mean() > 0.95
        assert share[valid].mean() < 0.05 and share[unobserved].mean() > 0.95


# ============================================================================ properties
class TestProperties:
    def test_deterministic_for_a_seed(self, room):
        args = (room.image, room.depth, room.camera, room.obj)
        a = render_reference(*args, ReferenceSettings(spp=8, seed=3))
        b = render_reference(*args, ReferenceSettings(spp=8, seed=3))
        c = render_reference(*args, ReferenceSettings(spp=8, seed=4))
        assert np.array_equal(a.image, b.image) and np.array_equal(a.unobserved, b.unobserved)
        assert not np.array_equal(a.image, c.image)

    def test_ior_one_object_vanishes(self, room):
        ref = render_reference(room.image, room.depth, room.camera, room.obj.with_ior(1.0), ReferenceSettings(spp=8))
        err = np.abs(ref.image - room.image).max(axis=-1)
        assert err.mean() < 0.1 / 255
        assert np.mean(err < 1 / 255) > 0.999
        assert ref.mask.sum() > 0.99 * ref.object_mask.sum()

    def test_missing_mitsuba_names_the_extra(self, room, monkeypatch):
        monkeypatch.setitem(sys.modules, "mitsuba", None)
        with pytest.raises(ImportError, match=r"snell_bench\[render\]"):
            render_reference(room.image, room.depth, room.camera, room.obj)
