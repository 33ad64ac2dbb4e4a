"""Camera conventions: OpenCV frame, pixel centres at integers, z-depth."""

import math

import numpy as np
import pytest

from snell_bench.scene.camera import Camera


def test_from_fov_principal_point_and_focal():
    cam = Camera.from_fov(1280, 720, 60.0)
    assert cam.K[0, 2] == 639.5 and cam.K[1, 2] == 359.5
    assert cam.K[0, 0] == pytest.approx(640 / math.tan(math.radians(30)))
    assert cam.fov_x_deg == pytest.approx(60.0)


def test_pixel_edges_span_the_field_of_view():
    cam = Camera.from_fov(64, 48, 90.0)
    left = cam.pixel_rays(np.array([[-0.5, 23.5]]))[0]
    right = cam.pixel_rays(np.array([[63.5, 23.5]]))[0]
    assert math.degrees(math.acos(left @ right)) == pytest.approx(90.0)


def test_centre_ray_is_optical_axis_and_frame_is_opencv():
    cam = Camera.from_fov(65, 33, 50.0)  # odd sizes: a pixel centre on the axis
    np.testing.assert_allclose(cam.pixel_rays(np.array([[32.0, 16.0]]))[0], [0, 0, 1])
    d = cam.pixel_rays(np.array([[64.0, 32.0]]))[0]
    assert d[0] > 0 and d[1] > 0  # bottom-right pixel: x right, y down


def test_unproject_project_round_trip():
    cam = Camera(K=np.array([[500.0, 0, 100.2], [0, 480.0, 60.7], [0, 0, 1]]), width=200, height=120)
    depth = np.random.default_rng(0).uniform(0.5, 20, cam.shape)
    pts = cam.unproject(depth)
    np.testing.assert_allclose(pts[..., 2], depth)
    pix, z = cam.project(pts)
    np.testing.assert_allclose(pix, cam.pixel_grid(), atol=1e-9)
    np.testing.assert_allclose(z, depth)


def test_project_behind_camera_is_nan():
    cam = Camera.from_fov(10, 10, 60)
    pix, _ = cam.project(np.array([[0, 0, -1.0], [0, 0, 0.0], [0, 0, 1.0]]))
    assert np.isnan(pix[:2]).all() and np.isfinite(pix[2]).all()


def test_scaled_keeps_pixel_centre_convention():
    cam = Camera.from_fov(1280, 720, 60)
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (640, 360)
    assert half.K[0, 2] == pytest.approx(319.5) and half.fov_x_deg == pytest.approx(60)


def test_non_square_pixels_scale_and_serialise():
    """fx != fy and an off-centre principal point: ``scaled`` keeps each point's pixel position in
    the pixel-centre convention along both axes, and the dict round trip keeps K."""
    cam = Camera(K=np.array([[520.9, 0, 325.1], [0, 521.0, 249.7], [0, 0, 1]]), width=640, height=480)
    pts = cam.unproject(np.random.default_rng(0).uniform(0.5, 5.0, cam.shape))
    small = cam.scaled(0.5)
    assert (small.width, small.height) == (320, 240)
    assert small.K[0, 0] == pytest.approx(260.45) and small.K[1, 1] == pytest.approx(260.5)
    pix, _ = small.project(pts)
    np.testing.assert_allclose(pix, (cam.pixel_grid() + 0.5) * 0.5 - 0.5, atol=1e-9)
    d = small.pixel_rays(pix)
    np.testing.assert_allclose(d, pts / np.linalg.norm(pts, axis=-1, keepdims=True), atol=1e-12)
    # a factor that rounds the sides differently scales fx and fy differently
    odd = Camera(K=cam.K, width=641, height=480).scaled(0.3)
    assert (odd.width, odd.height) == (192, 144)
    assert odd.K[0, 0] == pytest.approx(520.9 * 192 / 641) and odd.K[1, 1] == pytest.approx(521.0 * 0.3)
    back = Camera.from_dict(cam.to_dict())
    assert back == cam and np.array_equal(back.K, cam.K)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(K=np.eye(2), width=4, height=4), "3x3"),
        (dict(K=np.diag([0.0, 1, 1]), width=4, height=4), "focal"),
        (dict(K=np.diag([np.nan, 1, 1]), width=4, height=4), "finite"),
        (dict(K=np.eye(3), width=0, height=4), "width"),
        (dict(K=np.eye(3), width=4, height=2.5), "height"),
    ],
)
def test_bad_cameras(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Camera(**kwargs)


def test_dict_round_trip_and_equality():
    cam = Camera.from_fov(32, 24, 70)
    assert Camera.from_dict(cam.to_dict()) == cam
    assert hash(Camera.from_dict(cam.to_dict())) == hash(cam)
    with pytest.raises(ValueError, match="fov_x_deg"):
        Camera.from_fov(32, 24, 180)
