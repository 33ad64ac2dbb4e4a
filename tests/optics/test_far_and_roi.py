"""compute_warps with region-of-interest tracing (exact) and far background at infinity (within its
pixel bound); the far-field module itself is tested in test_far_field.py."""

import numpy as np
import pytest
from conftest import sphere_at

from snell_bench.optics import HitKind, compute_warps
from snell_bench.optics.warps import far_background_mask, object_pixel_box
from snell_bench.scene.camera import Camera

CENTER, RADIUS = np.array([0.3, 0.4, 3.0]), 0.5
FIELDS = ("refraction", "reflection", "pano_refraction", "pano_reflection", "pano_to_persp")


@pytest.fixture(scope="module")
def cam():
    return Camera.from_fov(320, 180, 60.0)


def two_planes(cam, near=6.0, far=3000.0):
    """A floor-like near plane in the lower half and a far backdrop (sky) in the upper half."""
    d = np.full(cam.shape, far, np.float32)
    d[cam.height // 2 :] = near
    return d


def test_roi_tracing_is_exact(cam):
    depth = two_planes(cam)
    obj = sphere_at(CENTER, RADIUS)
    a = compute_warps(depth, cam, obj, pano_height=32, roi=False)
    b = compute_warps(depth, cam, obj, pano_height=32, roi=True)
    for f in FIELDS + ("object_mask", "refraction_valid", "fresnel", "bounces", "pano_to_persp_object"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    assert b.stats["traced_primary_rays"] < 0.2 * a.stats["traced_primary_rays"]
    x0, y0, x1, y1 = object_pixel_box(obj, cam)
    ys, xs = np.nonzero(a.object_mask)
    assert xs.min() >= x0 and xs.max() <= x1 and ys.min() >= y0 and ys.max() <= y1


def test_far_background_moves_warps_less_than_the_tolerance(cam):
    depth = two_planes(cam)
    obj = sphere_at(CENTER, RADIUS)
    exact = compute_warps(depth, cam, obj, pano_height=32)
    for tol in (0.5, 1.0, 2.0):
        ws = compute_warps(depth, cam, obj, pano_height=32, infinity_tolerance_px=tol)
        fb = ws.stats["far_background"]
        assert fb["far_fraction"] == pytest.approx(0.5, abs=0.01)  # the backdrop, not the floor
        assert fb["max_bound_px_of_far"] < tol
        for f in ("refraction", "reflection", "pano_to_persp"):  # perspective pixels
            a, b = getattr(exact, f), getattr(ws, f)
            both = np.isfinite(a).all(-1) & np.isfinite(b).all(-1)
            assert both.sum() > 0.9 * np.isfinite(a).all(-1).sum(), f
            assert np.abs(a - b)[both].max() < tol, f
        np.testing.assert_array_equal(exact.object_mask, ws.object_mask)
        assert not np.isin(ws.refraction_kind[ws.object_mask], [HitKind.ESCAPED]).any()


def test_far_background_decides_per_pixel_and_rejects_bad_tolerance(cam):
    obj = sphere_at(CENTER, RADIUS)
    indoor = np.full(cam.shape, 6.0, np.float32)
    ws = compute_warps(indoor, cam, obj, pano_height=32, infinity_tolerance_px=1.0)
    assert ws.stats["far_background"]["far_fraction"] == 0.0
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="infinity_tolerance_px"):
            compute_warps(indoor, cam, obj, pano_height=32, infinity_tolerance_px=bad)
    depth = two_planes(cam)
    depth[:10] = np.nan  # holes stay holes: never "far"
    far, _ = far_background_mask(depth, cam, CENTER, RADIUS, 1.0)
    assert not far[:10].any() and far[20 : cam.height // 2 - 2].all()
