"""compute_warps against closed-form optics, invariants, persistence and bad input."""

import logging

import numpy as np
import pytest
import torch
from conftest import analytic_sphere_plane, sphere_at

from snell_bench.optics import HitKind, WarpSet, compute_warps, fresnel_cos
from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject

CENTER, RADIUS, PLANE_Z = np.array([0.1, -0.2, 3.0]), 0.5, 5.0


@pytest.fixture(scope="module")
def cam():
    return Camera.from_fov(640, 360, 60.0)


@pytest.fixture(scope="module")
def plane_depth(cam):
    return np.full(cam.shape, PLANE_Z, np.float32)


@pytest.fixture(scope="module")
def sphere_warps(cam, plane_depth):
    return compute_warps(plane_depth, cam, sphere_at(CENTER, RADIUS), pano_height=64)


def refraction_error(ws, cam, ior=1.5):
    m = ws.object_mask & ws.refraction_valid
    ys, xs = np.nonzero(m)
    dirs = cam.pixel_rays(np.stack([xs, ys], -1).astype(float))
    p, _ = analytic_sphere_plane(dirs, CENTER, RADIUS, ior, PLANE_Z)
    pix, _ = cam.project(p)
    ok = np.isfinite(pix).all(1)
    return np.linalg.norm(pix[ok] - ws.refraction[ys[ok], xs[ok]], axis=-1)


class TestClosedFormSphere:
    def test_interpolated_normals_match_analytic_sphere(self, sphere_warps, cam):
        err = refraction_error(sphere_warps, cam)
        assert len(err) > 20_000
        assert np.median(err) < 0.15, f"median warp error {np.median(err):.3f} px"
        assert np.percentile(err, 75) < 0.3

    def test_face_normals_are_much_less_accurate(self, sphere_warps, cam, plane_depth):
        ws = compute_warps(plane_depth, cam, sphere_at(CENTER, RADIUS), pano_height=16, normals="face")
        assert np.median(refraction_error(ws, cam)) > 5 * np.median(refraction_error(sphere_warps, cam))

    def test_object_mask_matches_sphere_silhouette(self, sphere_warps, cam):
        dirs = cam.pixel_rays().reshape(-1, 3)
        _, p1 = analytic_sphere_plane(dirs, CENTER, RADIUS, 1.5, PLANE_Z)
        analytic = np.isfinite(p1).all(1).reshape(cam.shape)
        disagree = (analytic != sphere_warps.object_mask).sum()
        assert disagree < 0.01 * analytic.sum()  # only silhouette pixels of the polygonal sphere

    def test_image_is_flipped(self, sphere_warps, cam):
        cx, cy = cam.project(CENTER[None])[0][0]
        row = int(round(cy))
        m = sphere_warps.object_mask[row] & sphere_warps.refraction_valid[row]
        xs = np.flatnonzero(m)
        src_x = sphere_warps.refraction[row, xs, 0]
        assert np.all(np.diff(src_x) < 0), "a glass sphere shows the background mirrored left-right"
        # and magnified: the source span is wider than the sphere's own span
        assert np.ptp(src_x) > np.ptp(xs)

    def test_sphere_needs_two_interactions(self, sphere_warps):
        b = sphere_warps.bounces[sphere_warps.object_mask]
        assert np.mean(b == 2) > 0.999

    def test_fresnel_matches_incidence_angle(self, sphere_warps, cam):
        ys, xs = np.nonzero(sphere_warps.object_mask)
        dirs = cam.pixel_rays(np.stack([xs, ys], -1).astype(float))
        _, p1 = analytic_sphere_plane(dirs, CENTER, RADIUS, 1.5, PLANE_Z)
        ok = np.isfinite(p1).all(1)
        cos_i = -((p1[ok] - CENTER) / RADIUS * dirs[ok]).sum(-1)
        ref = fresnel_cos(torch.from_numpy(cos_i), 1.0, 1.5).numpy()
        got = sphere_warps.fresnel[ys[ok], xs[ok]]
        assert np.median(np.abs(got - ref)) < 1e-3
        # the pixel nearest normal incidence reflects 4 %, the silhouette nearly everything
        assert float(np.min(sphere_warps.fresnel[ys, xs])) == pytest.approx(0.04, abs=2e-4)
        assert float(np.max(sphere_warps.fresnel[ys, xs])) > 0.5

    def test_identity_outside_object(self, sphere_warps, cam):
        out = ~sphere_warps.object_mask
        np.testing.assert_array_equal(sphere_warps.refraction[out], cam.pixel_grid()[out].astype(np.float32))
        assert sphere_warps.refraction_valid[out].all()
        assert np.all(sphere_warps.fresnel[out] == 0)

    def test_no_nan_where_valid(self, sphere_warps):
        ws = sphere_warps
        for warp, valid in [
            (ws.refraction, ws.refraction_valid),
            (ws.reflection, ws.reflection_valid),
            (ws.pano_refraction, ws.pano_refraction_valid),
            (ws.pano_reflection, ws.pano_reflection_valid),
            (ws.pano_to_persp, ws.pano_to_persp_valid),
        ]:
            assert np.isfinite(warp[valid]).all()
            assert np.isnan(warp[~valid]).all() or warp is ws.refraction

    def test_required_call_signature(self):
        H, W = 48, 64
        K = np.array([[60.0, 0, (W - 1) / 2], [0, 60.0, (H - 1) / 2], [0, 0, 1]])
        sph = sphere_at([0, 0, 3.0], 0.6, subdivisions=3)
        vertices, faces = sph.vertices, sph.faces
        ws = compute_warps(
            depth=np.full((H, W), 5.0, np.float32),
            camera=Camera(K=K, width=W, height=H),
            obj=GlassObject.from_mesh(vertices, faces, ior=1.5),
            pano_height=128,
        )
        assert ws.object_mask.shape == (H, W) and ws.refraction.shape == (H, W, 2)
        assert ws.pano_to_persp.shape == (128, 256, 2)
        assert ws.object_mask.sum() > 100


class TestIORLimits:
    def test_unit_ior_is_identity(self, cam, plane_depth):
        ws = compute_warps(plane_depth, cam, sphere_at(CENTER, RADIUS, ior=1.0), pano_height=16)
        m = ws.object_mask
        assert ws.refraction_valid[m].mean() > 0.999
        v = m & ws.refraction_valid
        err = np.abs(ws.refraction[v] - cam.pixel_grid()[v])
        assert err.max() < 2e-3
        assert np.all(ws.fresnel[m] < 1e-6)

    def test_warp_approaches_identity_continuously(self, cam, plane_depth):
        errs = []
        for ior in (1 + 1e-6, 1.001, 1.01, 1.1):
            ws = compute_warps(plane_depth, cam, sphere_at(CENTER, RADIUS, ior=ior), pano_height=16)
            v = ws.object_mask & ws.refraction_valid
            errs.append(float(np.median(np.linalg.norm(ws.refraction[v] - cam.pixel_grid()[v], axis=-1))))
        assert errs[0] < 1e-3
        assert all(a < b for a, b in zip(errs, errs[1:])), errs


class TestTotalInternalReflection:
    def test_diamond_cube_bounces_and_terminates(self, cam, plane_depth):
        # a cube turned 45 deg about two axes: many paths totally reflect inside
        import trimesh

        box = trimesh.creation.box(extents=(0.8, 0.8, 0.8))
        R = trimesh.transformations.euler_matrix(0.6, 0.785, 0.0)
        box.apply_transform(R)
        box.apply_translation([0.0, 0.0, 3.0])
        obj = GlassObject.from_mesh(box.vertices, box.faces, ior="diamond")
        ws = compute_warps(plane_depth, cam, obj, pano_height=16)
        b = ws.bounces[ws.object_mask]
        assert (b >= 3).mean() > 0.2, "expected total internal reflection inside a diamond cube"
        kinds = ws.refraction_kind[ws.object_mask]
        assert not np.any(kinds == HitKind.LOST)
        assert np.any(ws.fresnel[ws.object_mask] > 0.1)

    def test_max_bounces_marks_trapped(self, cam, plane_depth):
        ws = compute_warps(plane_depth, cam, sphere_at(CENTER, RADIUS), pano_height=16, max_bounces=1)
        kinds = ws.refraction_kind[ws.object_mask]
        assert np.all(kinds == HitKind.TRAPPED)
        assert not ws.refraction_valid[ws.object_mask].any()
        assert not ws.pano_refraction_valid[ws.object_mask].any()


class TestPanorama:
    def test_pano_to_persp_round_trip(self, sphere_warps, cam, plane_depth):
        ws = sphere_warps
        # perspective pixels of the plane -> panorama pixel -> back through pi
        rng = np.random.default_rng(0)
        xs, ys = rng.integers(0, cam.width, 400), rng.integers(0, cam.height, 400)
        keep = ~ws.object_mask[ys, xs]
        xs, ys = xs[keep], ys[keep]
        pts = cam.unproject(plane_depth)[ys, xs]
        uv = ws.pano.project_points(pts)
        iu = np.clip(np.rint(uv).astype(int), 0, [ws.pano.width - 1, ws.pano.height - 1])
        back = ws.pano_to_persp[iu[:, 1], iu[:, 0]]
        ok = ws.pano_to_persp_valid[iu[:, 1], iu[:, 0]]
        assert ok.mean() > 0.95
        # rounding to the panorama pixel grid moves the point by under one panorama pixel
        px_per_rad = cam.K[0, 0] * 5.0 / (5.0 - CENTER[2])  # magnification of plane points seen from the centre
        tol = px_per_rad * (2 * np.pi / ws.pano.width)
        assert np.all(np.linalg.norm(back[ok] - np.stack([xs, ys], -1)[ok], axis=-1) < tol)

    def test_pano_is_level_and_centred_on_object(self, sphere_warps):
        p = sphere_warps.pano
        np.testing.assert_allclose(p.center, CENTER, atol=1e-3)
        np.testing.assert_allclose(p.rotation[:, 1], [0, 1, 0], atol=1e-12)  # down is the camera's down

    def test_unit_ior_panorama_warp_sees_straight_through(self, cam, plane_depth):
        ws = compute_warps(plane_depth, cam, sphere_at(CENTER, RADIUS, ior=1.0), pano_height=64)
        m = ws.object_mask & ws.pano_refraction_valid
        pts = cam.unproject(plane_depth)[m]
        np.testing.assert_allclose(ws.pano_refraction[m], ws.pano.project_points(pts), atol=1e-2)

    def test_reflection_at_centre_looks_back(self, sphere_warps, cam):
        (cx, cy) = cam.project(CENTER[None])[0][0]
        x, y = int(round(cx)), int(round(cy))
        assert sphere_warps.object_mask[y, x] and sphere_warps.pano_reflection_valid[y, x]
        u, v = sphere_warps.pano_reflection[y, x]
        W = sphere_warps.pano.width
        assert min(abs(u - (-0.5)), abs(u - (W - 0.5))) < 0.1 * W  # the back of the panorama
        assert not sphere_warps.reflection_valid[y, x]  # behind the camera: I⁻ cannot show it

    def test_object_occludes_pano_to_persp(self, sphere_warps):
        ws = sphere_warps
        occ = ws.pano_to_persp_object
        assert occ.any() and not (occ & ~ws.pano_to_persp_valid).any()
        pix = np.rint(ws.pano_to_persp[occ]).astype(int)
        assert ws.object_mask[pix[:, 1], pix[:, 0]].all()


class TestDepthProblems:
    def test_hole_behind_sphere_invalidates_only_those_rays(self, cam, caplog):
        depth = np.full(cam.shape, PLANE_Z, np.float32)
        depth[150:210, 280:360] = np.nan
        depth[0, 0] = np.inf
        depth[0, 1] = 0.0
        depth[0, 2] = -1.0
        with caplog.at_level(logging.WARNING):
            ws = compute_warps(depth, cam, sphere_at(CENTER, RADIUS), pano_height=16)
        assert "invalid" in caplog.text
        assert ws.stats["invalid_depth_pixels"] == 60 * 80 + 3
        m = ws.object_mask
        ys, xs = np.nonzero(m)
        dirs = cam.pixel_rays(np.stack([xs, ys], -1).astype(float))
        p, _ = analytic_sphere_plane(dirs, CENTER, RADIUS, 1.5, PLANE_Z)
        pix, _ = cam.project(p)
        lands_in_hole = (pix[:, 0] > 281) & (pix[:, 0] < 358) & (pix[:, 1] > 151) & (pix[:, 1] < 208)
        lands_on_plane = ((pix[:, 0] < 278) | (pix[:, 0] > 362) | (pix[:, 1] < 148) | (pix[:, 1] > 212)) & (
            (pix[:, 0] > 2) & (pix[:, 0] < cam.width - 3) & (pix[:, 1] > 2) & (pix[:, 1] < cam.height - 3)
        )
        assert lands_in_hole.sum() > 100
        assert not ws.refraction_valid[ys[lands_in_hole], xs[lands_in_hole]].any()
        assert ws.refraction_valid[ys[lands_on_plane], xs[lands_on_plane]].mean() > 0.99
        assert np.all(ws.refraction_kind[ys[lands_in_hole], xs[lands_in_hole]] == HitKind.UNOBSERVED)
        for a in (ws.refraction, ws.pano_refraction, ws.pano_to_persp):
            assert not np.isinf(a).any()

    def test_all_invalid_depth_is_an_error(self, cam):
        with pytest.raises(ValueError, match="no valid pixel"):
            compute_warps(np.full(cam.shape, np.nan), cam, sphere_at(CENTER, RADIUS), pano_height=16)

    def test_depth_shape_mismatch(self, cam):
        with pytest.raises(ValueError, match="camera's"):
            compute_warps(np.full((10, 10), 5.0), cam, sphere_at(CENTER, RADIUS), pano_height=16)


class TestBadObjects:
    def test_behind_camera(self, cam, plane_depth):
        with pytest.raises(ValueError, match="behind the camera"):
            compute_warps(plane_depth, cam, sphere_at([0, 0, -3.0], 0.5), pano_height=16)

    def test_crossing_camera_plane(self, cam, plane_depth):
        with pytest.raises(ValueError, match="crossing the camera plane"):
            compute_warps(plane_depth, cam, sphere_at([0, 0, 0.2], 0.5), pano_height=16)

    def test_outside_view(self, cam, plane_depth):
        with pytest.raises(ValueError, match="outside the view"):
            compute_warps(plane_depth, cam, sphere_at([30.0, 0, 3.0], 0.5), pano_height=16)

    def test_unplaced_object(self, cam, plane_depth):
        with pytest.raises(ValueError, match="place it first"):
            compute_warps(plane_depth, cam, GlassObject.sphere(), pano_height=16)

    def test_bad_pano_height_and_up(self, cam, plane_depth):
        obj = sphere_at(CENTER, RADIUS, subdivisions=2)
        with pytest.raises(ValueError, match="pano_height"):
            compute_warps(plane_depth, cam, obj, pano_height=0)
        with pytest.raises(ValueError, match="up"):
            compute_warps(plane_depth, cam, obj, pano_height=16, up=(0, 0, 0))

    def test_subpixel_object_gives_empty_mask(self, cam, plane_depth, caplog):
        # a sphere much smaller than a pixel, between pixel centres: a documented empty mask
        f = cam.K[0, 0]
        c = np.array([(0.5 - cam.K[0, 2]) / f * 3.0, (0.5 - cam.K[1, 2]) / f * 3.0, 3.0])
        with caplog.at_level(logging.WARNING):
            ws = compute_warps(plane_depth, cam, sphere_at(c, 0.1 / f, subdivisions=2), pano_height=16)
        assert "empty" in caplog.text
        assert not ws.object_mask.any()
        assert ws.refraction_valid.all()
        np.testing.assert_array_equal(ws.refraction, cam.pixel_grid().astype(np.float32))


class TestPersistence:
    def test_save_load_round_trip(self, sphere_warps, tmp_path):
        p = sphere_warps.save(tmp_path / "w.npz")
        ws = WarpSet.load(p)
        names = ("object_mask", "refraction", "fresnel", "pano_to_persp", "pano_reflection", "bounces")
        for name in names + ("pano_refraction_frame", "pano_refraction_frame_valid"):
            np.testing.assert_array_equal(getattr(ws, name), getattr(sphere_warps, name))
        assert ws.camera == sphere_warps.camera and ws.ior == 1.5
        np.testing.assert_array_equal(ws.pano.rotation, sphere_warps.pano.rotation)
        assert ws.input_hash == sphere_warps.input_hash

    def test_save_is_atomic(self, sphere_warps, tmp_path):
        """Missing folders are created, no temporary is left behind, and the file gets the mode of
        a new file under the process's umask."""
        import os

        p = sphere_warps.save(tmp_path / "a" / "b" / "w.npz")
        assert sorted(f.name for f in p.parent.iterdir()) == ["w.npz"]
        mask = os.umask(0)
        os.umask(mask)
        assert p.stat().st_mode & 0o777 == 0o666 & ~mask
        sphere_warps.save(p)  # overwriting is atomic too
        assert sorted(f.name for f in p.parent.iterdir()) == ["w.npz"]
        np.testing.assert_array_equal(WarpSet.load(p).pano_to_persp, sphere_warps.pano_to_persp)

    def test_load_rejects_other_versions(self, sphere_warps, tmp_path):
        import json

        p = sphere_warps.save(tmp_path / "w.npz")
        with np.load(p) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(str(arrays["meta"]))
        meta["version"] = -1
        arrays["meta"] = np.array(json.dumps(meta))
        np.savez_compressed(p, **arrays)
        with pytest.raises(ValueError, match="version -1"):
            WarpSet.load(p)

    def test_stats_and_stage_timings(self, sphere_warps):
        st = sphere_warps.stats
        assert list(st["timings_s"]) == ["build", "primary", "refraction", "reflection", "panorama", "frame"]
        assert st["roi"] is True and st["traced_primary_rays"] < sphere_warps.object_mask.size
        assert st["background_triangles"] > 0 and "far_background" not in st

    def test_cache_and_hash(self, cam, plane_depth, tmp_path):
        obj = sphere_at(CENTER, RADIUS, subdivisions=3)
        a = compute_warps(plane_depth, cam, obj, pano_height=16, cache_dir=tmp_path)
        files = list(tmp_path.glob("*.npz"))
        assert [f.stem for f in files] == [a.input_hash]
        b = compute_warps(plane_depth, cam, obj, pano_height=16, cache_dir=tmp_path)
        np.testing.assert_array_equal(a.refraction, b.refraction)
        c = compute_warps(plane_depth, cam, obj.with_ior(1.4), pano_height=16, cache_dir=tmp_path)
        assert c.input_hash != a.input_hash and len(list(tmp_path.glob("*.npz"))) == 2

    @pytest.mark.parametrize("damage", ["truncate", "garbage", "empty"])
    def test_unreadable_cache_entry_is_a_miss(self, cam, plane_depth, tmp_path, caplog, damage):
        """A damaged cache file is logged with its path, deleted and recomputed; the new entry
        reads back."""
        obj = sphere_at(CENTER, RADIUS, subdivisions=3)
        a = compute_warps(plane_depth, cam, obj, pano_height=16, cache_dir=tmp_path)
        (f,) = tmp_path.glob("*.npz")
        data = f.read_bytes()
        f.write_bytes({"truncate": data[: len(data) // 2], "garbage": b"not a zip" * 100, "empty": b""}[damage])
        with caplog.at_level(logging.WARNING, logger="snell_bench.optics.warps"):
            b = compute_warps(plane_depth, cam, obj, pano_height=16, cache_dir=tmp_path)
        assert str(f) in caplog.text and "recomputing" in caplog.text
        np.testing.assert_array_equal(a.refraction, b.refraction)
        np.testing.assert_array_equal(WarpSet.load(f).refraction, a.refraction)  # rewritten whole
        assert sorted(p.name for p in tmp_path.iterdir()) == [f.name]  # no temporaries

    def test_deterministic(self, cam, plane_depth):
        obj = sphere_at(CENTER, RADIUS, subdivisions=3)
        a = compute_warps(plane_depth, cam, obj, pano_height=16)
        b = compute_warps(plane_depth, cam, obj, pano_height=16)
        np.testing.assert_array_equal(a.refraction, b.refraction)
        np.testing.assert_array_equal(a.pano_to_persp, b.pano_to_persp)


def test_depth_mesh_points_are_always_visible(cam):
    """The visibility argument of _self_warp: with a depth-map background, explicit camera-ray
    visibility checks change nothing, even with occluding steps in the depth."""
    depth = np.full(cam.shape, PLANE_Z, np.float32)
    depth[:, 330:] = 3.6  # a near wall on the right, partly behind the sphere
    depth[200:, :200] = 2.8  # a near block lower left
    obj = sphere_at(CENTER, RADIUS, subdivisions=4)
    a = compute_warps(depth, cam, obj, pano_height=64)
    b = compute_warps(depth, cam, obj, pano_height=64, verify_visibility=True)
    assert a.stats["cut_triangles"] > 0
    for name in ("refraction_valid", "reflection_valid", "pano_to_persp_valid"):
        va, vb = getattr(a, name), getattr(b, name)
        assert (va != vb).sum() <= 1e-4 * va.size, name
