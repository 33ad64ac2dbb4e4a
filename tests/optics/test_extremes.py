"""compute_warps at numerical extremes: IOR 1 to 3, objects at the border, tiny and huge objects,
objects cutting into the background, and depth maps full of holes and invalid values."""

import numpy as np
import pytest
from conftest import analytic_sphere_plane, sphere_at

from snell_bench.optics import HitKind, compute_warps
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import valid_depth_mask
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import place_object
from snell_bench.scene.procedural import ProceduralScene

H, W = 96, 160
CENTER, RADIUS, PLANE_Z = np.array([0.1, -0.2, 3.0]), 0.5, 5.0
IORS = (1.0, 1.0 + 1e-6, 1.001, 1.333, 1.5, 2.0, 2.42, 3.0)


@pytest.fixture(scope="module")
def cam():
    return Camera.from_fov(W, H, 60.0)


@pytest.fixture(scope="module")
def plane(cam):
    return np.full(cam.shape, PLANE_Z, np.float32)


@pytest.fixture(scope="module")
def ior_sweep(cam, plane):
    return {
        ior: compute_warps(plane, cam, sphere_at(CENTER, RADIUS, ior=ior, subdivisions=4), pano_height=16)
        for ior in IORS
    }


def assert_finite_where_valid(ws):
    """Every valid entry of every warp is finite; invalid entries are NaN, never inf."""
    for warp, valid in [
        (ws.refraction, ws.refraction_valid),
        (ws.reflection, ws.reflection_valid),
        (ws.pano_refraction, ws.pano_refraction_valid),
        (ws.pano_reflection, ws.pano_reflection_valid),
        (ws.pano_to_persp, ws.pano_to_persp_valid),
    ]:
        assert np.isfinite(warp[valid]).all()
        assert not np.isinf(warp).any()
    assert np.isfinite(ws.fresnel).all()
    assert ws.fresnel.min() >= 0.0 and ws.fresnel.max() <= 1.0
    # outside the object the refraction warp is the identity
    out = ~ws.object_mask
    np.testing.assert_array_equal(ws.refraction[out], ws.camera.pixel_grid()[out].astype(np.float32))
    assert np.all(ws.refraction_kind[out] == HitKind.NONE)


def displacement(ws):
    v = ws.object_mask & ws.refraction_valid
    return np.linalg.norm(ws.refraction[v] - ws.camera.pixel_grid()[v], axis=-1)


def analytic_silhouette(cam, center, radius):
    """(H, W) bool: pixel centres whose camera ray hits the exact sphere."""
    _, p1 = analytic_sphere_plane(cam.pixel_rays().reshape(-1, 3), center, radius, 1.5, 1e9)
    return np.isfinite(p1).all(1).reshape(cam.shape)


def dilate(m, k=1):
    out = m.copy()
    for dy in range(-k, k + 1):
        for dx in range(-k, k + 1):
            out |= np.roll(np.roll(m, dy, 0), dx, 1)
    return out


class TestIORRange:
    @pytest.mark.parametrize("ior", IORS)
    def test_finite_and_fresnel_in_unit_interval(self, ior_sweep, ior):
        ws = ior_sweep[ior]
        assert ws.object_mask.sum() > 1500
        assert_finite_where_valid(ws)
        m = ws.object_mask
        assert not np.any(ws.refraction_kind[m] == HitKind.LOST)
        assert np.all(ws.refraction_kind[m] != HitKind.NONE)
        assert ws.bounces.max() <= 8

    def test_unit_ior_is_exactly_straight(self, ior_sweep):
        ws = ior_sweep[1.0]
        assert ws.refraction_valid[ws.object_mask].all()
        assert displacement(ws).max() < 1e-4  # float32 ray casting only
        assert ws.fresnel.max() < 1e-12

    def test_warp_approaches_identity_linearly(self, ior_sweep, cam, plane):
        # the deviation is first order in (ior - 1): 1 + 1e-6 moves every pixel by at most a few
        # thousandths of a pixel (the most at the silhouette, where the exact sphere gives 0.0027 px)
        d6, d3 = displacement(ior_sweep[1.0 + 1e-6]), displacement(ior_sweep[1.001])
        assert np.median(d6) < 1e-3
        assert d6.max() < 1e-2
        assert np.percentile(d6, 90) < 1e-3
        assert np.median(d6) / 1e-6 == pytest.approx(np.median(d3) / 1e-3, rel=0.05)
        ws5 = compute_warps(plane, cam, sphere_at(CENTER, RADIUS, ior=1.0 + 1e-5, subdivisions=4), pano_height=16)
        assert d6.max() / 1e-6 == pytest.approx(displacement(ws5).max() / 1e-5, rel=0.05)
        # and the Fresnel reflectance goes to 0 with it
        assert ior_sweep[1.0 + 1e-6].fresnel.max() < 1e-5

    def test_median_displacement_monotone_in_ior(self, ior_sweep):
        med = [float(np.median(displacement(ior_sweep[ior]))) for ior in IORS]
        assert all(a < b for a, b in zip(med, med[1:])), med

    def test_normal_incidence_fresnel_matches_closed_form(self, ior_sweep):
        for ior in IORS[2:]:
            ws = ior_sweep[ior]
            r0 = ((ior - 1) / (ior + 1)) ** 2
            assert float(ws.fresnel[ws.object_mask].min()) == pytest.approx(r0, rel=2e-2, abs=1e-6)

    def test_sphere_at_high_ior_mostly_two_bounces(self, ior_sweep):
        # a sphere cannot totally reflect (the exit angle equals the entry's refracted angle)
        ws = ior_sweep[3.0]
        b = ws.bounces[ws.object_mask]
        assert np.mean(b == 2) > 0.99
        trapped = ws.refraction_kind == HitKind.TRAPPED
        assert np.all(ws.bounces[trapped] == 8)
        assert not ws.refraction_valid[trapped].any() and not ws.pano_refraction_valid[trapped].any()

    @pytest.fixture(scope="class")
    @staticmethod
    def cube():
        import trimesh

        box = trimesh.creation.box(extents=(0.8, 0.8, 0.8))
        box.apply_transform(trimesh.transformations.euler_matrix(0.6, 0.785, 0.0))
        box.apply_translation([0.0, 0.0, 3.0])
        return GlassObject.from_mesh(box.vertices, box.faces, ior=3.0)

    @pytest.mark.parametrize("max_bounces", [1, 2, 3])
    def test_high_ior_cube_bounces_bounded_and_trapped_marked(self, cam, plane, cube, max_bounces):
        ref = compute_warps(plane, cam, cube, pano_height=16, max_bounces=16)
        m = ref.object_mask
        need = ref.bounces[m]
        assert not np.any(ref.refraction_kind[m] == HitKind.LOST)
        assert np.mean(need >= 3) > 0.2, "total internal reflection at IOR 3 inside a tilted cube"
        ws = compute_warps(plane, cam, cube, pano_height=16, max_bounces=max_bounces)
        assert_finite_where_valid(ws)
        np.testing.assert_array_equal(ws.object_mask, m)
        kinds, b = ws.refraction_kind[m], ws.bounces[m]
        assert b.max() <= max_bounces
        assert not np.any(kinds == HitKind.LOST)
        # exactly the paths that need more interactions are trapped, after max_bounces of them
        trapped = kinds == HitKind.TRAPPED
        np.testing.assert_array_equal(trapped, need > max_bounces)
        assert np.all(b[trapped] == max_bounces)
        assert not ws.refraction_valid[m][trapped].any()
        assert np.isnan(ws.refraction[m][trapped]).all() and np.isnan(ws.pano_refraction[m][trapped]).all()
        # the others are unchanged
        same = ~trapped
        np.testing.assert_array_equal(b[same], need[same])
        np.testing.assert_array_equal(ws.refraction[m][same], ref.refraction[m][same])
        np.testing.assert_array_equal(ws.fresnel, ref.fresnel)


class TestBorder:
    @pytest.mark.parametrize("where", ["left", "right", "top", "bottom", "corner"])
    def test_partly_outside_view(self, cam, plane, where):
        f, cx, cy = cam.K[0, 0], cam.K[0, 2], cam.K[1, 2]
        z, r = 3.0, 0.4
        # the sphere's centre projects onto (or just past) the image border
        px = {
            "left": (-0.5, cy),
            "right": (W - 0.5 + 3, cy),
            "top": (cx, -0.5),
            "bottom": (cx, H + 2.0),
            "corner": (W - 0.5, H - 0.5),
        }[where]
        c = np.array([(px[0] - cx) / f * z, (px[1] - cy) / f * z, z])
        ws = compute_warps(plane, cam, sphere_at(c, r, subdivisions=4), pano_height=16)
        assert_finite_where_valid(ws)
        m = ws.object_mask
        exact = analytic_silhouette(cam, c, r)
        assert exact.sum() > 100 and m.sum() > 100
        assert not (m & ~dilate(exact)).any(), "object pixels away from the sphere"
        assert (m != exact).sum() < 0.05 * exact.sum()
        assert not np.any(ws.refraction_kind[m] == HitKind.LOST)
        # the refracted rays against the closed form: valid where they land in view, and there right
        ys, xs = np.nonzero(m)
        p, _ = analytic_sphere_plane(cam.pixel_rays(np.stack([xs, ys], -1).astype(float)), c, r, 1.5, PLANE_Z)
        pix, _ = cam.project(p)
        inside = (pix[:, 0] > 1.5) & (pix[:, 0] < W - 2.5) & (pix[:, 1] > 1.5) & (pix[:, 1] < H - 2.5)
        outside = (pix[:, 0] < -2.5) | (pix[:, 0] > W + 1.5) | (pix[:, 1] < -2.5) | (pix[:, 1] > H + 1.5)
        valid = ws.refraction_valid[ys, xs]
        assert not valid[outside].any()
        if inside.sum() > 20:
            assert valid[inside].mean() > 0.95
            err = np.linalg.norm(ws.refraction[ys, xs][inside & valid] - pix[inside & valid], axis=-1)
            assert np.median(err) < 0.5

    def test_grazing_object_just_inside_the_frustum(self, cam, plane):
        # only a sliver of the sphere crosses the left border
        f, cx, cy = cam.K[0, 0], cam.K[0, 2], cam.K[1, 2]
        z, r = 3.0, 0.4
        c = np.array([(-0.5 - cx) / f * z - 0.95 * r, (cy - cy) / f * z, z])
        ws = compute_warps(plane, cam, sphere_at(c, r, subdivisions=4), pano_height=16)
        assert_finite_where_valid(ws)
        m = ws.object_mask
        assert 0 < m.sum() < 0.05 * m.size
        assert not m[:, 10:].any()
        assert not (m & ~dilate(analytic_silhouette(cam, c, r))).any()

    @pytest.mark.parametrize("offset", [(-60.0, 0.0), (W + 60.0, 0.0), (0.0, -60.0), (0.0, H + 60.0)])
    def test_entirely_outside_raises(self, cam, plane, offset):
        f, cx, cy = cam.K[0, 0], cam.K[0, 2], cam.K[1, 2]
        z, r = 3.0, 0.2  # 9 px radius: the whole sphere is 60 px beyond the border
        px = (offset[0] if offset[0] else cx, offset[1] if offset[1] else cy)
        c = np.array([(px[0] - cx) / f * z, (px[1] - cy) / f * z, z])
        with pytest.raises(ValueError, match="outside the view"):
            compute_warps(plane, cam, sphere_at(c, r, subdivisions=3), pano_height=16)


class TestSize:
    def test_tiny_object(self, cam, plane):
        f = cam.K[0, 0]
        c = np.array([0.0, 0.0, 3.0])
        r = 2.0 * 3.0 / f  # a radius of 2 px
        ws = compute_warps(plane, cam, sphere_at(c, r, subdivisions=4), pano_height=16)
        assert_finite_where_valid(ws)
        n = int(ws.object_mask.sum())
        assert 1 <= n <= 30, n
        assert abs(n - analytic_silhouette(cam, c, r).sum()) <= 4
        m = ws.object_mask
        assert ws.refraction_valid[m].all() and np.all(ws.refraction_kind[m] == HitKind.OBSERVED)
        assert np.all(ws.bounces[m] == 2)
        # a ball lens flips what is behind it: sources are near the sphere, on the other side
        # a 2 px ball lens spreads what lies behind it over tens of pixels, as the closed form does
        ys, xs = np.nonzero(m)
        p, _ = analytic_sphere_plane(cam.pixel_rays(np.stack([xs, ys], -1).astype(float)), c, r, 1.5, PLANE_Z)
        err = np.linalg.norm(ws.refraction[m] - cam.project(p)[0], axis=-1)
        assert err.max() < 0.5, err

    @pytest.mark.parametrize("ior", [1.0, 1.5, 3.0])
    def test_huge_object_fills_the_frame(self, cam, plane, ior):
        c, r = np.array([0.0, 0.0, 1.2]), 1.0  # the camera is 0.2 in front of the glass
        ws = compute_warps(plane, cam, sphere_at(c, r, ior=ior, subdivisions=4), pano_height=16)
        assert_finite_where_valid(ws)
        m = ws.object_mask
        assert m.mean() > 0.95
        assert not np.any(ws.refraction_kind[m] == HitKind.LOST)
        if ior == 1.0:
            # straight through: the identity (rays through the outermost pixel centres graze the
            # edge of the depth mesh and may miss it by float32 rounding: those are marked invalid)
            assert ws.refraction_valid[1:-1, 1:-1].all()
            assert displacement(ws).max() < 1e-3
            assert np.all(ws.refraction_kind[m & ~ws.refraction_valid] == HitKind.UNOBSERVED)
        else:
            assert ws.refraction_valid[m].mean() > 0.5
            assert np.median(ws.bounces[m]) == 2


class TestIntersectingBackground:
    def test_sphere_centre_on_the_plane(self, cam, plane):
        c = np.array([0.0, 0.0, PLANE_Z])
        r = 0.8
        ws = compute_warps(plane, cam, sphere_at(c, r, subdivisions=4), pano_height=16)
        assert_finite_where_valid(ws)
        m = ws.object_mask
        assert m.sum() > 300
        # every ray enters once and ends on the plane inside the glass
        assert np.all(ws.refraction_kind[m] == HitKind.OBSERVED)
        assert np.all(ws.bounces[m] == 1)
        assert ws.refraction_valid[m].all()
        # the ray ends on the plane where the sphere cuts it: the sources lie inside that disc
        src = ws.refraction[m]
        pts = cam.unproject(plane)
        ix = np.clip(np.rint(src).astype(int), 0, [W - 1, H - 1])
        end = pts[ix[:, 1], ix[:, 0]]
        assert np.all(np.linalg.norm(end - c, axis=-1) < r * 1.02)
        # refraction bends towards the axis: the image is shrunk, not flipped
        ys, xs = np.nonzero(m)
        cpx = cam.project(c[None])[0][0]
        d_src = np.linalg.norm(src - cpx, axis=-1)
        d_dst = np.linalg.norm(np.stack([xs, ys], -1) - cpx, axis=-1)
        assert np.all(d_src <= d_dst + 0.5)

    def test_half_buried_sphere_on_a_table(self):
        scene = ProceduralScene("room", seed=0)
        rend = scene.render(W, H)
        obj = place_object(
            GlassObject.sphere(subdivisions=4), rend.depth, rend.camera, up_hint=scene.up, relative_size=0.35, lift=-0.5
        )
        ws = compute_warps(rend.depth, rend.camera, obj, pano_height=16)
        assert_finite_where_valid(ws)
        m = ws.object_mask
        assert m.sum() > 50
        kinds, b = ws.refraction_kind[m], ws.bounces[m]
        assert not np.any(kinds == HitKind.LOST)
        ended_inside = b == 1
        assert ended_inside.mean() > 0.2, "rays through the lower half end on the table inside the glass"
        assert np.all(kinds[ended_inside] == HitKind.OBSERVED)
        # those end points lie on the table, inside the sphere
        pts = rend.camera.unproject(np.where(valid_depth_mask(rend.depth), rend.depth, np.nan))
        src = ws.refraction[m][ended_inside & ws.refraction_valid[m]]
        ix = np.clip(np.rint(src).astype(int), 0, [W - 1, H - 1])
        end = pts[ix[:, 1], ix[:, 0]]
        radius = 0.5 * obj.diameter
        assert np.nanmax(np.linalg.norm(end - obj.center, axis=-1)) < 1.1 * radius


class TestBadDepth:
    @pytest.fixture(scope="class")
    @staticmethod
    def corrupted(cam):
        rng = np.random.default_rng(7)
        depth = np.full(cam.shape, PLANE_Z, np.float32)
        idx = rng.choice(depth.size, int(0.05 * depth.size), replace=False)
        bad = np.array([np.nan, np.inf, -np.inf, 0.0, -1.0, -1e30], np.float32)
        depth.reshape(-1)[idx] = bad[rng.integers(0, len(bad), len(idx))]
        depth[40:50, 60:75] = np.nan  # and a hole
        return depth

    @pytest.mark.parametrize("ior", [1.0, 1.5, 3.0])
    def test_scattered_invalid_depth(self, cam, corrupted, ior):
        ws = compute_warps(corrupted, cam, sphere_at(CENTER, RADIUS, ior=ior, subdivisions=4), pano_height=32)
        assert_finite_where_valid(ws)
        valid = valid_depth_mask(corrupted)
        assert ws.stats["invalid_depth_pixels"] == int((~valid).sum())
        m = ws.object_mask
        assert not np.any(ws.refraction_kind[m] == HitKind.LOST)
        # a valid warp lands inside a triangle of valid pixels: its nearest pixel has valid depth
        for warp, ok in [
            (ws.refraction, ws.refraction_valid & m),
            (ws.reflection, ws.reflection_valid),
            (ws.pano_to_persp, ws.pano_to_persp_valid),
        ]:
            ix = np.rint(warp[ok]).astype(int)
            assert valid[ix[:, 1], ix[:, 0]].all()
        assert 0.3 < ws.refraction_valid[m].mean() < 1.0
        clean = compute_warps(
            np.full(cam.shape, PLANE_Z, np.float32),
            cam,
            sphere_at(CENTER, RADIUS, ior=ior, subdivisions=4),
            pano_height=32,
        )
        assert ws.pano_to_persp_valid.mean() > 0.5 * clean.pano_to_persp_valid.mean()
        assert not (ws.pano_to_persp_valid & ~clean.pano_to_persp_valid).any()

    def test_depth_valid_only_in_a_small_patch(self, cam):
        depth = np.full(cam.shape, np.nan, np.float32)
        depth[44:52, 76:84] = PLANE_Z
        ws = compute_warps(depth, cam, sphere_at(CENTER, RADIUS, subdivisions=4), pano_height=32)
        assert_finite_where_valid(ws)
        assert ws.stats["invalid_depth_pixels"] == depth.size - 64
        m = ws.object_mask
        assert m.sum() > 1500
        assert not np.any(ws.refraction_kind[m] == HitKind.LOST)
        ok = ws.refraction_valid & m
        ix = np.rint(ws.refraction[ok]).astype(int)
        assert np.all((ix[:, 0] >= 76) & (ix[:, 0] < 84) & (ix[:, 1] >= 44) & (ix[:, 1] < 52))
        # the rest of the refracted rays see unobserved space
        assert np.all(np.isin(ws.refraction_kind[m & ~ws.refraction_valid], (HitKind.UNOBSERVED, HitKind.TRAPPED)))
        assert (ws.refraction_kind[m] == HitKind.UNOBSERVED).mean() > 0.9

    @pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf, 0.0, -2.0, "mixed"])
    def test_all_invalid_is_an_error(self, cam, value):
        if value == "mixed":
            depth = np.resize(np.array([np.nan, np.inf, 0.0, -1.0], np.float32), cam.shape)
        else:
            depth = np.full(cam.shape, value, np.float32)
        with pytest.raises(ValueError, match="no valid pixel"):
            compute_warps(depth, cam, sphere_at(CENTER, RADIUS, subdivisions=2), pano_height=16)
