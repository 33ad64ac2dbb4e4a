"""Tests for snell_bench.scene.procedural: shapes, determinism, exact depth, the support surface,
view-independence of the radiance field and perspective/panorama consistency."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from snell_bench.imaging.equirect import PanoramaCamera
from snell_bench.scene.procedural import SCENE_KINDS, ProceduralScene, srgb_decode, srgb_encode

W, H = 160, 96


@pytest.fixture(scope="module", params=SCENE_KINDS)
def scene_and_render(request):
    sc = ProceduralScene(request.param, seed=3)
    return sc, sc.render(W, H)


def _bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Sample an equirectangular image (H, 2H, C) at pixel coords (..., 2), wrapping in u."""
    h, w = img.shape[:2]
    u, v = uv[..., 0], np.clip(uv[..., 1], 0, h - 1)
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = (u - u0)[..., None], (v - v0)[..., None]
    v1 = np.minimum(v0 + 1, h - 1)
    u0w, u1w = u0 % w, (u0 + 1) % w
    top = img[v0, u0w] * (1 - fu) + img[v0, u1w] * fu
    bot = img[v1, u0w] * (1 - fu) + img[v1, u1w] * fu
    return top * (1 - fv) + bot * fv


def test_srgb_roundtrip():
    x = np.linspace(0, 1, 1001, dtype=np.float32)
    assert np.allclose(srgb_decode(srgb_encode(x)), x, atol=1e-6)
    assert srgb_encode(np.float32(0.0031308)) == pytest.approx(0.04045, abs=1e-5)
    assert srgb_encode(np.float32(0.214041)) == pytest.approx(0.5, abs=1e-4)


def test_shapes_dtypes_ranges(scene_and_render):
    sc, r = scene_and_render
    assert r.image.shape == (H, W, 3) and r.image.dtype == np.float32
    assert r.depth.shape == (H, W) and r.depth.dtype == np.float32
    assert r.image.min() >= 0.0 and r.image.max() <= 1.0
    assert np.all(np.isfinite(r.depth)) and r.depth.min() > 0.0
    assert r.camera == sc.camera(W, H)
    assert r.camera.fov_x_deg == pytest.approx(sc.fov_x_deg)
    # not a blank image: real contrast and colour
    assert r.image.std() > 0.05
    assert np.abs(r.image[..., 0] - r.image[..., 2]).mean() > 0.01


def test_determinism_and_seed_variation():
    for kind in SCENE_KINDS:
        a = ProceduralScene(kind, 7).render(W, H)
        b = ProceduralScene(kind, 7).render(W, H)
        assert np.array_equal(a.image, b.image) and np.array_equal(a.depth, b.depth)
        c = ProceduralScene(kind, 8).render(W, H)
        assert np.abs(a.image - c.image).mean() > 0.04, kind


def test_depth_equals_ray_distance_times_z(scene_and_render):
    sc, r = scene_and_render
    d = r.camera.pixel_rays()  # unit directions
    rad, t = sc.radiance(np.zeros(3), d.reshape(-1, 3))
    assert rad.shape == (H * W, 3) and rad.dtype == np.float32 and t.dtype == np.float32
    expected = t.reshape(H, W).astype(np.float64) * d[..., 2]
    np.testing.assert_allclose(r.depth, expected, rtol=1e-6)
    # the image is the sRGB encoding of the same radiance
    np.testing.assert_allclose(r.image, srgb_encode(rad.reshape(H, W, 3)), atol=1e-6)


def test_depth_matches_independent_mesh_cast(scene_and_render):
    sc, r = scene_and_render
    m = sc.mesh()
    assert len(m.faces) > 1000
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(
        o3d.core.Tensor(np.asarray(m.vertices, np.float32)), o3d.core.Tensor(np.asarray(m.faces, np.uint32))
    )
    d = r.camera.pixel_rays(normalize=False).reshape(-1, 3)  # z = 1: t is the depth
    rays = np.concatenate([np.zeros_like(d), d], 1).astype(np.float32)
    t = rc.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().reshape(H, W)
    np.testing.assert_allclose(r.depth, t, rtol=1e-5)


def test_depth_exact_on_support_plane(scene_and_render):
    """Pixels around the support point see the support plane; their depth is the analytic
    ray-plane intersection."""
    sc, r = scene_and_render
    cam = r.camera
    pix, z = cam.project(sc.support_point[None])
    x0, y0 = np.round(pix[0]).astype(int)
    ys, xs = np.mgrid[y0 - 3 : y0 + 4, x0 - 5 : x0 + 6]
    d = cam.pixel_rays(np.stack([xs, ys], -1).astype(float), normalize=False)  # z = 1
    analytic = (sc.support_point @ sc.up) / (d @ sc.up)
    np.testing.assert_allclose(r.depth[ys, xs], analytic, rtol=2e-6)


def test_support_surface(scene_and_render):
    sc, r = scene_and_render
    assert np.linalg.norm(sc.up) == pytest.approx(1.0, abs=1e-9)
    assert np.allclose(sc.support_normal, sc.up)
    # camera pitched down by 10-22 degrees: up is mostly -y, tilted towards -z (backwards)
    assert sc.up[1] < -0.9 and -0.38 < sc.up[2] < -0.17
    cam = r.camera
    pix, z = cam.project(sc.support_point[None])
    assert z[0] > 0.5
    assert abs(pix[0, 0] - cam.K[0, 2]) < 0.15 * W and H / 2 < pix[0, 1] < H - 2
    pts = cam.unproject(r.depth)
    on = np.abs((pts - sc.support_point) @ sc.up) < 1e-3
    assert on.mean() > 0.08, on.mean()
    cx = int(round(cam.K[0, 2]))
    centre_lower = on[H // 2 :, cx - 3 : cx + 4]
    assert centre_lower.sum() >= 0.15 * centre_lower.size
    # the support point is clear: everything above it within 25 cm is free space
    rad, t = sc.radiance(sc.support_point + 1e-3 * sc.up, sc.up[None])
    assert t[0] > 0.5


def test_radiance_view_independent():
    """The same surface point has the same radiance seen from the camera and from another point."""
    for kind in ("room", "outdoor"):
        sc = ProceduralScene(kind, 11)
        r = sc.render(W, H)
        p = r.camera.unproject(r.depth).reshape(-1, 3)
        rad0, _ = sc.radiance(np.zeros(3), p)
        o2 = np.array([0.25, -0.15, 0.2])
        rad1, t1 = sc.radiance(o2, p - o2)
        vis = np.abs(t1 - np.linalg.norm(p - o2, axis=1)) < 2e-3 * np.maximum(1.0, np.linalg.norm(p - o2, axis=1))
        assert vis.mean() > 0.7
        diff = np.abs(rad0[vis] - rad1[vis]).max(1)
        assert np.median(diff) < 1e-4 and np.mean(diff < 1e-2) > 0.98, kind


def test_radiance_api():
    sc = ProceduralScene("room", 0)
    d = np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    rad, t = sc.radiance(np.zeros(3), d)
    assert rad.shape == (4, 3) and t.shape == (4,)
    assert np.all(np.isfinite(t)) and np.all(t > 0)
    rad2, t2 = sc.radiance(np.zeros((4, 3)), d / np.linalg.norm(d, axis=1, keepdims=True))
    assert np.array_equal(rad, rad2) and np.array_equal(t, t2)
    # a ray from far outside the closed room that points away misses: t = inf, radiance finite
    rad3, t3 = sc.radiance(np.array([[0.0, 0.0, 1e4]]), np.array([[0.0, 0.0, 1.0]]))
    assert np.isinf(t3[0]) and np.all(np.isfinite(rad3))
    # every direction from the camera hits something (closed scenes)
    for kind in ("room", "outdoor"):
        s = ProceduralScene(kind, 2)
        dirs = np.random.default_rng(0).normal(size=(20000, 3))
        _, t = s.radiance(np.zeros(3), dirs)
        assert np.all(np.isfinite(t)) and np.all(t > 0)


def test_supersample():
    sc = ProceduralScene("room", 1)
    a = sc.render(W, H)
    b = sc.render(W, H, supersample=2)
    assert np.array_equal(a.depth, b.depth)
    assert b.image.dtype == np.float32 and b.image.shape == a.image.shape
    assert 0 < np.abs(a.image - b.image).mean() < 0.03
    with pytest.raises(ValueError):
        sc.render(W, H, supersample=0)


@pytest.mark.parametrize("kind", SCENE_KINDS)
def test_panorama_matches_perspective(kind):
    """A panorama centred at the camera, resampled in the perspective pixel directions,
    reproduces the perspective image: both come from the same radiance field."""
    sc = ProceduralScene(kind, 5)
    r = sc.render(W, H, supersample=2)
    ph = 320
    pano = sc.render_panorama((0.0, 0.0, 0.0), height=ph, supersample=2)
    assert pano.shape == (ph, 2 * ph, 3) and pano.dtype == np.float32
    assert pano.min() >= 0 and pano.max() <= 1
    pc = PanoramaCamera.level(np.zeros(3), sc.up, (0.0, 0.0, 1.0), ph)
    uv = pc.project_directions(r.camera.pixel_rays())
    sampled = _bilinear(pano.astype(np.float64), uv)
    mad = np.abs(sampled - r.image).mean()
    assert mad < 0.03, mad
    # and it is not trivially small because the images are flat
    shifted = _bilinear(pano.astype(np.float64), uv + np.array([ph / 8, 0.0]))
    assert np.abs(shifted - r.image).mean() > 2 * mad


def test_panorama_orientation_and_other_centres():
    sc = ProceduralScene("outdoor", 4)
    pano = sc.render_panorama(sc.support_point + 0.3 * sc.up, height=32)
    assert pano.shape == (32, 64, 3)
    # looking up from the outdoor scene sees the (bright, blue-ish) sky; down sees the table/ground
    top, bottom = srgb_decode(pano[:3]).mean((0, 1)), srgb_decode(pano[-3:]).mean((0, 1))
    assert top.sum() > bottom.sum() and top[2] > top[0]


def test_bad_arguments():
    with pytest.raises(ValueError) as e:
        ProceduralScene("castle", 0)
    msg = str(e.value)
    assert "castle" in msg and all(k in msg for k in SCENE_KINDS)
    with pytest.raises(TypeError):
        ProceduralScene("room", 1.5)
    with pytest.raises(TypeError):
        ProceduralScene("room", "1")
    with pytest.raises(ValueError):
        ProceduralScene("room", -1)


@pytest.mark.parametrize("kind", SCENE_KINDS)
def test_a_pickled_scene_is_the_same_scene(kind):
    """A scene is its kind and seed (its textures are closures): pickled as those two, it renders
    the very same image and depth when read back (a sweep's inputs are kept this way)."""
    import pickle

    scene = ProceduralScene(kind, seed=4)
    back = pickle.loads(pickle.dumps(scene))
    a, b = scene.render(width=48, height=32), back.render(width=48, height=32)
    assert back.kind == kind and back.seed == 4
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.depth, b.depth)
