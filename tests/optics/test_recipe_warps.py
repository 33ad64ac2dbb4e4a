"""The warps' recipe switches (``warps.*`` of ``conf/recipe/authors.yaml``) against closed forms and
hand-made geometry: back-face ends in π^R, the authors' interaction limit, flat face normals with
π^-R by the mirror direction alone, the half-pixel shift of the perspective maps, and the panorama at
the surface centroid with the camera's axes."""

import numpy as np
import pytest
import torch
import trimesh
from conftest import sphere_at
from tolerances import EPS32

from snell_bench.optics import HitKind, SceneTracer, compute_warps
from snell_bench.optics.warp_maps import PrimaryRays, refraction_warps
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import build_background
from snell_bench.scene.objects import GlassObject

CENTER, RADIUS, PLANE_Z = np.array([0.0, 0.0, 3.0]), 0.5, 5.0


@pytest.fixture(scope="module")
def cam():
    return Camera.from_fov(64, 48, 60.0)


def plane(cam):
    return np.full(cam.shape, PLANE_Z, np.float32)


def hand_pano_pixel(d, pano_height):
    """Panorama pixel of directions ``d`` in the panorama frame (the documented convention)."""
    lon = np.arctan2(d[:, 0], d[:, 2])
    lat = np.arctan2(-d[:, 1], np.hypot(d[:, 0], d[:, 2]))
    return np.stack([(lon / (2 * np.pi) + 0.5) * 2 * pano_height - 0.5, (0.5 - lat / np.pi) * pano_height - 0.5], -1)


def first_faces(tris, d):
    """Brute-force Möller-Trumbore of rays from the origin along ``d`` (N, 3) against every triangle
    ``tris`` (F, 3, 3), independent of Open3D: ``(face (N,), barycentrics (N, 3))`` of the nearest hit."""
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    h = np.cross(d[:, None], e2[None])
    det = np.einsum("fk,nfk->nf", e1, h)
    s = -tris[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.einsum("nfk,nfk->nf", s, h) / det
        q = np.cross(s, e1[None])
        v = np.einsum("nk,nfk->nf", d, q) / det
        t = np.einsum("fk,nfk->nf", e2, q) / det
    t = np.where((u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0), t, np.inf)
    f = t.argmin(axis=1)
    n = np.arange(len(d))
    return f, np.stack([1 - u[n, f] - v[n, f], u[n, f], v[n, f]], -1)


def wrapped(a, b, width):
    """``a - b`` with the x difference taken around the panorama's seam."""
    d = np.asarray(a, np.float64) - b
    d[:, 0] = (d[:, 0] + width / 2) % width - width / 2
    return d


# --------------------------------------------------------------------------- π^R and back faces
def test_back_face_end_is_valid_only_with_back_faces(cam):
    """Rays cast towards the camera from behind the plane z = 5 through a sphere of IOR 1 (straight
    lines) end on the plane's back side at ``(x, y, 5)``: unobserved by default; with
    ``back_faces`` valid at the pixel ``K (x, y, 5) / 5`` that shows the front of that point."""
    obj = sphere_at([0.0, 0.0, 6.0], 0.3, ior=1.0)
    bg = build_background(plane(cam), cam, extra_points=[[0.0, 0.0, 8.0]])
    tracer = SceneTracer(bg, obj)
    xy = np.array([[0.0, 0.0], [0.1, -0.05], [-0.12, 0.08]])
    o = np.column_stack([xy, np.full(len(xy), 7.5)])
    tr = tracer.trace(o, np.tile([0.0, 0.0, -1.0], (len(xy), 1)))
    assert (tr.kind == HitKind.UNOBSERVED).all() and not tr.on_box.any() and (tr.bounces == 2).all()
    pixels = np.arange(len(xy)) * 7
    mask = np.zeros(cam.height * cam.width, bool)
    mask[pixels] = True
    primary = PrimaryRays(len(xy), pixels, np.zeros((len(xy), 3)), mask)
    off = refraction_warps(cam, tracer, tr, primary, False)
    on = refraction_warps(cam, tracer, tr, primary, False, back_faces=True)
    assert not off["refraction_valid"][pixels].any() and np.isnan(off["refraction"][pixels]).all()
    assert on["refraction_valid"][pixels].all()
    expected = cam.K[:2, :2] @ (xy.T / PLANE_Z) + cam.K[:2, 2:3]
    # float32 rays: the end moves by ~8 u |p| across the ray, f / z pixels per unit; the stored pixel
    # adds u |x|; twice the sum
    tol = 2 * (cam.K[0, 0] / PLANE_Z * 8 * EPS32 * 8.0 + EPS32 * cam.width)
    np.testing.assert_allclose(on["refraction"][pixels], expected.T, atol=tol, rtol=0)
    np.testing.assert_array_equal(on["refraction_kind"][pixels], HitKind.UNOBSERVED)  # the kind stays


# --------------------------------------------------------------------------- interactions
def test_recipe_max_bounces_replaces_the_presets_limit(cam):
    """Every path through a sphere takes two interactions: one is not enough (all trapped); the
    recipe's 12 replaces a limit of 1 and gives the warps of ``max_bounces=12``."""
    obj = sphere_at(CENTER, RADIUS)
    one = compute_warps(plane(cam), cam, obj, pano_height=16, max_bounces=1)
    m = one.object_mask
    assert (one.refraction_kind[m] == HitKind.TRAPPED).all()
    rec = compute_warps(plane(cam), cam, obj, pano_height=16, max_bounces=1, recipe_max_bounces=12)
    ref = compute_warps(plane(cam), cam, obj, pano_height=16, max_bounces=12)
    assert (rec.bounces[m] == 2).all() and rec.options["max_bounces"] == 12
    assert rec.input_hash == ref.input_hash
    np.testing.assert_array_equal(rec.refraction, ref.refraction)


# --------------------------------------------------------------------------- face normals, π^-R by direction
def test_face_normals_mirror_direction_matches_trimesh(cam):
    """On a 320-face icosphere with flat face normals, π^-R without parallax is the panorama pixel of
    ``d - 2 (d · n) n`` with ``n`` the normal of the face trimesh finds for each camera ray (the
    panorama frame is the camera frame for up (0, -1, 0)). Interpolated normals differ by pixels."""
    obj = sphere_at(CENTER, RADIUS, subdivisions=2)
    Hp = 32
    ws = compute_warps(plane(cam), cam, obj, pano_height=Hp, normals="face", reflection_parallax=False)
    np.testing.assert_allclose(ws.pano.rotation, np.eye(3), atol=1e-12)
    m = ws.object_mask
    d = cam.pixel_rays()[m]
    tri, bary = first_faces(np.asarray(obj.mesh.triangles), d)
    inner = bary.min(axis=1) > 1e-3  # off the faces' edges, where the two casters may pick either face
    assert inner.sum() > 0.8 * len(d)
    n = obj.mesh.face_normals[tri]
    mirror = d - 2 * np.einsum("ij,ij->i", d, n)[:, None] * n
    expected = hand_pano_pixel(mirror, Hp)
    got = ws.pano_reflection[m]
    # the caster's face normal is the cross product of float32 vertices: each coordinate rounded by
    # u |v|, so the normal turns by <= 4 u |v|max / (shortest edge), the mirror by twice that; Wp / 2pi
    # pixels a radian in latitude, that over cos(lat) in longitude; the stored pixel adds u Wp; twice
    edges = np.linalg.norm(np.diff(np.asarray(obj.mesh.triangles), axis=1, append=obj.mesh.triangles[:, :1]), axis=2)
    turn = 2 * 4 * EPS32 * np.abs(obj.vertices).max() / edges.min()
    cos_lat = np.hypot(mirror[:, 0], mirror[:, 2]) / np.linalg.norm(mirror, axis=1)
    tol = 2 * (2 * Hp / (2 * np.pi) * turn * (1 + 1 / cos_lat) + EPS32 * 2 * Hp)
    err = np.abs(wrapped(got, expected, 2 * Hp)).max(axis=1)
    assert (err <= tol)[inner].all(), (err - tol)[inner].max()
    smooth = compute_warps(plane(cam), cam, obj, pano_height=Hp, reflection_parallax=False)
    assert np.abs(wrapped(smooth.pano_reflection[m], expected, 2 * Hp)).max() > 0.5


def test_parallax_off_ignores_the_mirror_rays_end(cam):
    """Without parallax, π^-R does not depend on where the mirror ray ends: moving the plane moves
    π^-R with parallax only."""
    obj = sphere_at(CENTER, RADIUS)
    kw = dict(pano_height=32, reflection_parallax=False)
    a = compute_warps(plane(cam), cam, obj, **kw)
    b = compute_warps(plane(cam) * 2, cam, obj, **kw)
    np.testing.assert_array_equal(a.pano_reflection, b.pano_reflection)
    pa = compute_warps(plane(cam), cam, obj, pano_height=32)
    pb = compute_warps(plane(cam) * 2, cam, obj, pano_height=32)
    both = pa.pano_reflection_valid & pb.pano_reflection_valid & (pa.reflection_valid | pb.reflection_valid)
    assert both.any() and np.abs(pa.pano_reflection[both] - pb.pano_reflection[both]).max() > 0.1


# --------------------------------------------------------------------------- half-pixel shift
def test_half_pixel_shift_of_an_invisible_object(cam):
    """IOR 1: every object pixel's refracted ray is its own camera ray, so π^R is the identity; the
    shift makes it ``x + 0.5, y + 0.5`` there and leaves the identity outside the object. π (the
    panorama's rays) moves by exactly 0.5 px where the shifted source stays in [0, W - 1) x [0, H - 1)
    and becomes invalid elsewhere."""
    obj = sphere_at(CENTER, RADIUS, ior=1.0)
    a = compute_warps(plane(cam), cam, obj, pano_height=32)
    b = compute_warps(plane(cam), cam, obj, pano_height=32, half_pixel_shift=True)
    m = b.object_mask
    grid = cam.pixel_grid()
    # the straight ray ends on the mesh vertex of its pixel: ~8 u |p| in space, f / z px a unit
    tol = 2 * (cam.K[0, 0] / PLANE_Z * 8 * EPS32 * 2 * PLANE_Z + EPS32 * cam.width)
    np.testing.assert_allclose(a.refraction[m], grid[m], atol=tol, rtol=0)
    np.testing.assert_allclose(b.refraction[m], grid[m] + 0.5, atol=tol, rtol=0)
    np.testing.assert_array_equal(b.refraction[~m], grid[~m])
    W, H = cam.width, cam.height
    s = a.pano_to_persp + np.float32(0.5)
    with np.errstate(invalid="ignore"):
        inside = a.pano_to_persp_valid & (s[..., 0] >= 0) & (s[..., 0] < W - 1) & (s[..., 1] >= 0) & (s[..., 1] < H - 1)
    assert (a.pano_to_persp_valid & ~inside).any()  # the last column and row drop out
    np.testing.assert_array_equal(b.pano_to_persp_valid, inside)
    np.testing.assert_array_equal(b.pano_to_persp[inside], s[inside])
    assert not (b.pano_to_persp_object & ~b.pano_to_persp_valid).any()


def test_align_corners_reads_edge_coordinates_half_a_pixel_late():
    """What the shift reproduces: a map in pixel-edge coordinates (the centre of pixel ``i`` at
    ``i + 0.5``) read by ``grid_sample(align_corners=True)`` samples the pixel-centre coordinate
    ``x_c + 0.5``: for a linear ramp ``I(x, y) = 3 x + 5 y`` the value is ``3 (x_c + 0.5) + 5 (y_c + 0.5)``."""
    H, W = 6, 9
    yy, xx = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    img = (3 * xx + 5 * yy)[None, None]
    xc = torch.tensor([1.0, 2.25, 4.0, 6.5], dtype=torch.float64)
    yc = torch.tensor([0.0, 1.5, 3.75, 2.0], dtype=torch.float64)
    ex, ey = xc + 0.5, yc + 0.5  # the authors' stored coordinates
    grid = torch.stack([ex / (W - 1) * 2 - 1, ey / (H - 1) * 2 - 1], -1)[None, None]
    got = torch.nn.functional.grid_sample(img, grid, mode="bilinear", align_corners=True)[0, 0, 0]
    torch.testing.assert_close(got, 3 * (xc + 0.5) + 5 * (yc + 0.5), rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- the panorama's pose
def cone_object():
    mesh = trimesh.creation.cone(radius=0.3, height=0.6, sections=24)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))  # apex towards -y (up)
    mesh.apply_translation(CENTER)
    return GlassObject.from_mesh(mesh.vertices, mesh.faces)


def test_pano_at_the_surface_centroid(cam):
    """The centre is the mean of the triangles' centres weighted by their areas (written out here),
    not the bounding box's centre (a cone's differ by a sixth of its height and more)."""
    obj = cone_object()
    ws = compute_warps(plane(cam), cam, obj, pano_height=16, pano_center="centroid")
    tri = obj.vertices[obj.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    centroid = (tri.mean(axis=1) * area[:, None]).sum(0) / area.sum()
    np.testing.assert_allclose(ws.pano.center, centroid, atol=1e-12)
    assert np.linalg.norm(centroid - obj.center) > 0.05


def test_pano_in_the_camera_frame_for_a_tilted_scene(cam):
    """Scene up tilted 20 degrees towards the camera: the level panorama's top row looks along it,
    the camera-frame one along the camera's -y. π of the camera-frame panorama against the closed
    form on the plane z = 5: panorama pixel centre direction ``d`` (the documented convention), end
    ``c + t d`` with ``t = (5 - c_z) / d_z``, perspective pixel ``K (c + t d) / 5``."""
    a = np.radians(20.0)
    up = np.array([0.0, -np.cos(a), -np.sin(a)])
    obj = sphere_at(CENTER, RADIUS)
    level = compute_warps(plane(cam), cam, obj, pano_height=16, up=up)
    np.testing.assert_allclose(-level.pano.rotation[:, 1], up, atol=1e-12)
    Hp = 16
    ws = compute_warps(plane(cam), cam, obj, pano_height=Hp, up=up, pano_axes="camera")
    np.testing.assert_array_equal(ws.pano.rotation, np.eye(3))
    u, v = np.meshgrid(np.arange(2 * Hp) + 0.0, np.arange(Hp) + 0.0)
    lon = ((u + 0.5) / (2 * Hp) - 0.5) * 2 * np.pi
    lat = (0.5 - (v + 0.5) / Hp) * np.pi
    d = np.stack([np.cos(lat) * np.sin(lon), -np.sin(lat), np.cos(lat) * np.cos(lon)], -1)
    c = ws.pano.center
    with np.errstate(divide="ignore"):
        t = (PLANE_Z - c[2]) / d[..., 2]
    p = c + t[..., None] * d
    pix = (p / PLANE_Z) @ cam.K.T
    ok = ws.pano_to_persp_valid & ~ws.pano_to_persp_object
    assert ok.sum() > 20
    # the end lies on the mesh (float32: ~8 u |p|), f / z pixels a unit; the stored pixel adds u W
    tol = 2 * (cam.K[0, 0] / PLANE_Z * 8 * EPS32 * 4 * PLANE_Z + EPS32 * cam.width)
    np.testing.assert_allclose(ws.pano_to_persp[ok], pix[ok][:, :2], atol=tol, rtol=0)


def test_config_names_a_bad_pano_choice():
    from snell_bench.config.schema import WarpConfig

    with pytest.raises(Exception, match=r"warps.pano_center='middle'.*bbox or centroid"):
        WarpConfig(pano_center="middle")
    with pytest.raises(Exception, match=r"warps.recipe_max_bounces=0"):
        WarpConfig(recipe_max_bounces=0)
    with pytest.raises(ValueError, match="pano_axes='tilted'"):
        compute_warps(np.full((8, 8), 5.0), Camera.from_fov(8, 8, 60.0), sphere_at(CENTER, RADIUS), pano_axes="tilted")
