"""π⁻¹ over the whole frame (``WarpSet.pano_refraction_frame``) against closed forms: the panorama
pixel of each background point, occlusion from the panorama centre, far background, persistence."""

import numpy as np
import pytest
from conftest import sphere_at
from tolerances import EPS32

from snell_bench.optics import WarpSet, compute_warps
from snell_bench.scene.camera import Camera

CENTER, RADIUS, PLANE_Z = np.array([0.0, 0.0, 3.0]), 0.5, 5.0
SHEET_Z, SHEET_X = 4.0, (0.2, 0.4)  # a floating sheet at z = 4, seen between x/z = 0.2 and 0.4


@pytest.fixture(scope="module")
def cam():
    return Camera.from_fov(64, 48, 60.0)


def hand_pano_pixel(p, c, pano_height):
    """Panorama pixel of points ``p`` seen from ``c``, written out from the documented convention
    (panorama frame = camera frame for the default up (0, -1, 0) and forward +z): longitude
    atan2(x, z), latitude atan2(-y, hypot(x, z)), ``u = (lon / 2pi + 0.5) W - 0.5``,
    ``v = (0.5 - lat / pi) H - 0.5``."""
    d = np.asarray(p, np.float64) - c
    lon = np.arctan2(d[:, 0], d[:, 2])
    lat = np.arctan2(-d[:, 1], np.hypot(d[:, 0], d[:, 2]))
    Hp, Wp = pano_height, 2 * pano_height
    return np.stack([(lon / (2 * np.pi) + 0.5) * Wp - 0.5, (0.5 - lat / np.pi) * Hp - 0.5], -1)


def pixel_tolerance(p, c, pano_height):
    """Float32 rounding of the mesh vertex (``EPS32 |p|`` per coordinate) turns the direction from
    ``c`` by at most ``sqrt(3) EPS32 |p| / |p - c|`` radians, ``Wp / 2pi`` pixels per radian on
    each axis; the stored float32 pixel adds ``EPS32 Wp``. Twice the sum."""
    p = np.asarray(p, np.float64)
    turn = np.sqrt(3) * EPS32 * np.linalg.norm(p, axis=1) / np.linalg.norm(p - c, axis=1)
    Wp = 2 * pano_height
    return 2 * (Wp / (2 * np.pi) * np.sqrt(2) * turn.max() + EPS32 * Wp)


def sheet_depth(cam):
    """The plane z = 5 with a sheet at z = 4 in front of it, over the pixels whose rays have
    x/z in [0.2, 0.4] (cut from the plane at both edges: a relative depth jump of 25 %)."""
    xn = cam.pixel_rays(normalize=False)[..., 0]
    return np.where((xn >= SHEET_X[0]) & (xn <= SHEET_X[1]), SHEET_Z, PLANE_Z).astype(np.float32)


class TestClosedForm:
    def test_background_pixels_see_their_point_from_the_centre(self, cam):
        """A plane behind a sphere: every pixel off the object maps to the panorama pixel of its
        plane point seen from the sphere's centre; the object keeps ``pano_refraction``."""
        ws = compute_warps(np.full(cam.shape, PLANE_Z, np.float32), cam, sphere_at(CENTER, RADIUS), pano_height=32)
        np.testing.assert_allclose(ws.pano.rotation, np.eye(3), atol=1e-12)
        c = ws.pano.center
        np.testing.assert_allclose(c, CENTER, atol=1e-3)  # the icosphere's centre
        off = ~ws.object_mask
        p = cam.unproject(np.full(cam.shape, PLANE_Z))[off]
        expected = hand_pano_pixel(p, c, 32)
        np.testing.assert_allclose(ws.pano_refraction_frame[off], expected, atol=pixel_tolerance(p, c, 32), rtol=0)
        assert ws.pano_refraction_frame_valid[off].all()
        m = ws.object_mask
        assert m.sum() > 100
        np.testing.assert_array_equal(ws.pano_refraction_frame[m], ws.pano_refraction[m])
        np.testing.assert_array_equal(ws.pano_refraction_frame_valid, np.isfinite(ws.pano_refraction_frame).all(-1))

    def test_occluder_between_centre_and_point_gives_nan(self, cam):
        """A sheet at z = 4 that the camera sees beside the object hides the plane points beyond
        it from the panorama centre: the segment from the centre to a plane point crosses z = 4
        at ``m``, and the point is hidden iff ``m`` falls on the sheet (decided here away from its
        edges, where the triangulation between pixel centres makes the answer ambiguous)."""
        depth = sheet_depth(cam)
        ws = compute_warps(depth, cam, sphere_at(CENTER, RADIUS), pano_height=32)
        c = ws.pano.center
        p = cam.unproject(depth.astype(np.float64))
        s = (SHEET_Z - c[2]) / (p[..., 2] - c[2])
        mx = (c[0] + s * (p[..., 0] - c[0])) / SHEET_Z  # x/z of the crossing
        one_px = 1.0 / cam.K[0, 0]
        on_plane = (depth == PLANE_Z) & ~ws.object_mask
        hidden = on_plane & (mx > SHEET_X[0] + one_px) & (mx < SHEET_X[1] - one_px)
        seen = on_plane & ((mx < SHEET_X[0] - one_px) | (mx > SHEET_X[1] + one_px))
        sheet = (depth == SHEET_Z) & ~ws.object_mask
        assert hidden.sum() > 200 and seen.sum() > 500 and sheet.sum() > 200
        assert np.isnan(ws.pano_refraction_frame[hidden]).all()
        assert not ws.pano_refraction_frame_valid[hidden].any()
        assert ws.pano_refraction_frame_valid[seen].all() and ws.pano_refraction_frame_valid[sheet].all()
        for region in (seen, sheet):
            expected = hand_pano_pixel(p[region], c, 32)
            np.testing.assert_allclose(
                ws.pano_refraction_frame[region], expected, atol=pixel_tolerance(p[region], c, 32), rtol=0
            )

    def test_grazing_floor_is_not_self_occluded(self, cam):
        """A floor (y = 1) meeting a wall (z = 6), the object resting on the floor: from its centre
        the floor is seen at down to 2 degrees, and every floor and wall point is visible (a
        concave corner seen from inside): the tolerance of the re-cast keeps grazing hits on the
        point's own surface from counting as occluders."""
        yn = cam.pixel_rays(normalize=False)[..., 1]
        with np.errstate(divide="ignore"):
            depth = np.where(yn > 0, np.minimum(1.0 / yn, 6.0), 6.0).astype(np.float32)
        r = 0.1
        ws = compute_warps(depth, cam, sphere_at([0.0, 1.0 - r - 1e-3, 3.0], r), pano_height=32)
        off = ~ws.object_mask
        assert ws.pano_refraction_frame_valid[off].all()

    def test_far_background_is_seen_by_direction(self, cam):
        """Background treated as at infinity: the pixel's ray direction, seen from anywhere, is
        the panorama pixel of that direction."""
        depth = np.full(cam.shape, 1e4, np.float32)
        ws = compute_warps(depth, cam, sphere_at(CENTER, RADIUS), pano_height=32, infinity_tolerance_px=0.5)
        assert ws.stats["far_background"]["far_fraction"] > 0.99
        off = ~ws.object_mask
        d = cam.pixel_rays()[off]
        expected = hand_pano_pixel(d, np.zeros(3), 32)
        np.testing.assert_allclose(
            ws.pano_refraction_frame[off], expected, atol=2 * EPS32 * 64, rtol=0
        )  # float32 storage

    def test_no_depth_is_nan(self, cam):
        depth = np.full(cam.shape, PLANE_Z, np.float32)
        depth[:, :8] = np.nan
        ws = compute_warps(depth, cam, sphere_at(CENTER, RADIUS), pano_height=32)
        assert np.isnan(ws.pano_refraction_frame[:, :8]).all()
        assert ws.pano_refraction_frame_valid[:, 9:][~ws.object_mask[:, 9:]].all()


def test_save_load_keeps_the_frame_map(cam, tmp_path):
    ws = compute_warps(sheet_depth(cam), cam, sphere_at(CENTER, RADIUS), pano_height=16)
    back = WarpSet.load(ws.save(tmp_path / "w.npz"))
    np.testing.assert_array_equal(back.pano_refraction_frame, ws.pano_refraction_frame)
    np.testing.assert_array_equal(back.pano_refraction_frame_valid, ws.pano_refraction_frame_valid)
    assert np.isnan(back.pano_refraction_frame).any()  # the occluded pixels survive as NaN


def test_unoccluded_from_sees_only_the_front_side(cam):
    """Points of the plane z = 5 (the depth mesh faces the camera): seen from in front (z = 3),
    not from behind it (z = 6), with the mesh's vertex normals (without them, only where the
    re-cast hits a triangle at the point rather than slipping between them); a sheet at z = 4 in
    between hides the points behind it."""
    from snell_bench.optics import SceneTracer
    from snell_bench.optics.warp_maps import vertex_normals
    from snell_bench.scene.depth_mesh import build_background

    obj = sphere_at(CENTER, RADIUS)
    bg = build_background(np.full(cam.shape, PLANE_Z, np.float32), cam, extra_points=[[0, 0, 7]])
    plane, normals = bg.vertices.astype(np.float64), vertex_normals(bg.vertices, bg.faces)
    np.testing.assert_allclose(normals / np.linalg.norm(normals, axis=1, keepdims=True), [[0, 0, -1]] * len(plane))
    tracer = SceneTracer(bg, obj)
    assert tracer.unoccluded_from(np.array([0.1, 0.2, 3.0]), plane, normals).all()
    assert tracer.unoccluded_from(np.array([0.1, 0.2, 3.0]), plane).all()
    assert not tracer.unoccluded_from(np.array([0.1, 0.2, 6.0]), plane, normals).any()
    tracer = SceneTracer(build_background(sheet_depth(cam), cam), obj)
    inner = (sheet_depth(cam) == SHEET_Z)[0]
    inner = inner & np.roll(inner, 1) & np.roll(inner, -1)  # columns inside the sheet's edges
    assert inner.sum() > 5
    p = cam.unproject(np.full(cam.shape, PLANE_Z))[1:-1, inner].reshape(-1, 3)  # behind the sheet
    assert not tracer.unoccluded_from(np.zeros(3), p).any()  # the camera's own view: hidden
