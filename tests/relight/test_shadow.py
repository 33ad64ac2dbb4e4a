"""The traced-shadow relighter: light conventions, the shadow against its closed form on a floor,
and the stand-in on real prepared inputs."""

import json
import math

import numpy as np
import pytest
import torch
from conftest import sphere_at

from snell_bench.optics.warps import compute_warps
from snell_bench.relight import Relighter, candidate_seeds, masked_psnr, relight
from snell_bench.relight.shadow import (
    Occluder,
    ShadowRelighter,
    apply_shadow,
    cone_directions,
    horizontal_frame,
    jitter_direction,
    light_direction,
    occluded_fraction,
    scene_up,
    shadow_fraction_map,
)
from snell_bench.scene.camera import Camera
from snell_bench.scene.sources import SceneInputs

H, W = 96, 160
PITCH = math.radians(35.0)
UP = np.array([0.0, -math.cos(PITCH), -math.sin(PITCH)])  # a camera pitched 35 degrees down
CAMERA_HEIGHT = 1.5
RADIUS = 0.4


def angle_deg(a, b):
    return math.degrees(math.acos(np.clip(np.dot(a, b), -1.0, 1.0)))


def floor_depth(camera):
    """z-depth of the floor ``X . UP = -CAMERA_HEIGHT`` (NaN above the horizon)."""
    d = camera.pixel_rays(normalize=False)  # z = 1
    s = d @ UP
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(s < -1e-6, -CAMERA_HEIGHT / s, np.nan).astype(np.float32)


@pytest.fixture(scope="module")
def floor():
    """A floor, a glass sphere standing on it on the optical axis, and the warps."""
    camera = Camera.from_fov(W, H, 60.0)
    depth = floor_depth(camera)
    ground = np.array([0.0, 0.0, CAMERA_HEIGHT / math.sin(PITCH)])  # the floor on the optical axis
    center = ground + RADIUS * UP
    obj = sphere_at(center, RADIUS, subdivisions=4)
    obj = type(obj)(mesh=obj.mesh, ior=obj.ior, name="sphere", placed=True, up=UP)
    scene = SceneInputs(image=np.full((H, W, 3), 0.6, np.float32), depth=depth, camera=camera, up=UP, source=None)
    warps = compute_warps(depth, camera, obj, pano_height=16)
    return scene, obj, warps, center


def closed_form_shadow(scene, center, light):
    """Floor pixels whose ray towards the light passes within RADIUS of the sphere's centre."""
    pts = scene.camera.unproject(np.nan_to_num(scene.depth))
    q = center - pts
    along = q @ light
    perp2 = (q * q).sum(-1) - along**2
    return np.isfinite(scene.depth) & (along > 0) & (perp2 <= RADIUS**2)


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


class TestLight:
    def test_frame_and_angles(self):
        up = np.array([0.0, -1.0, 0.0])
        f, r = horizontal_frame(up)
        assert np.allclose(f, [0, 0, 1]) and np.allclose(r, [1, 0, 0])
        assert np.allclose(light_direction(90, 123, up), up)
        assert np.allclose(light_direction(0, 0, up), [0, 0, -1])  # from behind the camera
        assert np.allclose(light_direction(0, 90, up), [1, 0, 0])  # from the camera's right
        assert np.allclose(light_direction(0, 180, up), [0, 0, 1])  # against the camera
        d = light_direction(60, 30, UP)
        assert angle_deg(d, UP) == pytest.approx(30.0)
        f, r = horizontal_frame(UP)
        assert np.allclose(f, [0, -math.sin(PITCH), math.cos(PITCH)]) and np.allclose(r, [1, 0, 0])

    def test_camera_looking_down(self):
        f, r = horizontal_frame([0.0, 0.0, -1.0])
        assert np.allclose(f, [0, -1, 0]) and np.allclose(r, [1, 0, 0])

    def test_scene_up(self, floor):
        scene, obj, _, _ = floor
        assert np.allclose(scene_up(obj, scene), UP)
        assert np.allclose(scene_up(None, scene), UP)
        assert np.allclose(scene_up(), [0, -1, 0])

    def test_jitter(self):
        d = light_direction(60, 30, UP)
        js = [jitter_direction(d, 15, s, up=UP) for s in range(50)]
        assert all(angle_deg(j, d) <= 15 + 1e-9 for j in js)
        assert max(angle_deg(j, d) for j in js) > 10
        assert np.array_equal(jitter_direction(d, 15, 3, up=UP), js[3])
        assert len({tuple(np.round(j, 9)) for j in js}) == 50
        assert np.array_equal(jitter_direction(d, 0, 3), d)
        low = light_direction(2, 0, UP)
        assert all(jitter_direction(low, 20, s, up=UP) @ UP >= 0 for s in range(50))

    def test_cone(self):
        d = light_direction(60, 30, UP)
        c = cone_directions(d, 5, 32)
        assert c.shape == (32, 3) and np.allclose(np.linalg.norm(c, axis=1), 1)
        angles = [angle_deg(x, d) for x in c]
        assert max(angles) <= 5 + 1e-9 and min(angles) < 1 and max(angles) > 4.5
        assert angle_deg(c.mean(0) / np.linalg.norm(c.mean(0)), d) < 0.5  # balanced around the axis
        assert np.array_equal(cone_directions(d, 0, 32), d[None])


class TestShadowGeometry:
    @pytest.mark.parametrize("elevation,azimuth", [(90, 0), (45, 90), (60, 200)])
    def test_hard_shadow_matches_the_closed_form(self, floor, elevation, azimuth):
        scene, obj, _, center = floor
        light = light_direction(elevation, azimuth, UP)
        occ = Occluder.from_mesh(obj.vertices, obj.faces)
        f = shadow_fraction_map(scene.depth, scene.camera, occ, light[None])
        expected = closed_form_shadow(scene, center, light)
        assert expected.sum() > 300
        assert set(np.unique(f)) <= {0.0, 1.0}
        assert iou(f > 0.5, expected) > 0.9
        assert (f[~np.isfinite(scene.depth)] == 0).all()

    def test_overhead_shadow_lies_under_the_sphere(self, floor):
        scene, obj, _, center = floor
        occ = Occluder.from_mesh(obj.vertices, obj.faces)
        f = shadow_fraction_map(scene.depth, scene.camera, occ, UP[None])
        dist = np.linalg.norm(scene.camera.unproject(np.nan_to_num(scene.depth)) - (center - RADIUS * UP), axis=-1)
        dist = np.where(np.isfinite(scene.depth), dist, np.inf)  # from the sphere's foot on the floor
        assert dist[f > 0.5].max() <= RADIUS * 1.05  # the shadow is the disk under the sphere
        assert (f[dist < 0.95 * RADIUS] == 1).all() and (dist < 0.95 * RADIUS).sum() > 300

    def test_soft_shadow_has_a_penumbra(self, floor):
        scene, obj, _, center = floor
        light = light_direction(45, 90, UP)
        occ = Occluder.from_mesh(obj.vertices, obj.faces)
        hard = shadow_fraction_map(scene.depth, scene.camera, occ, light[None])
        soft = shadow_fraction_map(scene.depth, scene.camera, occ, cone_directions(light, 5, 32))
        penumbra = (soft > 0) & (soft < 1)
        assert penumbra.sum() > 20
        assert (soft[hard == 0] < 1).all() and (soft[hard == 1] > 0).all()
        assert iou(soft == 1, hard == 1) < 1 and (soft == 1).sum() < (hard == 1).sum()

    def test_culling_is_exact(self, floor):
        scene, obj, _, _ = floor
        occ = Occluder.from_mesh(obj.vertices, obj.faces)
        known = np.isfinite(scene.depth)
        pts = scene.camera.unproject(np.nan_to_num(scene.depth))[known]
        dirs = cone_directions(light_direction(45, 90, UP), 5, 8)
        import open3d as o3d

        rays = np.concatenate([np.repeat(pts, len(dirs), 0), np.tile(dirs, (len(pts), 1))], 1).astype(np.float32)
        brute = occ.scene.test_occlusions(o3d.core.Tensor(rays), tnear=occ.eps).numpy()
        brute = brute.reshape(len(pts), len(dirs)).mean(1)
        np.testing.assert_array_equal(occluded_fraction(occ, pts, dirs), brute.astype(np.float32))


class TestApplyShadow:
    def test_linear_darkening_and_untouched_pixels(self):
        img = torch.full((1, 3, 4, 5), 0.5)
        f = np.zeros((4, 5), np.float32)
        f[1, 2] = 1.0
        f[2, 3] = 0.5
        out = apply_shadow(img, f, strength=0.5)
        from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear

        lin = float(srgb_to_linear(torch.tensor(0.5)))
        assert out[0, :, 1, 2] == pytest.approx([float(linear_to_srgb(torch.tensor(lin * 0.5)))] * 3, abs=1e-6)
        assert out[0, :, 2, 3] == pytest.approx([float(linear_to_srgb(torch.tensor(lin * 0.75)))] * 3, abs=1e-6)
        keep = torch.from_numpy(f == 0)
        assert torch.equal(out[:, :, keep], img[:, :, keep])

    def test_through_the_warp_and_fresnel(self):
        img = torch.full((1, 3, 4, 5), 0.5)
        f = np.zeros((4, 5), np.float32)
        f[0, 0] = 1.0
        ys, xs = np.mgrid[0:4, 0:5].astype(np.float32)
        warp = np.stack([xs, ys], -1)
        warp[3, 4] = [0.0, 0.0]  # pixel (3, 4) sees the shadowed pixel (0, 0) through the glass
        warp[3, 3] = np.nan  # invalid: left as it is
        fresnel = np.zeros((4, 5), np.float32)
        fresnel[3, 4] = 0.5
        out = apply_shadow(img, f, strength=1.0, refraction=warp, fresnel=fresnel)
        a = apply_shadow(img, np.where(np.arange(20).reshape(4, 5) == 0, 0.5, 0.0), strength=1.0)
        assert torch.allclose(out[0, :, 3, 4], a[0, :, 0, 0])  # (1 - F) f = 0.5
        assert torch.equal(out[0, :, 3, 3], img[0, :, 3, 3])
        assert out[0, 0, 0, 0] == 0.0


class TestShadowRelighter:
    def test_on_the_floor(self, floor):
        scene, obj, warps, center = floor
        img = torch.full((1, 3, H, W), 0.6)
        r = ShadowRelighter(light_elevation_deg=45, light_azimuth_deg=90, jitter_deg=0, softness_deg=0, strength=0.5)
        assert isinstance(r, Relighter) and "no caustics" in r.describe()
        out = r.relight(img, prompt="", seed=0, scene=scene, obj=obj, warps=warps)
        assert out.shape == img.shape and out.dtype == torch.float32
        darker = (out < img - 1e-4).any(1)[0].numpy()
        expected = closed_form_shadow(scene, center, light_direction(45, 90, UP)) & ~warps.object_mask
        assert iou(darker & ~warps.object_mask, expected) > 0.9
        # far from the object and its shadow the image is untouched, bit for bit
        ys, xs = np.mgrid[0:H, 0:W]
        box = warps.object_mask.nonzero()
        far = (np.abs(ys - box[0].mean()) > 30) | (xs < 10) | (xs > W - 10)
        far &= ~expected
        assert torch.equal(out[0][:, torch.from_numpy(far)], img[0][:, torch.from_numpy(far)])

    def test_candidates_differ_and_are_deterministic(self, floor):
        scene, obj, warps, _ = floor
        img = torch.full((1, 3, H, W), 0.6)
        r = ShadowRelighter(samples=8)
        kw = {"scene": scene, "obj": obj, "warps": warps}
        a = r.relight(img, prompt="", seed=1, **kw)
        assert torch.equal(a, ShadowRelighter(samples=8).relight(img, prompt="", seed=1, **kw))
        assert not torch.equal(a, r.relight(img, prompt="", seed=2, **kw))

    def test_needs_the_scene(self, floor):
        scene, obj, warps, _ = floor
        r = ShadowRelighter()
        img = torch.full((1, 3, H, W), 0.6)
        with pytest.raises(ValueError, match="needs the scene"):
            r.relight(img, prompt="", seed=0, scene=scene, obj=obj)
        with pytest.raises(ValueError, match="same size"):
            r.relight(img[..., :-1], prompt="", seed=0, scene=scene, obj=obj, warps=warps)

    @pytest.mark.parametrize(
        "kw", [{"samples": 0}, {"softness_deg": 90}, {"strength": 1.5}, {"jitter_deg": -1}, {"light_elevation_deg": 91}]
    )
    def test_invalid_settings(self, kw):
        with pytest.raises(ValueError):
            ShadowRelighter(**kw)


@pytest.fixture(scope="module")
def prepared():
    from snell_bench.config import compose
    from snell_bench.pipeline import prepare_inputs

    cfg = compose(
        [
            "scene.width=160",
            "scene.height=96",
            "reference.enabled=false",
            "warps.cache_dir=null",
            "warps.pano_height=64",
        ]
    )
    return prepare_inputs(cfg, references=False)


def test_on_prepared_inputs(prepared):
    """The stand-in on a procedural room with a placed glass sphere, through the selection."""
    from snell_bench.imaging.remap import remap

    inp = prepared
    mask = inp.warps.object_mask
    seen, _ = remap(inp.i_minus, inp.warps.refraction)  # I⁻ seen through the glass: a stand-in image
    img = torch.where(torch.from_numpy(mask)[None, None], seen, inp.i_minus)
    r = ShadowRelighter()
    kw = {"scene": inp.scene, "obj": inp.obj, "warps": inp.warps}
    seeds = candidate_seeds(0, 3)
    outs = [r.relight(img, prompt="p", seed=s, **kw) for s in seeds]
    for out in outs:
        changed = (out != img).any(1)[0].numpy()
        assert changed.sum() > 50 and changed[mask].sum() > 10  # the shadow is seen through the glass too
        assert (out <= img + 1e-6).all()  # a shadow only darkens
        assert not changed[:10].any()  # the top rows (walls, far from the object) are untouched
    psnrs = [masked_psnr(o, img, mask) for o in outs]
    assert len(set(psnrs)) == 3
    res = relight(img, relighter=r, prompt="p", seeds=seeds, object_mask=mask, **kw)
    assert res.chosen == int(np.argmax(psnrs)) and torch.equal(res.image, outs[res.chosen])
    rec = json.loads(json.dumps(res.to_json(), allow_nan=False))
    assert rec["relighter"] == "traced_shadow" and [c["seed"] for c in rec["candidates"]] == seeds
