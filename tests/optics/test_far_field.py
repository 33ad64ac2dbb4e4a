"""far_field: the far-background bound and mask, and rays resolved at infinity."""

import numpy as np
import pytest

from snell_bench.optics import HitKind, far_field, warps
from snell_bench.optics.far_field import POINT_AT_INFINITY, AtInfinity, far_background_mask
from snell_bench.scene.camera import Camera

CENTER, RADIUS = np.array([0.3, 0.4, 3.0]), 0.5


@pytest.fixture(scope="module")
def cam():
    return Camera.from_fov(320, 180, 60.0)


def two_planes(cam, near=6.0, far=3000.0):
    """A floor-like near plane in the lower half and a far backdrop (sky) in the upper half."""
    d = np.full(cam.shape, far, np.float32)
    d[cam.height // 2 :] = near
    return d


def test_warps_reexports_far_background_mask():
    assert warps.far_background_mask is far_field.far_background_mask
    assert "far_background_mask" in warps.__all__


def test_far_bound_holds_against_brute_force(cam):
    """The per-pixel bound of far_background_mask is an upper bound of the true pixel error for
    rays from anywhere in the object's ball to the background, and not loose by much."""
    depth = np.full(cam.shape, 400.0)
    far, bound = far_background_mask(depth, cam, CENTER, RADIUS, tolerance_px=1e9)
    assert far.all()
    rng = np.random.default_rng(0)
    f = cam.K[0, 0]
    worst_ratio = 0.0
    for _ in range(200):
        x, y = rng.uniform(0, cam.width - 1), rng.uniform(0, cam.height - 1)
        q = cam.unproject(np.full(cam.shape, 400.0))[int(round(y)), int(round(x))]  # a far point
        v = rng.normal(size=(500, 3))
        p = CENTER + RADIUS * v / np.linalg.norm(v, axis=1, keepdims=True) * rng.uniform(0, 1, (500, 1)) ** (1 / 3)
        d = q - p  # direction of the ray from p that ends at q
        exact, _ = cam.project(q[None])
        at_inf, _ = cam.project(d)
        err = np.linalg.norm(at_inf - exact, axis=1).max()
        b = bound[int(round(y)), int(round(x))]
        assert err <= b * 1.01 + 1e-9
        worst_ratio = max(worst_ratio, err / b)
    assert worst_ratio > 0.3  # the bound is not vacuous
    assert f > 0


def test_mask_decides_per_pixel_and_keeps_holes(cam):
    depth = two_planes(cam)
    depth[:10] = np.nan  # holes stay holes: never "far"
    far, bound = far_background_mask(depth, cam, CENTER, RADIUS, 1.0)
    assert not far[:10].any() and np.isinf(bound[:10]).all()
    assert far[20 : cam.height // 2 - 2].all()
    assert not far[cam.height // 2 + 1 :].any()  # the near floor


def test_bound_uses_the_nearest_depth_of_the_3x3_neighbourhood():
    """Without a panorama the bound is ``f * lateral / zmin``, ``zmin`` the smallest valid depth of
    the 3 x 3 neighbourhood, the border pixels repeated."""
    cam = Camera.from_fov(9, 7, 60.0)
    _, unit = far_background_mask(np.ones(cam.shape), cam, CENTER, RADIUS, 1.0)  # f * lateral
    depth = np.full(cam.shape, 400.0)
    depth[0, 0] = 4.0  # a near corner pixel
    _, bound = far_background_mask(depth, cam, CENTER, RADIUS, 1.0)
    zmin = unit / bound
    np.testing.assert_allclose(zmin[:2, :2], 4.0, rtol=1e-12)
    zmin[:2, :2] = 400.0
    np.testing.assert_allclose(zmin, 400.0, rtol=1e-12)

    rng = np.random.default_rng(1)
    depth = rng.uniform(50.0, 500.0, cam.shape)
    depth[rng.random(cam.shape) < 0.2] = np.nan
    valid = np.isfinite(depth)
    _, bound = far_background_mask(depth, cam, CENTER, RADIUS, 1.0)
    zp = np.pad(np.where(valid, depth, np.inf), 1, mode="edge")
    zmin = np.min([zp[dy : dy + 7, dx : dx + 9] for dy in range(3) for dx in range(3)], axis=0)
    np.testing.assert_allclose(bound[valid], (unit / zmin)[valid], rtol=1e-12)
    assert np.isinf(bound[~valid]).all()


def test_panorama_height_only_tightens_the_mask(cam):
    depth = np.full(cam.shape, 300.0)
    far_p, bound_p = far_background_mask(depth, cam, CENTER, RADIUS, 2.0)
    far_pp, bound_pp = far_background_mask(depth, cam, CENTER, RADIUS, 2.0, pano_height=512)
    assert np.all(bound_pp >= bound_p) and not (far_pp & ~far_p).any()


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_tolerance_is_rejected(cam, bad):
    with pytest.raises(ValueError, match="infinity_tolerance_px"):
        far_background_mask(np.full(cam.shape, 10.0), cam, CENTER, RADIUS, bad)


class TestAtInfinity:
    @pytest.fixture
    def small(self):
        return Camera.from_fov(16, 12, 60.0)

    def test_resolves_escaped_and_box_rays_onto_far_pixels(self, small):
        far = np.zeros(small.shape, bool)
        far[:, 8:] = True  # the right half is far
        at_inf = AtInfinity(small, far)
        right, left, behind = [0.2, 0.0, 1.0], [-0.2, 0.0, 1.0], [0.0, 0.0, -1.0]
        direction = np.array([right, right, left, behind, right])
        kind = np.array(
            [HitKind.ESCAPED, HitKind.UNOBSERVED, HitKind.ESCAPED, HitKind.ESCAPED, HitKind.OBSERVED], np.int8
        )
        on_box = np.array([False, True, False, False, False])
        point = np.full((5, 3), np.nan)
        point[1] = [1.0, 0.0, 5.0]
        point[4] = [1.0, 0.0, 5.0]
        at_inf.resolve(kind, point, direction, on_box)
        assert kind.tolist() == [HitKind.OBSERVED, HitKind.OBSERVED, HitKind.ESCAPED, HitKind.ESCAPED, HitKind.OBSERVED]
        unit = np.array(right) / np.linalg.norm(right)
        np.testing.assert_array_equal(point[0], unit * POINT_AT_INFINITY)
        np.testing.assert_array_equal(point[1], unit * POINT_AT_INFINITY)
        assert np.isnan(point[2:4]).all()  # near pixel, or behind the camera: unchanged
        np.testing.assert_array_equal(point[4], [1.0, 0.0, 5.0])  # a mesh hit is never touched

    def test_points_at_infinity_project_along_their_direction(self, small):
        at_inf = AtInfinity(small, np.ones(small.shape, bool))
        d = np.array([[0.1, -0.05, 1.0]])
        kind, point = np.array([HitKind.ESCAPED], np.int8), np.full((1, 3), np.nan)
        at_inf.resolve(kind, point, d, np.zeros(1, bool))
        np.testing.assert_allclose(small.project(point)[0], small.project(d)[0], atol=1e-9)

    def test_nothing_to_resolve(self, small):
        at_inf = AtInfinity(small, np.ones(small.shape, bool))
        kind = np.array([HitKind.OBSERVED], np.int8)
        point = np.array([[0.0, 0.0, 5.0]])
        at_inf.resolve(kind, point, np.array([[0.0, 0.0, 1.0]]), np.zeros(1, bool))
        assert kind.tolist() == [HitKind.OBSERVED] and point.tolist() == [[0.0, 0.0, 5.0]]
