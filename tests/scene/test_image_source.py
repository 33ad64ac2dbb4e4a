"""Loading photos, depth maps and cameras from files (snell_bench.scene.image_source)."""

import dataclasses
import doctest
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageOps

from snell_bench.scene import depth_values, image_source, photo_camera, photo_file, photo_size
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_files import read_pfm
from snell_bench.scene.depth_values import load_depth
from snell_bench.scene.image_source import RGBDFrame, load_frame
from snell_bench.scene.photo_camera import camera_from
from snell_bench.scene.photo_file import load_image
from snell_bench.scene.photo_size import fit_to_block

TUM = Path(__file__).resolve().parents[2] / "snell_bench" / "datasets" / "rgbd" / "tum_fr3_office"
TUM_INTRINSICS = [525.0, 525.0, 319.5, 239.5]


@pytest.mark.parametrize("module", [image_source, photo_file, photo_camera, photo_size, depth_values])
def test_doctests(module):
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0 and result.attempted > 0


# ---------------------------------------------------------------------------------------------- images
def test_load_image_rgb_exact(tmp_path):
    rng = np.random.default_rng(0)
    arr = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    Image.fromarray(arr).save(tmp_path / "a.png")
    img = load_image(tmp_path / "a.png")
    assert img.dtype == np.float32 and img.shape == (5, 7, 3)
    np.testing.assert_array_equal(img, arr.astype(np.float32) / np.float32(255))


def test_load_image_modes(tmp_path):
    grey = np.array([[0, 51, 255]], np.uint8)
    Image.fromarray(grey, mode="L").save(tmp_path / "l.png")
    np.testing.assert_allclose(load_image(tmp_path / "l.png"), np.repeat((grey / 255.0)[..., None], 3, -1), atol=1e-7)

    rgba = np.zeros((2, 2, 4), np.uint8)
    rgba[..., 0], rgba[..., 3] = 255, 0  # fully transparent red: the colour is kept
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "rgba.png")
    np.testing.assert_array_equal(load_image(tmp_path / "rgba.png")[0, 0], [1.0, 0.0, 0.0])

    pal = Image.new("P", (3, 1))
    pal.putpalette([0, 0, 0, 255, 0, 0, 0, 0, 255] + [0] * (256 * 3 - 9))
    pal.putdata([0, 1, 2])
    pal.save(tmp_path / "p.png")
    np.testing.assert_array_equal(load_image(tmp_path / "p.png")[0], [[0, 0, 0], [1, 0, 0], [0, 0, 1]])

    g16 = np.array([[0, 65535, 13107]], np.uint16)
    Image.fromarray(g16).save(tmp_path / "g16.png")
    assert Image.open(tmp_path / "g16.png").mode == "I;16"
    np.testing.assert_allclose(load_image(tmp_path / "g16.png")[0, :, 1], [0.0, 1.0, 0.2], atol=1e-7)


def test_load_image_jpeg_and_exif_orientation(tmp_path):
    arr = np.full((4, 6, 3), 200, np.uint8)
    im = Image.fromarray(arr)
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 degrees clockwise to display"
    im.save(tmp_path / "phone.jpg", exif=exif, quality=95)
    img = load_image(tmp_path / "phone.jpg")
    assert img.shape == (6, 4, 3)  # upright, as a viewer shows it
    np.testing.assert_allclose(img, 200 / 255, atol=2 / 255)
    assert load_image(tmp_path / "phone.jpg", orient=False).shape == (4, 6, 3)


def test_load_image_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"scene\.image='.*nope\.png' does not exist"):
        load_image(tmp_path / "nope.png")
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "x.jpg").write_bytes(b"")
    with pytest.raises(ValueError, match=r"scene\.image=.*is a folder.*x\.jpg"):
        load_image(tmp_path / "photos")
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n this is no image")
    with pytest.raises(ValueError, match=r"scene\.image='.*bad\.png' is not a readable image.*PNG or JPEG"):
        load_image(tmp_path / "bad.png")
    good = tmp_path / "cut.png"
    Image.fromarray(np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)).save(good)
    good.write_bytes(good.read_bytes()[:300])  # truncated
    with pytest.raises(ValueError, match=r"scene\.image"):
        load_image(good)
    with pytest.raises(ValueError, match=r"scene\.image is not set"):
        load_image("")


# ---------------------------------------------------------------------------------------------- depth
def test_depth_png16_exact_and_missing(tmp_path):
    raw = np.array([[0, 1, 5000], [12345, 46655, 65535]])
    Image.fromarray(raw.astype(np.uint16)).save(tmp_path / "d.png")
    assert Image.open(tmp_path / "d.png").mode == "I;16"  # Pillow wrote 16 bits
    d = load_depth(tmp_path / "d.png", scale=5000)
    assert d.dtype == np.float32 and d.shape == (2, 3)
    assert np.isnan(d[0, 0])
    expected = np.array([1 / 5000, 1.0, 12345 / 5000, 46655 / 5000, 65535 / 5000], np.float32)
    np.testing.assert_array_equal(d.ravel()[1:], expected)


def test_depth_millimetres(tmp_path):
    Image.fromarray(np.array([[1500, 0]], np.uint16)).save(tmp_path / "mm.png")
    np.testing.assert_array_equal(load_depth(tmp_path / "mm.png", scale=1000), [[1.5, np.nan]])


def test_depth_tiff_integer_and_float(tmp_path):
    Image.fromarray(np.array([[0, 2500], [5000, 7]], np.uint16)).save(tmp_path / "d16.tif")
    np.testing.assert_array_equal(
        load_depth(tmp_path / "d16.tif", scale=5000), np.array([[np.nan, 0.5], [1.0, 7 / 5000]], np.float32)
    )
    f = np.array([[1.25, np.nan, np.inf], [-2.0, 0.0, 3.5]], np.float32)
    Image.fromarray(f, mode="F").save(tmp_path / "f.tiff")
    d = load_depth(tmp_path / "f.tiff")  # float: metres
    np.testing.assert_array_equal(d, [[1.25, np.nan, np.nan], [np.nan, np.nan, 3.5]])


def test_depth_tiff_without_tifffile_uses_pillow(tmp_path, monkeypatch):
    Image.fromarray(np.array([[0, 2500]], np.uint16)).save(tmp_path / "d.tif")
    monkeypatch.setitem(sys.modules, "tifffile", None)
    np.testing.assert_array_equal(load_depth(tmp_path / "d.tif", scale=5000), [[np.nan, 0.5]])


def test_depth_npy(tmp_path):
    m = np.array([[2.0, 0.0], [np.nan, 4.5]])
    np.save(tmp_path / "m.npy", m)
    d = load_depth(tmp_path / "m.npy")
    assert d.dtype == np.float32
    np.testing.assert_array_equal(d, [[2.0, np.nan], [np.nan, 4.5]])
    np.save(tmp_path / "mm.npy", (m * 1000)[..., None].astype(np.float32))  # (H, W, 1), millimetres
    np.testing.assert_array_equal(load_depth(tmp_path / "mm.npy", scale=1000), d)
    np.save(tmp_path / "int.npy", np.array([[1000, 0]], np.int32))
    np.testing.assert_array_equal(load_depth(tmp_path / "int.npy", scale=1000), [[1.0, np.nan]])


def _pfm_bytes(rows_top_first, kind=b"Pf", little=True):
    h, w = len(rows_top_first), len(rows_top_first[0])
    data = np.asarray(rows_top_first, np.float32)[::-1]  # stored bottom row first
    header = kind + b"\n" + f"{w} {h}\n".encode() + (b"-1.0\n" if little else b"1.0\n")
    return header + data.astype("<f4" if little else ">f4").tobytes()


@pytest.mark.parametrize("little", [True, False])
def test_depth_pfm_by_hand(tmp_path, little):
    rows = [[1.0, 2.0, 0.0], [4.0, -1.0, 6.0]]
    (tmp_path / "d.pfm").write_bytes(_pfm_bytes(rows, little=little))
    np.testing.assert_array_equal(load_depth(tmp_path / "d.pfm"), [[1, 2, np.nan], [4, np.nan, 6]])
    np.testing.assert_array_equal(read_pfm(tmp_path / "d.pfm"), rows)


def test_depth_pfm_three_equal_channels(tmp_path):
    rows = [[[1.0] * 3, [2.0] * 3]]
    (tmp_path / "c.pfm").write_bytes(_pfm_bytes(rows, kind=b"PF"))
    np.testing.assert_array_equal(load_depth(tmp_path / "c.pfm"), [[1.0, 2.0]])
    (tmp_path / "rgb.pfm").write_bytes(_pfm_bytes([[[1.0, 2.0, 3.0], [2.0, 2.0, 2.0]]], kind=b"PF"))
    with pytest.raises(ValueError, match=r"scene\.depth=.*one channel"):
        load_depth(tmp_path / "rgb.pfm")
    (tmp_path / "short.pfm").write_bytes(_pfm_bytes([[1.0, 2.0]])[:-3])
    with pytest.raises(ValueError, match=r"scene\.depth=.*not a readable \.pfm"):
        load_depth(tmp_path / "short.pfm")


def test_range_to_z_fronto_parallel_plane(tmp_path):
    cam = camera_from(40, 30, intrinsics=[30.0, 45.0, 17.0, 12.5])  # fx != fy, off-centre
    u, v = np.meshgrid(np.arange(40.0), np.arange(30.0))
    z = 2.5
    # range = z / cos(angle between the ray and the optical axis)
    tan2 = ((u - 17.0) / 30.0) ** 2 + ((v - 12.5) / 45.0) ** 2
    rng = z / np.cos(np.arctan(np.sqrt(tan2)))
    rng[3, 4] = 0.0
    np.save(tmp_path / "range.npy", rng)
    d = load_depth(tmp_path / "range.npy", kind="range", camera=cam)
    assert np.isnan(d[3, 4])
    d[3, 4] = z
    np.testing.assert_allclose(d, z, rtol=1e-6)
    np.testing.assert_allclose(load_depth(tmp_path / "range.npy", camera=cam)[0, 0], rng[0, 0], rtol=1e-6)
    with pytest.raises(ValueError, match=r"scene\.depth_kind=range needs the camera"):
        load_depth(tmp_path / "range.npy", kind="range")


def test_exr_with_openexr(tmp_path):
    OpenEXR = pytest.importorskip("OpenEXR")
    z = np.array([[1.5, 0.0], [np.inf, 3.0]], np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"Z": z}).write(str(tmp_path / "z.exr"))
    np.testing.assert_array_equal(load_depth(tmp_path / "z.exr"), [[1.5, np.nan], [np.nan, 3.0]])
    rgb = np.stack([z, z, z], -1)
    OpenEXR.File(header, {"RGB": rgb}).write(str(tmp_path / "rgb.exr"))
    np.testing.assert_array_equal(load_depth(tmp_path / "rgb.exr"), [[1.5, np.nan], [np.nan, 3.0]])


def test_exr_without_openexr_says_what_to_install(tmp_path, monkeypatch):
    (tmp_path / "d.exr").write_bytes(b"v/1\x01")
    monkeypatch.setitem(sys.modules, "OpenEXR", None)  # import OpenEXR raises ImportError
    with pytest.raises(ImportError, match=r"scene\.depth=.*pip install OpenEXR"):
        load_depth(tmp_path / "d.exr")


def test_depth_errors(tmp_path):
    Image.fromarray(np.array([[1000, 2000]], np.uint16)).save(tmp_path / "d.png")
    with pytest.raises(FileNotFoundError, match=r"scene\.depth='.*missing\.png' does not exist"):
        load_depth(tmp_path / "missing.png", scale=1000)
    with pytest.raises(ValueError, match=r"scene\.depth=.*is a folder.*d\.png"):
        load_depth(tmp_path, scale=1000)
    (tmp_path / "bad.png").write_bytes(b"garbage")
    with pytest.raises(ValueError, match=r"scene\.depth='.*bad\.png' is not a readable \.png"):
        load_depth(tmp_path / "bad.png", scale=1000)
    (tmp_path / "bad.npy").write_bytes(b"garbage")
    with pytest.raises(ValueError, match=r"scene\.depth='.*bad\.npy' is not a readable"):
        load_depth(tmp_path / "bad.npy")
    (tmp_path / "d.jpg").write_bytes(b"")
    with pytest.raises(ValueError, match=r"scene\.depth=.*'\.jpg', which is not a depth format"):
        load_depth(tmp_path / "d.jpg")
    with pytest.raises(ValueError, match=r"scene\.depth=.*holds integers.*set scene\.depth_scale"):
        load_depth(tmp_path / "d.png")
    for bad in (0, -5000, float("nan"), float("inf"), "five", True):
        with pytest.raises(ValueError, match=r"scene\.depth_scale=.*positive number"):
            load_depth(tmp_path / "d.png", scale=bad)
    with pytest.raises(ValueError, match=r"scene\.depth_kind='distance'.*z\|range"):
        load_depth(tmp_path / "d.png", scale=1000, kind="distance")
    Image.fromarray(np.zeros((2, 3), np.uint16)).save(tmp_path / "zero.png")
    with pytest.raises(ValueError, match=r"scene\.depth=.*no valid depth"):
        load_depth(tmp_path / "zero.png", scale=1000)
    Image.fromarray(np.zeros((2, 3, 3), np.uint8) + np.uint8([0, 80, 200])).save(tmp_path / "colour.png")
    with pytest.raises(ValueError, match=r"scene\.depth=.*one channel"):
        load_depth(tmp_path / "colour.png", scale=1000)
    (tmp_path / "bad.tif").write_bytes(b"II*\x00 no image")
    with pytest.raises(ValueError, match=r"scene\.depth='.*bad\.tif'"):
        load_depth(tmp_path / "bad.tif")
    np.save(tmp_path / "empty.npy", np.zeros((0, 4)))
    with pytest.raises(ValueError, match=r"scene\.depth=.*holds no pixels"):
        load_depth(tmp_path / "empty.npy")
    np.save(tmp_path / "bool.npy", np.ones((2, 2), bool))
    with pytest.raises(ValueError, match=r"scene\.depth=.*not numbers"):
        load_depth(tmp_path / "bool.npy")
    Image.new("P", (3, 2)).save(tmp_path / "palette.png")
    with pytest.raises(ValueError, match=r"scene\.depth=.*palette"):
        load_depth(tmp_path / "palette.png", scale=1000)


def test_depth_size_must_match_the_image(tmp_path):
    Image.fromarray(np.full((240, 320), 5000, np.uint16)).save(tmp_path / "small.png")
    cam = camera_from(640, 480, fov_deg=60.0)
    with pytest.raises(ValueError, match=r"scene\.depth=.*\(240, 320\).*scene\.image is \(480, 640\)"):
        load_depth(tmp_path / "small.png", scale=5000, camera=cam)


# ---------------------------------------------------------------------------------------------- camera
def test_camera_from_intrinsics_and_fov():
    cam = camera_from(640, 480, intrinsics=[520.9, 521.0, 325.1, 249.7])
    np.testing.assert_array_equal(cam.K, [[520.9, 0, 325.1], [0, 521.0, 249.7], [0, 0, 1]])
    assert cam.shape == (480, 640)
    cam = camera_from(640, 480, intrinsics=np.array([500, 500, 319.5, 239.5]))
    assert cam.K[0, 0] == 500.0
    cam = camera_from(200, 100, fov_deg=90.0)  # tan(45 deg) = 1: f = W / 2
    np.testing.assert_allclose(cam.K, [[100, 0, 99.5], [0, 100, 49.5], [0, 0, 1]], atol=1e-12)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({}, r"exactly one of scene\.intrinsics.*scene\.fov_deg.*neither"),
        ({"intrinsics": [500, 500, 320, 240], "fov_deg": 60}, r"exactly one of scene\.intrinsics.*both"),
        ({"intrinsics": [500, 500, 320]}, r"scene\.intrinsics=.*3 values, not 4"),
        ({"intrinsics": [[500, 0, 320], [0, 500, 240], [0, 0, 1]]}, r"scene\.intrinsics=.*3 values, not 4.*K00"),
        ({"intrinsics": "500 500 320 240"}, r"scene\.intrinsics=.*not a list of four numbers"),
        ({"intrinsics": [500, "a", 320, 240]}, r"scene\.intrinsics=.*not numbers"),
        ({"intrinsics": [0, 500, 320, 240]}, r"scene\.intrinsics: the focal lengths.*> 0"),
        ({"intrinsics": [500, -1, 320, 240]}, r"scene\.intrinsics: the focal lengths"),
        ({"intrinsics": [500, 500, float("nan"), 240]}, r"scene\.intrinsics=.*finite"),
        ({"intrinsics": [500, 500, 960, 540]}, r"scene\.intrinsics: the principal point.*outside.*calibrated"),
        ({"intrinsics": [500, 500, 320, -1]}, r"scene\.intrinsics: the principal point"),
        ({"fov_deg": 0}, r"scene\.fov_deg=0 must be"),
        ({"fov_deg": 180}, r"scene\.fov_deg=180 must be"),
        ({"fov_deg": float("nan")}, r"scene\.fov_deg=nan must be"),
        ({"fov_deg": "wide"}, r"scene\.fov_deg='wide' must be"),
    ],
)
def test_camera_from_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        camera_from(640, 480, **kwargs)


# ---------------------------------------------------------------------------------------------- fit_to_block
def _bilinear(img, x, y):
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    ax, ay = (x - x0)[:, None], (y - y0)[:, None]
    return (
        img[y0, x0] * (1 - ax) * (1 - ay)
        + img[y0, x0 + 1] * ax * (1 - ay)
        + img[y0 + 1, x0] * (1 - ax) * ay
        + img[y0 + 1, x0 + 1] * ax * ay
    )


def _ramp(h, w):
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.stack([0.1 + 0.8 * u / w, 0.1 + 0.8 * v / h, 0.5 + 0.3 * (u / w - v / h)], -1).astype(np.float32)


def test_crop_keeps_projections_exact():
    rng = np.random.default_rng(1)
    H, W = 53, 75
    image = rng.random((H, W, 3), dtype=np.float32)
    depth = (1.0 + rng.random((H, W))).astype(np.float32)
    depth[5, 9] = np.nan
    cam = camera_from(W, H, intrinsics=[60.0, 61.0, 36.2, 27.9])
    img2, dep2, cam2 = fit_to_block(image, depth, cam, 16)
    assert img2.shape == (48, 64, 3) and dep2.shape == (48, 64) and cam2.shape == (48, 64)
    # 11 extra columns: 5 cut on the left; 5 extra rows: 2 cut at the top
    np.testing.assert_allclose(cam2.K[:2, 2], [36.2 - 5, 27.9 - 2])
    assert cam2.K[0, 0] == 60.0 and cam2.K[1, 1] == 61.0
    # 3-D points seen at the pixel centres of the old image land on the same content in the new one
    vs, us = np.mgrid[2:50, 5:69]
    pts = cam.unproject(np.nan_to_num(depth, nan=1.0))[vs, us].reshape(-1, 3)
    pix, _ = cam2.project(pts)
    x, y = np.rint(pix[:, 0]).astype(int), np.rint(pix[:, 1]).astype(int)
    np.testing.assert_allclose(pix, np.stack([x, y], -1), atol=1e-9)
    np.testing.assert_array_equal(img2[y, x], image[vs.ravel(), us.ravel()])
    np.testing.assert_array_equal(dep2[y, x], depth[vs.ravel(), us.ravel()])
    assert np.isnan(dep2[3, 4])


def test_crop_noop_and_errors():
    cam = camera_from(32, 16, fov_deg=50.0)
    img = np.zeros((16, 32, 3), np.float32)
    out = fit_to_block(img, None, cam, 16)
    assert out[0] is img and out[1] is None and out[2] is cam
    with pytest.raises(ValueError, match="block must be a positive integer"):
        fit_to_block(img, None, cam, 0)
    with pytest.raises(ValueError, match="mode must be 'crop' or 'resize'"):
        fit_to_block(img, None, cam, 8, mode="pad")
    with pytest.raises(ValueError, match=r"scene\.image is 32x16, smaller than one 32x32 block"):
        fit_to_block(img, None, cam, 32)
    with pytest.raises(ValueError, match="multiples of block=16"):
        fit_to_block(img, None, cam, 16, mode="resize", size=(40, 16))
    with pytest.raises(ValueError, match="depth has shape"):
        fit_to_block(img, np.zeros((16, 31)), cam, 8)


@pytest.mark.parametrize("src, dst", [((96, 72), (48, 32)), ((75, 53), (80, 56)), ((64, 48), (128, 96))])
def test_resize_keeps_projections(src, dst):
    (W, H), (w, h) = src, dst
    image = _ramp(H, W)
    depth = np.linspace(1.0, 3.0, H * W, dtype=np.float32).reshape(H, W)
    depth[10:14, 20:26] = np.nan
    cam = camera_from(W, H, intrinsics=[70.0, 72.0, 0.45 * W, 0.52 * H])
    img2, dep2, cam2 = fit_to_block(image, depth, cam, 8, mode="resize", size=(w, h))
    assert img2.shape == (h, w, 3) and img2.dtype == np.float32 and cam2.shape == (h, w)
    # points in the interior (away from the borders, where the filter sees past the image edge)
    rng = np.random.default_rng(2)
    xy = rng.uniform([0.2 * W, 0.2 * H], [0.8 * W, 0.8 * H], (200, 2))
    pts = cam.pixel_rays(xy, normalize=False) * rng.uniform(1.0, 4.0, (200, 1))
    new, _ = cam2.project(pts)
    # the ramp spans ~0.8 over the width: a half-pixel error in K would show as >= 4e-3
    np.testing.assert_allclose(_bilinear(img2, new[:, 0], new[:, 1]), _bilinear(image, xy[:, 0], xy[:, 1]), atol=1.5e-3)
    # the analytic mapping between pixel coordinates: (x + 0.5) * w / W - 0.5
    np.testing.assert_allclose(new, (xy + 0.5) * [w / W, h / H] - 0.5, atol=1e-9)
    # depth by nearest neighbour: values copied from the input, holes stay holes, never blended
    xs = np.floor((np.arange(w) + 0.5) * W / w).astype(int)
    ys = np.floor((np.arange(h) + 0.5) * H / h).astype(int)
    np.testing.assert_array_equal(dep2, depth[ys[:, None], xs[None, :]])
    assert np.isnan(dep2).any() and np.isin(dep2[np.isfinite(dep2)], depth).all()


def test_resize_default_size_rounds_to_the_block():
    cam = camera_from(70, 37, fov_deg=60.0)
    img2, dep2, cam2 = fit_to_block(np.zeros((37, 70, 3), np.float32), None, cam, 16, mode="resize")
    assert cam2.shape == (32, 64) and dep2 is None
    assert cam2.K[0, 0] == pytest.approx(cam.K[0, 0] * 64 / 70) and cam2.K[1, 1] == pytest.approx(cam.K[1, 1] * 32 / 37)


# ---------------------------------------------------------------------------------------------- frames
def _write_frame(tmp_path, w, h):
    rng = np.random.default_rng(3)
    Image.fromarray(rng.integers(0, 256, (h, w, 3), dtype=np.uint8)).save(tmp_path / "rgb.png")
    raw = rng.integers(0, 20000, (h, w)).astype(np.uint16)
    raw[0, :5] = 0
    Image.fromarray(raw).save(tmp_path / "depth.png")
    return raw


def test_load_frame_crops_to_the_block(tmp_path):
    raw = _write_frame(tmp_path, 650, 490)
    f = load_frame(
        tmp_path / "rgb.png", tmp_path / "depth.png", depth_scale=5000, intrinsics=[500.0, 501.0, 324.5, 244.5]
    )
    assert isinstance(f, RGBDFrame) and f.image.shape == (480, 640, 3) and f.depth.shape == (480, 640)
    np.testing.assert_allclose(f.camera.K[:2, 2], [319.5, 239.5])  # 5 pixels cut on each side
    np.testing.assert_array_equal(f.depth, np.where(raw > 0, raw / 5000, np.nan).astype(np.float32)[5:485, 5:645])
    with pytest.raises(dataclasses.FrozenInstanceError):
        f.depth = None
    f = load_frame(tmp_path / "rgb.png", fov_deg=60.0, block=8)
    assert f.depth is None and f.camera.shape == (488, 648)
    f = load_frame(tmp_path / "rgb.png", tmp_path / "depth.png", depth_scale=5000, fov_deg=60.0, block=None)
    assert f.camera.shape == (490, 650)
    f = load_frame(tmp_path / "rgb.png", fov_deg=60.0, size=(320, 240))
    assert f.image.shape == (240, 320, 3)
    with pytest.raises(ValueError, match=r"image has shape"):
        RGBDFrame(image=np.zeros((4, 4, 3)), depth=None, camera=Camera.from_fov(5, 4, 60.0))


def test_load_frame_rejects_a_depth_of_another_size(tmp_path):
    _write_frame(tmp_path, 64, 48)
    Image.fromarray(np.full((24, 32), 1000, np.uint16)).save(tmp_path / "half.png")
    with pytest.raises(ValueError, match=r"scene\.depth=.*\(24, 32\).*scene\.image is \(48, 64\)"):
        load_frame(tmp_path / "rgb.png", tmp_path / "half.png", depth_scale=1000, fov_deg=60.0)


# ---------------------------------------------------------------------------------------------- the TUM frame
@pytest.fixture(scope="module")
def tum():
    return load_frame(TUM / "color.png", TUM / "depth.png", depth_scale=5000, intrinsics=TUM_INTRINSICS)


def test_tum_frame_loads(tum):
    assert tum.image.shape == (480, 640, 3) and tum.depth.shape == (480, 640)
    assert tum.camera == camera_from(640, 480, intrinsics=TUM_INTRINSICS)  # 640 x 480: no crop at block 16
    valid = np.isfinite(tum.depth)
    assert 1 - valid.mean() == pytest.approx(0.19, abs=0.01)
    assert float(np.median(tum.depth[valid])) == pytest.approx(2.42, abs=0.01)
    assert float(np.nanmin(tum.depth)) == pytest.approx(1.46, abs=0.005)
    assert float(np.nanmax(tum.depth)) == pytest.approx(9.33, abs=0.005)
    assert 0.2 < tum.image.mean() < 0.8


def test_tum_frame_has_a_desk_top_above_the_floor(tum):
    from snell_bench.scene.placement import find_support_plane

    up = np.array([0.0, -1.0, 0.0])
    # the defaults: a horizontal plane is found (the camera looks ~30 deg down, at the tilt limit)
    plane = find_support_plane(tum.depth, tum.camera, up_hint=up)
    assert plane.normal @ up >= math.cos(math.radians(30.0)) and plane.inliers > 1000
    assert -1.8 < plane.point @ plane.normal < -1.0  # the desk top (~1.1 m below the camera) or the floor
    # with room for the pitch: the highest plane is the desk top, the largest the floor, ~0.7 m lower
    kw = dict(up_hint=up, max_tilt_deg=45.0, max_points=20_000)
    desk = find_support_plane(tum.depth, tum.camera, **kw)
    floor = find_support_plane(tum.depth, tum.camera, prefer="largest", **kw)
    assert desk.normal @ floor.normal > math.cos(math.radians(5.0))
    assert (desk.point - floor.point) @ floor.normal == pytest.approx(0.70, abs=0.08)
    assert desk.pixel[1] < floor.pixel[1]  # the desk is seen above the floor in the image


# ---------------------------------------------------------------------------------------------- depth vs. scale
def test_an_8bit_depth_file_is_refused_at_any_scale(tmp_path):
    """256 levels are a picture of depth: refused with or without a scale, naming the fix."""
    Image.fromarray(np.array([[10, 255]], np.uint8)).save(tmp_path / "d8.png")
    assert Image.open(tmp_path / "d8.png").mode == "L"
    for scale in (10, 1000, None):
        with pytest.raises(
            ValueError, match=r"scene\.depth=.*d8\.png' is an 8-bit file.*16-bit PNG.*scene\.depth_scale"
        ):
            load_depth(tmp_path / "d8.png", scale=scale)
    np.save(tmp_path / "d8.npy", np.array([[10, 255]], np.uint8))
    with pytest.raises(
        ValueError, match=r"8-bit file: its 256 levels \(at scene\.depth_scale=10: steps of 0\.1 m up to 25\.5 m\)"
    ):
        load_depth(tmp_path / "d8.npy", scale=10)


def test_an_integer_file_with_a_scale_below_one_names_its_inverse(tmp_path):
    Image.fromarray(np.full((4, 4), 2500, np.uint16)).save(tmp_path / "mm.png")
    with pytest.raises(
        ValueError, match=r"scene\.depth_scale=0\.001 is below 1.*not metres per unit; set scene\.depth_scale=1000$"
    ):
        load_depth(tmp_path / "mm.png", scale=0.001)


@pytest.mark.parametrize(
    "values, dtype, scale, fix",
    [
        # float metres given the TUM frame's scale: all nearer than 5 cm
        ([0.5, 2.0, 9.0], np.float32, 5000, r"set scene\.depth_scale=null \(metres: median 2 m\)"),
        # float millimetres read as metres: a median of 2 km
        ([800.0, 2000.0, 4000.0], np.float32, None, r"set scene\.depth_scale=1000 \(millimetres: median 2 m\)"),
        # 16-bit millimetres at scale 1
        ([800, 2000, 4000], np.uint16, 1, r"set scene\.depth_scale=1000 \(millimetres: median 2 m\)"),
        # 16-bit millimetres with the scale of metres to millimetres inverted twice
        ([800, 2000, 4000], np.uint16, 1e6, r"set scene\.depth_scale=1000 \(millimetres: median 2 m\)"),
    ],
)
def test_a_depth_implausible_in_metres_names_the_scale_that_fits(tmp_path, values, dtype, scale, fix):
    np.save(tmp_path / "d.npy", np.array([values], dtype))
    with pytest.raises(ValueError, match=r"scene\.depth=.*implausible as depth in metres.*" + fix):
        load_depth(tmp_path / "d.npy", scale=scale)


def test_the_plausible_range_boundaries(tmp_path):
    """Farthest value exactly 5 cm and a median of exactly 1 km pass; just beyond either fails."""
    ok_near = np.array([[0.01, 0.05]], np.float64)
    ok_far = np.array([[1.0, 1000.0, 5000.0]], np.float64)
    for name, a in (("near", ok_near), ("far", ok_far)):
        np.save(tmp_path / f"{name}.npy", a)
        np.testing.assert_allclose(load_depth(tmp_path / f"{name}.npy"), a.astype(np.float32))
    np.save(tmp_path / "nearer.npy", ok_near * 0.99)
    with pytest.raises(ValueError, match=r"all of it is nearer than 0\.05 m \(the farthest valid value is 0\.0495 m\)"):
        load_depth(tmp_path / "nearer.npy")
    np.save(tmp_path / "farther.npy", ok_far * 1.01)
    with pytest.raises(ValueError, match=r"its median is 1010 m, farther than 1000 m"):
        load_depth(tmp_path / "farther.npy")


def test_a_float_file_in_millimetres_with_its_scale_is_accepted(tmp_path):
    np.save(tmp_path / "mm.npy", np.array([[800.0, 2000.0]], np.float32))
    np.testing.assert_allclose(load_depth(tmp_path / "mm.npy", scale=1000), [[0.8, 2.0]], rtol=1e-6)


# ---------------------------------------------------------------------------------------------- EXIF orientation
def _exif_photo(path, w, h, orientation, marks=()):
    """A stored ``w x h`` JPEG (PNG for exact pixels) with EXIF ``orientation``; ``marks``: stored
    pixels set to distinct values (in a grey channel copied to RGB)."""
    arr = np.zeros((h, w), np.uint8)
    for i, (x, y) in enumerate(marks):
        arr[y, x] = 10 * (i + 1)
    exif = Image.Exif()
    exif[image_source.EXIF_ORIENTATION] = orientation
    Image.fromarray(arr).convert("RGB").save(path, exif=exif)
    return arr


@pytest.mark.parametrize("orientation", range(1, 9))
def test_intrinsics_turn_with_the_exif_orientation(tmp_path, orientation):
    """Independent reference: Pillow's exif_transpose moves marked pixels; the upright camera
    (orient_intrinsics) sees each moved pixel along a ray at the same angles to the others as the
    stored camera sees the stored pixel (a camera turn or mirror keeps angles), and the principal
    point moves as a pixel does."""
    w, h = 9, 6
    K = [7.0, 11.0, 3.0, 2.0]  # fx != fy and an off-centre principal point: a swap would show
    marks = [(3, 2), (0, 0), (8, 1), (5, 5), (1, 4)]  # the first is the principal point
    _exif_photo(tmp_path / "p.png", w, h, orientation, marks)
    upright = (np.asarray(ImageOps.exif_transpose(Image.open(tmp_path / "p.png")))[..., 0]).astype(int)
    moved = [tuple(np.argwhere(upright == 10 * (i + 1))[0][::-1]) for i in range(len(marks))]
    k2 = image_source.orient_intrinsics(K, w, h, orientation)
    assert (k2[2], k2[3]) == moved[0]
    header = image_source.read_photo_header(tmp_path / "p.png")
    assert header.orientation == orientation and header.upright_size == upright.shape[::-1]
    cam = camera_from(w, h, intrinsics=K)
    cam2 = image_source.photo_camera(header, intrinsics=K)
    np.testing.assert_allclose([cam2.K[0, 0], cam2.K[1, 1], cam2.K[0, 2], cam2.K[1, 2]], k2)
    rays = cam.pixel_rays(np.array(marks, float))
    rays2 = cam2.pixel_rays(np.array(moved, float))
    np.testing.assert_allclose(rays2 @ rays2.T, rays @ rays.T, atol=1e-12)
    if orientation in (5, 6, 7, 8):
        assert (k2[0], k2[1]) == (11.0, 7.0)


def test_exif_needs_no_upright_intrinsics_error_for_a_portrait_photo(tmp_path):
    """Intrinsics of a landscape file stored sideways are valid for it (they would be outside the
    upright photo): checked against the file as stored, and the error says so when they are not."""
    _exif_photo(tmp_path / "p.jpg", 40, 20, 6)
    header = image_source.read_photo_header(tmp_path / "p.jpg")
    cam = image_source.photo_camera(header, intrinsics=[30.0, 30.0, 35.0, 9.5])  # cx = 35 < 40 only as stored
    assert cam.shape == (40, 20) and cam.K[0, 2] == pytest.approx(20 - 1 - 9.5) and cam.K[1, 2] == 35.0
    with pytest.raises(
        ValueError, match=r"principal point.*as stored, 40x20; the photo was rotated by 90 degrees clockwise"
    ):
        image_source.photo_camera(header, intrinsics=[30.0, 30.0, 45.0, 9.5])
    cam = image_source.photo_camera(header, fov_deg=90.0)  # the upright photo's horizontal field of view
    assert cam.K[0, 0] == pytest.approx(10.0) and cam.shape == (40, 20)


def test_a_depth_of_the_stored_shape_names_the_exif_rotation(tmp_path, caplog):
    _exif_photo(tmp_path / "phone.jpg", 48, 32, 6)
    Image.fromarray(np.full((32, 48), 2000, np.uint16)).save(tmp_path / "d.png")
    with pytest.raises(ValueError) as e:
        load_frame(tmp_path / "phone.jpg", tmp_path / "d.png", depth_scale=1000, fov_deg=60.0, block=8)
    msg = str(e.value)
    assert "\n" not in msg
    assert "scene.depth=" in msg and "has shape (32, 48)" in msg and "scene.image is (48, 32)" in msg
    assert "rotated by 90 degrees clockwise by its EXIF orientation tag 6 from 48x32 (as stored) to 32x48" in msg
    assert "the depth has the stored shape" in msg and "rotate the depth the same way (to 32x48)" in msg
    assert "re-save the photo without its EXIF orientation tag" in msg
    # the upright depth loads, with a warning that the photo was turned
    Image.fromarray(np.full((48, 32), 2000, np.uint16)).save(tmp_path / "up.png")
    with caplog.at_level("WARNING"):
        f = load_frame(tmp_path / "phone.jpg", tmp_path / "up.png", depth_scale=1000, fov_deg=60.0, block=8)
    assert f.image.shape == (48, 32, 3) and f.depth.shape == (48, 32) and f.info["exif_orientation"] == 6
    assert "EXIF orientation tag 6" in caplog.text and "upright orientation" in caplog.text


def test_load_frame_turns_the_intrinsics_of_the_stored_file(tmp_path):
    _exif_photo(tmp_path / "p.png", 64, 48, 8)
    Image.fromarray(np.full((64, 48), 2000, np.uint16)).save(tmp_path / "d.png")
    f = load_frame(tmp_path / "p.png", tmp_path / "d.png", depth_scale=1000, intrinsics=[50.0, 52.0, 30.0, 20.0])
    assert f.camera.shape == (64, 48)
    np.testing.assert_allclose(f.camera.K[[0, 1, 0, 1], [0, 1, 2, 2]], [52.0, 50.0, 20.0, 64 - 1 - 30.0])


# ---------------------------------------------------------------------------------------------- max_side
def test_max_side_size():
    assert image_source.max_side_size(4000, 3000, 1024) == (1024, 768)
    assert image_source.max_side_size(3000, 4000, 1000) == (750, 1000)
    assert image_source.max_side_size(1001, 333, 500) == (500, 166)  # 166.33 rounds down
    assert image_source.max_side_size(640, 480, 640) == (640, 480)
    assert image_source.max_side_size(640, 480, None) == (640, 480)
    for bad in (0, -5, 1.5, True, "512"):
        with pytest.raises(ValueError, match=r"scene\.max_side=.*positive whole number"):
            image_source.max_side_size(640, 480, bad)
    with pytest.raises(
        ValueError, match=r"scene\.max_side=32 makes the 4000x1000 photo 32x8.*model\.multiple=16.*at least 64"
    ):
        image_source.max_side_size(4000, 1000, 32, block=16)


def test_load_frame_resizes_for_max_side_then_fits_the_block(tmp_path):
    """The resize is fit_to_block's (Lanczos, depth by nearest neighbour, K scaled per axis):
    compared with it, and with the analytic scaling of K; then the centre crop to the block."""
    raw = _write_frame(tmp_path, 300, 200)
    k = [280.0, 281.0, 150.2, 99.7]
    f = load_frame(tmp_path / "rgb.png", tmp_path / "depth.png", depth_scale=5000, intrinsics=k, max_side=100, block=16)
    # 300x200 -> 100x67 (66.67 rounds up) -> cropped to 96x64: 2 columns cut on the left, 1 row at the top
    assert f.info == {
        "original_size": [300, 200],
        "exif_orientation": 1,
        "max_side": 100,
        "resized_to": [100, 67],
        "size": [96, 64],
    }
    assert f.image.shape == (64, 96, 3)
    s = (100 / 300, 67 / 200)
    np.testing.assert_allclose(
        f.camera.K[[0, 1, 0, 1], [0, 1, 2, 2]],
        [280 * s[0], 281 * s[1], (150.2 + 0.5) * s[0] - 0.5 - 2, (99.7 + 0.5) * s[1] - 0.5 - 1],
    )
    full = load_frame(tmp_path / "rgb.png", tmp_path / "depth.png", depth_scale=5000, intrinsics=k, block=None)
    img, dep, _ = fit_to_block(full.image, full.depth, full.camera, 1, mode="resize", size=(100, 67))
    np.testing.assert_array_equal(f.image, img[1:65, 2:98])
    np.testing.assert_array_equal(f.depth, dep[1:65, 2:98])
    xs = np.floor((np.arange(100) + 0.5) * 3.0).astype(int)
    ys = np.minimum(np.floor((np.arange(67) + 0.5) * 200 / 67).astype(int), 199)
    expected = np.where(raw > 0, raw / 5000, np.nan).astype(np.float32)[ys[:, None], xs[None, :]]
    np.testing.assert_array_equal(f.depth, expected[1:65, 2:98])
    # within max_side: untouched, and recorded as such
    g = load_frame(tmp_path / "rgb.png", tmp_path / "depth.png", depth_scale=5000, intrinsics=k, max_side=300)
    assert g.info["resized_to"] is None and g.info["size"] == [288, 192] and g.camera.K[0, 0] == 280.0


def test_load_photo_without_depth_resizes_image_and_camera(tmp_path):
    _write_frame(tmp_path, 300, 200)
    img, cam, header = image_source.load_photo(
        tmp_path / "rgb.png", intrinsics=[280.0, 281.0, 150.2, 99.7], max_side=150
    )
    assert img.shape == (100, 150, 3) and cam.shape == (100, 150) and header == image_source.PhotoHeader(300, 200)
    assert cam.K[0, 0] == pytest.approx(140.0)
    img, cam, _ = image_source.load_photo(tmp_path / "rgb.png", max_side=150)
    assert img.shape == (100, 150, 3) and cam is None


# ---------------------------------------------------------------------------------------------- before any work
def test_inspect_photo_agrees_with_load_frame_without_decoding(tmp_path, monkeypatch):
    _write_frame(tmp_path, 300, 200)
    kw = dict(depth_scale=5000, intrinsics=[280.0, 281.0, 150.2, 99.7], max_side=100, block=16)
    info = image_source.inspect_photo(tmp_path / "rgb.png", tmp_path / "depth.png", **kw)
    frame = load_frame(tmp_path / "rgb.png", tmp_path / "depth.png", **kw)
    assert {k: v for k, v in info.items() if k != "fx"} == frame.info
    assert info["fx"] == pytest.approx(frame.camera.K[0, 0])
    monkeypatch.setattr(image_source, "load_image", lambda *a, **k: pytest.fail("decoded the photo"))
    image_source.inspect_photo(tmp_path / "rgb.png", tmp_path / "depth.png", **kw)


def test_inspect_photo_refuses_what_load_frame_refuses(tmp_path):
    _write_frame(tmp_path, 64, 48)
    Image.fromarray(np.full((48, 64), 40, np.uint8)).save(tmp_path / "d8.png")
    with pytest.raises(ValueError, match="8-bit"):
        image_source.inspect_photo(tmp_path / "rgb.png", tmp_path / "d8.png", depth_scale=1000, fov_deg=60.0)
    Image.fromarray(np.full((24, 32), 1000, np.uint16)).save(tmp_path / "half.png")
    with pytest.raises(ValueError, match=r"scene\.depth=.*\(24, 32\).*scene\.image is \(48, 64\)"):
        image_source.inspect_photo(tmp_path / "rgb.png", tmp_path / "half.png", depth_scale=1000, fov_deg=60.0)
    (tmp_path / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n not a png any more")
    # a file that cannot be read is left to load_frame (its cell records why)
    info = image_source.inspect_photo(tmp_path / "rgb.png", tmp_path / "broken.png", depth_scale=1000, fov_deg=60.0)
    assert info["size"] == [64, 48]


# ---------------------------------------------------------------------------------------------- the cell's record
def test_a_photo_resized_for_max_side_is_recorded_with_the_cells_inputs(tmp_path):
    """scene.max_side through the pipeline's scene stage: half the TUM frame, K halved (pixel
    centres kept), and what was done recorded in the inputs' info (a cell's scene_info) and in
    camera.json."""
    from types import SimpleNamespace

    from snell_bench import pipeline
    from snell_bench.config import compose
    from snell_bench.experiment.files import save_scene_files
    from snell_bench.scene.objects import GlassObject

    sc = pipeline.load_scene(compose(["scene=tum_office", "scene.max_side=320", "output_dir=/tmp/x"]))
    assert sc.image.shape == (240, 320, 3) and sc.depth.shape == (240, 320)
    np.testing.assert_allclose(sc.camera.K[[0, 1, 0, 1], [0, 1, 2, 2]], [262.5, 262.5, 159.5, 119.5])
    info = {"original_size": [640, 480], "exif_orientation": 1, "max_side": 320, "resized_to": [320, 240]}
    assert sc.info == {**info, "size": [320, 240]}
    save_scene_files(SimpleNamespace(obj=GlassObject.sphere(), scene=sc), tmp_path)
    cam = json.loads((tmp_path / "camera.json").read_text())
    assert cam["photo"] == sc.info and (cam["width"], cam["height"]) == (320, 240)
    assert Camera.from_dict(cam) == sc.camera
