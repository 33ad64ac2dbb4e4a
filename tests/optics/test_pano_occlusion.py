"""π⁻¹ and π^-R of object pixels are valid only where the panorama centre sees the traced ray's end:
a surface between the centre and the end would otherwise lend its colour to the glass.

The scene: a glass sphere (IOR 1.5) at z = 3 before a plane at z = 5, with two sheets at z = 4 that
the camera sees beside the sphere's axis (cut from the plane: a relative depth jump of 25 %). Where a
traced ray ends on the plane is read back from its perspective warp (π^R or the mirror warp: the
pixel of I⁻ it ends on, at depth 5), so the reference below needs no ray tracing: the straight segment
from the panorama centre ``c`` to that end ``p`` crosses z = 4 at ``m``, and ``p`` is hidden iff ``m``
falls on a sheet. Both are decided one pixel (in x / z at the sheets' depth) away from the sheets'
edges, where the depth mesh's triangulation between pixel centres leaves the edge's position open.
"""

import numpy as np
import pytest
from conftest import sphere_at

from snell_bench.optics import compute_warps
from snell_bench.optics.occlusion import occlusion_tolerance, ray_ends_seen
from snell_bench.scene.camera import Camera

CENTER, RADIUS, PLANE_Z, SHEET_Z = np.array([0.0, 0.0, 3.0]), 0.5, 5.0, 4.0
#: x / z of the camera rays that see each sheet: the inner one hides plane points reached by refracted
#: rays (they cross the axis behind the sphere), the outer one those reached by mirror rays from the
#: sphere's left rim (x / z -0.16, ending near x / z -0.45 on the plane, their segment from the centre
#: crossing z = 4 near x / z -0.29).
SHEETS = ((-0.12, -0.06), (-0.34, -0.24))


@pytest.fixture(scope="module")
def cam():
    return Camera.from_fov(128, 96, 60.0)


def sheets_depth(cam):
    xn = cam.pixel_rays(normalize=False)[..., 0]
    on = np.zeros(cam.shape, bool)
    for lo, hi in SHEETS:
        on |= (xn >= lo) & (xn <= hi)
    return np.where(on, SHEET_Z, PLANE_Z).astype(np.float32)


@pytest.fixture(scope="module")
def scene(cam):
    depth = sheets_depth(cam)
    return depth, compute_warps(depth, cam, sphere_at(CENTER, RADIUS), pano_height=32)


def classify(cam, c, src):
    """Plane ends of the perspective warp ``src`` (``(N, 2)`` pixels of I⁻): ``(hidden, seen)`` from
    the segment's crossing of z = 4 (module docstring)."""
    one = 1.0 / cam.K[0, 0]
    xz = (src[:, 0].astype(np.float64) - cam.K[0, 2]) / cam.K[0, 0]
    yz = (src[:, 1].astype(np.float64) - cam.K[1, 2]) / cam.K[1, 1]
    near_sheet = np.zeros(len(src), bool)
    for lo, hi in SHEETS:
        near_sheet |= (xz >= lo - one) & (xz <= hi + one)
    p = np.stack([xz * PLANE_Z, yz * PLANE_Z, np.full_like(xz, PLANE_Z)], -1)
    s = (SHEET_Z - c[2]) / (p[:, 2] - c[2])
    mx = (c[0] + s * (p[:, 0] - c[0])) / SHEET_Z
    on_sheet = np.zeros(len(src), bool)
    off_sheets = np.ones(len(src), bool)
    for lo, hi in SHEETS:
        on_sheet |= (mx > lo + one) & (mx < hi - one)
        off_sheets &= (mx < lo - one) | (mx > hi + one)
    on_plane = ~near_sheet
    return on_plane & on_sheet, on_plane & off_sheets


def test_refracted_rays_hidden_from_the_centre_are_invalid(cam, scene):
    _, ws = scene
    m = ws.object_mask & ws.refraction_valid
    hidden, seen = classify(cam, ws.pano.center, ws.refraction[m])
    assert hidden.sum() >= 20 and seen.sum() >= 300
    assert not ws.pano_refraction_valid[m][hidden].any()
    assert np.isnan(ws.pano_refraction[m][hidden]).all()
    assert np.isnan(ws.pano_refraction_frame[m][hidden]).all()  # the whole-frame π⁻¹ keeps it
    assert ws.pano_refraction_valid[m][seen].all()


def test_mirror_rays_hidden_from_the_centre_are_invalid(cam, scene):
    _, ws = scene
    m = ws.object_mask & ws.reflection_valid
    hidden, seen = classify(cam, ws.pano.center, ws.reflection[m])
    assert hidden.sum() >= 4 and seen.sum() >= 50
    assert not ws.pano_reflection_valid[m][hidden].any()
    assert np.isnan(ws.pano_reflection[m][hidden]).all()
    assert ws.pano_reflection_valid[m][seen].all()


def test_without_parallax_the_mirror_direction_has_nothing_to_occlude(cam, scene):
    depth, ws = scene
    flat = compute_warps(depth, cam, sphere_at(CENTER, RADIUS), pano_height=32, reflection_parallax=False)
    hit = ws.object_mask & np.isfinite(flat.pano_reflection).all(-1)
    assert flat.pano_reflection_valid[ws.object_mask].all() and hit.sum() == ws.object_mask.sum()


def test_a_ray_that_reached_the_back_of_a_surface_is_not_seen_from_its_front(cam):
    """The centre in front of the plane z = 5 sees its front; a ray that arrived from behind it saw
    its back (unless ``sides=False``, which accepts either side)."""
    from snell_bench.optics import HitKind, SceneTracer
    from snell_bench.scene.depth_mesh import build_background

    bg = build_background(np.full(cam.shape, PLANE_Z, np.float32), cam, extra_points=[[0, 0, 7]])
    tracer = SceneTracer(bg, sphere_at(CENTER, RADIUS))
    o = np.array([[0.1, 0.05, 6.5], [0.1, 0.05, 3.5]])  # behind the plane, and in front of it
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    h = tracer.cast_background(o, d)
    assert h.kind.tolist() == [HitKind.UNOBSERVED, HitKind.OBSERVED] and not h.on_box.any()
    seen = ray_ends_seen(tracer, None, CENTER, h.point, o, h.kind, h.on_box)
    assert seen.tolist() == [False, True]
    assert ray_ends_seen(tracer, None, CENTER, h.point, o, h.kind, h.on_box, sides=False).all()


def test_tolerance_follows_the_scale_and_caps_at_grazing():
    c = np.array([0.0, 0.0, 3.0])
    o, p = np.array([[0.0, 0.0, 3.5]]), np.array([[0.0, 0.0, 5.0]])
    head_on = occlusion_tolerance(c, o, p, np.array([1.0]))[0]
    assert head_on == pytest.approx(16 * 2.0**-24 * (3 + 3.5 + 10))
    assert occlusion_tolerance(c, o, p, np.array([0.0]))[0] == pytest.approx(64 * head_on)
    assert occlusion_tolerance(c * 10, o * 10, p * 10, np.array([1.0]))[0] == pytest.approx(10 * head_on)
