"""The tracer on shapes with closed-form answers: slabs, re-entry, objects cutting the background."""

import math

import numpy as np
import pytest
import trimesh
from conftest import sphere_at

from snell_bench.optics import HitKind, compute_warps
from snell_bench.optics.tracer import SceneTracer
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import build_background
from snell_bench.scene.objects import GlassObject


@pytest.fixture(scope="module")
def cam():
    return Camera.from_fov(320, 180, 50.0)


def test_cube_face_on_is_a_slab(cam):
    """Through two parallel faces a ray keeps its direction; inside, it advances t tan(theta_t)
    sideways instead of t tan(theta) (t: slab thickness)."""
    t, ior, zf, zp = 0.6, 1.5, 2.7, 6.0
    box = trimesh.creation.box(extents=(4.0, 4.0, t))  # wider than the view: every ray crosses both faces
    box.apply_translation([0, 0, zf + t / 2])
    ws = compute_warps(
        np.full(cam.shape, zp, np.float32), cam, GlassObject.from_mesh(box.vertices, box.faces, ior=ior), pano_height=16
    )
    m = ws.object_mask & ws.refraction_valid
    ys, xs = np.nonzero(m)
    d = cam.pixel_rays(np.stack([xs, ys], -1).astype(float))
    theta = np.arccos(d[:, 2])
    theta_t = np.arcsin(np.sin(theta) / ior)
    # where the ray meets the plane: straight line minus the sideways shift along the radial direction
    radial = d[:, :2] / np.maximum(np.linalg.norm(d[:, :2], axis=1, keepdims=True), 1e-12)
    shift = t * (np.tan(theta) - np.tan(theta_t))
    p = d / d[:, 2:3] * zp
    p[:, :2] -= radial * shift[:, None]
    pix, _ = cam.project(p)
    err = np.linalg.norm(pix - ws.refraction[ys, xs], axis=1)
    assert len(err) == cam.width * cam.height
    assert err.max() < 1e-2  # flat faces: exact up to float32
    assert np.all(ws.bounces[m] == 2)


def test_torus_rays_reenter(cam):
    """A non-convex object: rays that leave one side of a torus hit its other side."""
    tor = trimesh.creation.torus(major_radius=0.5, minor_radius=0.18, major_sections=96, minor_sections=48)
    tor.apply_transform(trimesh.transformations.rotation_matrix(math.radians(80), [1, 0, 0]))  # nearly edge-on
    tor.apply_translation([0, 0, 3.0])
    ws = compute_warps(
        np.full(cam.shape, 6.0, np.float32), cam, GlassObject.from_mesh(tor.vertices, tor.faces), pano_height=16
    )
    b = ws.bounces[ws.object_mask]
    assert (b >= 4).sum() > 50, np.bincount(b)
    assert not np.any(ws.refraction_kind[ws.object_mask] == HitKind.LOST)


def test_sphere_cut_by_background_plane(cam):
    """Half a sphere sticks out of a wall: rays that refract in end on the wall inside the glass."""
    c, r, ior, wall = np.array([0.0, 0.0, 3.0]), 0.5, 1.5, 3.0
    ws = compute_warps(np.full(cam.shape, wall, np.float32), cam, sphere_at(c, r), pano_height=16)
    m = ws.object_mask
    ys, xs = np.nonzero(m)
    d = cam.pixel_rays(np.stack([xs, ys], -1).astype(float))
    # closed form: enter the sphere, then straight on to the wall plane
    b = d @ c
    tt = b - np.sqrt(b * b - (c @ c - r * r))
    p1 = tt[:, None] * d
    n = (p1 - c) / r
    cos_i = -(d * n).sum(1, keepdims=True)
    tan = (d + cos_i * n) / ior
    d1 = tan - np.sqrt(1 - (tan * tan).sum(1, keepdims=True)) * n
    p2 = p1 + ((wall - p1[:, 2]) / d1[:, 2])[:, None] * d1
    pix, _ = cam.project(p2)
    inner = np.linalg.norm(n[:, :2], axis=1) < 0.9  # away from the silhouette
    err = np.linalg.norm(pix[inner] - ws.refraction[ys[inner], xs[inner]], axis=1)
    assert np.median(err) < 0.05 and np.percentile(err, 99) < 0.5
    assert np.all(ws.bounces[ys[inner], xs[inner]] == 1)  # one interaction: entry
    assert np.all(ws.refraction_kind[ys[inner], xs[inner]] == HitKind.OBSERVED)
    # the object is only seen where it is in front of the wall: a disc of the sphere's radius
    area = m.sum() / (cam.K[0, 0] / wall) ** 2
    assert area == pytest.approx(math.pi * r * r, rel=0.05)


def test_back_side_of_background_is_unobserved(cam):
    """A ray that reaches the background from behind sees a side I⁻ never showed."""
    depth = np.full(cam.shape, 4.0, np.float32)
    bg = build_background(depth, cam, extra_points=np.array([[0, 0, 8.0]]))
    tracer = SceneTracer(bg, sphere_at([0, 0, 2.0], 0.2, subdivisions=2))
    hit = tracer.cast_background(
        np.array([[0.0, 0.0, 6.0], [0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    )
    assert hit.kind.tolist() == [HitKind.UNOBSERVED, HitKind.OBSERVED]
    np.testing.assert_allclose(hit.t, [2.0, 3.0], rtol=1e-6)


def test_bad_tracer_options(cam):
    bg = build_background(np.full(cam.shape, 4.0, np.float32), cam)
    obj = sphere_at([0, 0, 2.0], 0.2, subdivisions=1)
    with pytest.raises(ValueError, match="normals"):
        SceneTracer(bg, obj, normals="phong")
    with pytest.raises(ValueError, match="max_bounces"):
        SceneTracer(bg, obj, max_bounces=0)
