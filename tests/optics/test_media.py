"""Objects of several media (a glass of water): the medium stack against closed forms (Bouguer's
invariant on concentric spheres, a core of the glass's IOR, an air core against a hollow shell, a
shell of lower priority), and the optical depth of each medium."""

import numpy as np
import pytest
import trimesh

from snell_bench.config.materials import Medium
from snell_bench.optics import HitKind
from snell_bench.optics.media import current_medium, trace_nested
from snell_bench.optics.tracer import SceneTracer
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import build_background
from snell_bench.scene.objects import GlassObject

CENTRE = np.array([0.0, 0.0, 3.0])
R_OUT, R_IN = 0.5, 0.3
U32 = 2.0**-24


def _ball(radius: float, subdivisions: int = 5) -> trimesh.Trimesh:
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    m.apply_translation(CENTRE)
    return m


def _tracer(obj: GlassObject, max_bounces: int = 16) -> SceneTracer:
    cam = Camera.from_fov(16, 12, 90.0)
    return SceneTracer(build_background(np.full(cam.shape, 30.0), cam), obj, max_bounces=max_bounces)


def _rays(b_max: float, n: int = 12) -> np.ndarray:
    """Camera rays (from the origin) at impact parameters up to ``b_max`` from the centre, all azimuths."""
    b, az = np.meshgrid(np.linspace(0.0, b_max, n), np.linspace(0.0, 2 * np.pi, n, endpoint=False))
    alpha = np.arcsin(b.ravel() / np.linalg.norm(CENTRE))
    return np.stack([np.sin(alpha) * np.cos(az.ravel()), np.sin(alpha) * np.sin(az.ravel()), np.cos(alpha)], 1)


def _water_glass(core_ior=1.333, core_priority=1, glass_priority=0, absorption=((0.0,) * 3, (0.0,) * 3)):
    return GlassObject.nested(
        [
            (_ball(R_OUT), Medium(1.5, absorption[0], glass_priority)),
            (_ball(R_IN), Medium(core_ior, absorption[1], core_priority)),
        ],
        placed=True,  # the balls are in the camera frame
    )


def test_current_medium_is_the_highest_priority_shell():
    inside = np.array([0b000, 0b001, 0b011, 0b111, 0b101, 0b110])
    assert current_medium(inside, np.array([0, 2, 1])).tolist() == [-1, 0, 1, 1, 2, 1]
    assert current_medium(inside, np.array([0, 0, 0])).tolist() == [-1, 0, 1, 2, 2, 2]  # ties: the later shell


def _normal_error(obj: GlassObject, centre: np.ndarray) -> float:
    """The largest angle (radians) between a corner's shading normal and the radial direction there:
    the corner normals average the faces around a vertex, which is close to radial, not exactly."""
    cn = obj.corner_normals()
    r = obj.vertices[obj.faces] - centre
    r /= np.linalg.norm(r, axis=-1, keepdims=True)
    return float(np.arccos(np.clip((cn * r).sum(-1), -1.0, 1.0)).max())


def test_bouguer_invariant_along_rays_through_concentric_media():
    """In a spherically symmetric medium ``n |r x d|`` (n r sin θ) is constant along a ray: straight
    segments keep ``|r x d|``, refraction at a sphere keeps ``n`` times it (the normal is radial).

    Tolerance per surface met: a shading normal off the radial direction by ``delta`` (measured on
    the mesh, about 3e-3 rad at subdivision 5) changes ``n d`` across the surface by at most
    ``(n1 + n2) delta``, so ``J`` by ``r (n1 + n2) delta``; each ``eps`` offset along the face normal
    moves the ray's line by at most ``eps`` (times n); float32 barycentrics a few ulps more. Rays up
    to b = 0.3 meet the core at <= 42°, far from total reflection."""
    obj = _water_glass()
    tr = _tracer(obj)
    n_of = np.array([1.5, 1.333, 1.0])  # glass, water, air (index -1)
    record: list = []
    d = _rays(0.3)
    res = trace_nested(tr, np.zeros_like(d), d, record=record)
    assert (res.kind == HitKind.OBSERVED).all()
    assert (res.bounces == 4).all()  # glass in, water in, water out, glass out
    b = np.linalg.norm(np.cross(-CENTRE, d), axis=1)
    per_surface = R_OUT * (1.5 + 1.5) * _normal_error(obj, CENTRE) + 2 * 1.5 * tr.eps + 64 * U32 * 1.5 * R_OUT
    worst = 0.0
    for step, (rays, o, dd, medium) in enumerate(record):
        J = n_of[medium] * np.linalg.norm(np.cross(o - CENTRE, dd), axis=1)
        np.testing.assert_array_less(np.abs(J - b[rays]), step * per_surface + 1e-12)
        worst = max(worst, float(np.abs(J - b[rays]).max()))
    assert len(record) == 5 and worst < 0.01 * R_IN  # the bound is not vacuous: J is conserved to 1 %


def test_bouguer_invariant_to_1e_6_with_radial_normals():
    """``warps.normals=radial`` (the exact normals of concentric spheres): at every interface the
    invariant ``n |(p - c) x d|`` of the line through the hit point ``p`` is the same before and after
    to 1e-6 (refraction keeps the tangential part of ``n d``, and the normal is ``p - c``: float64
    rounding, about 1e-15); the line that leaves is moved ``eps`` along the face normal (the tracer's
    self-intersection offset), which changes the invariant by at most ``n eps``."""
    obj = _water_glass()
    cam = Camera.from_fov(16, 12, 90.0)
    tr = SceneTracer(build_background(np.full(cam.shape, 30.0), cam), obj, max_bounces=16, normals="radial")
    n_of = np.array([1.5, 1.333, 1.0])
    record: list = []
    d = _rays(0.45)
    res = trace_nested(tr, np.zeros_like(d), d, record=record)
    assert not np.isin(res.kind, [HitKind.TRAPPED, HitKind.LOST]).any() and len(record) >= 5
    worst_interface, worst_offset = 0.0, 0.0
    for (rays, o, dd, medium), (rays2, o2, dd2, medium2) in zip(record, record[1:]):
        keep = np.isin(rays, rays2)
        o, dd, medium = o[keep], dd[keep], medium[keep]
        t = tr.cast_object(o, dd)["t"]
        p = o + t[:, None] * dd  # the hit point, as the tracer computed it
        j_in = n_of[medium] * np.linalg.norm(np.cross(p - CENTRE, dd), axis=1)
        j_out = n_of[medium2] * np.linalg.norm(np.cross(p - CENTRE, dd2), axis=1)
        j_line = n_of[medium2] * np.linalg.norm(np.cross(o2 - CENTRE, dd2), axis=1)
        worst_interface = max(worst_interface, float(np.abs(j_out - j_in).max()))
        worst_offset = max(worst_offset, float(np.abs(j_line - j_out).max()))
    assert worst_interface < 1e-6 * R_IN
    assert worst_offset <= 1.5 * tr.eps * (1 + 1e-6)


def _compare(a, b, crossings: int, eps: float) -> None:
    """Two traces of the same rays through the same interfaces up to ``crossings`` extra surfaces
    met with no change of direction. Each extra surface's ``eps`` offset moves the ray's line by at
    most ``eps``, and every surface's float32 intersection (``8 u |p|`` at ``|p| <= 3.5`` m, the two
    traces cast different triangles or windings) moves its hit point, so the ray meets the next
    surface up to that much elsewhere, where the normal turns by that over ``R_in`` at most
    (curvature 1 / R), turning the ray by ``(n + 1)`` times that; the background is at most 30 m on."""
    assert np.array_equal(a.kind, b.kind)
    surfaces = int(max(a.bounces.max(), b.bounces.max()))
    moved = crossings * 4 * eps + surfaces * 8 * U32 * 3.5
    turn = surfaces * (1.5 + 1) * moved / R_IN
    np.testing.assert_allclose(a.direction, b.direction, rtol=0, atol=turn)
    np.testing.assert_array_less(np.linalg.norm(a.point - b.point, axis=1), 30 * turn + moved)


def test_a_core_of_the_glass_ior_is_the_solid_sphere():
    nested = _tracer(_water_glass(core_ior=1.5))
    solid = _tracer(GlassObject(mesh=_ball(R_OUT), ior=1.5, placed=True))
    d = _rays(0.4)
    a, b = nested.trace(np.zeros_like(d), d), solid.trace(np.zeros_like(d), d)
    _compare(a, b, 2, nested.eps)
    np.testing.assert_allclose(a.path_length, b.path_length, atol=4 * nested.eps)
    assert (a.bounces == b.bounces + 2).all()  # the core's two surfaces, met with eta = 1


def test_an_air_core_is_a_hollow_shell():
    """A core of IOR 1 inside the glass against one material whose surface is the outer sphere and
    the inner one turned inside out (a hollow ball): the same interfaces and IORs."""
    nested = _tracer(_water_glass(core_ior=1.0))
    inner = _ball(R_IN)
    inner.invert()
    hollow = _tracer(GlassObject(mesh=trimesh.util.concatenate([_ball(R_OUT), inner]), ior=1.5, placed=True))
    d = _rays(0.45)
    a, b = nested.trace(np.zeros_like(d), d), hollow.trace(np.zeros_like(d), d)
    assert (a.bounces > 2).any()  # some rays cross the cavity
    _compare(a, b, 0, nested.eps)
    assert np.array_equal(a.bounces, b.bounces)


def test_a_shell_of_lower_priority_is_no_interface():
    """Water (priority 0) inside glass (priority 1): inside the glass the water's surface changes
    nothing, rays go straight through it; the object is the solid glass sphere."""
    nested = _tracer(_water_glass(core_priority=0, glass_priority=1))
    solid = _tracer(GlassObject(mesh=_ball(R_OUT), ior=1.5, placed=True))
    d = _rays(0.4)
    a, b = nested.trace(np.zeros_like(d), d), solid.trace(np.zeros_like(d), d)
    _compare(a, b, 2, nested.eps)


def test_optical_depth_sums_each_medium():
    """Through the centre: 2 (R_out - R_in) of glass and 2 R_in of water, each times its own
    absorption; the meshes' faces lie up to their sag inside the spheres (four surfaces)."""
    sg, sw = np.array([2.0, 0.5, 0.0]), np.array([0.1, 1.0, 3.0])
    obj = _water_glass(absorption=(tuple(sg), tuple(sw)))
    tr = _tracer(obj)
    res = tr.trace(np.zeros((1, 3)), CENTRE[None] / 3.0)
    sag = R_OUT * (1 - np.cos(np.radians(63.43 / 2**5)))  # a generous bound on both meshes' sag
    expected = 2 * (R_OUT - R_IN) * sg + 2 * R_IN * sw
    np.testing.assert_allclose(res.optical_depth[0], expected, atol=8 * (sag + tr.eps) * max(sg.max(), sw.max()))
    assert res.path_length[0] == pytest.approx(2 * R_OUT, abs=8 * (sag + tr.eps))


def test_nested_needs_a_medium_per_face_and_its_own_material_is_the_first_shells():
    obj = _water_glass()
    assert obj.ior == 1.5 and len(obj.face_medium) == len(obj.faces)
    other = obj.with_ior(1.6).with_absorption((1.0, 2.0, 3.0))
    assert other.ior == 1.6 and other.media[0].ior == 1.6 and other.media[0].absorption == (1.0, 2.0, 3.0)
    assert other.media[1] == obj.media[1] and other.content_hash() != obj.content_hash()
    with pytest.raises(ValueError, match="face_medium"):
        GlassObject(mesh=_ball(R_OUT), media=(Medium(1.5),), placed=True)


def test_max_bounces_counts_interfaces_not_false_ones():
    """A core of lower priority than the glass adds two false interfaces on the axis: with
    ``max_bounces=2`` the axial ray still crosses the sphere's two interfaces and is not trapped."""
    obj = _water_glass(core_priority=0, glass_priority=1)
    axis = (np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
    res = _tracer(obj, max_bounces=2).trace(*axis)
    assert res.kind[0] == HitKind.OBSERVED and res.bounces[0] == 2
    assert _tracer(obj, max_bounces=1).trace(*axis).kind[0] == HitKind.TRAPPED


def test_interface_transmission_of_a_sphere_is_one_minus_its_entry_fresnel():
    """A ray straight through a sphere leaves at the angle it entered (the chord is symmetric), so by
    reciprocity the exit keeps ``1 - R`` of the entry's Fresnel reflectance R: the trace's
    ``interface_transmission`` against its own ``fresnel``, through one medium and through a core of
    the glass's IOR (an interface of equal IORs reflects nothing)."""
    import torch

    from snell_bench.optics.functional import fresnel_cos

    cos = torch.linspace(0.4, 1.0, 601, dtype=torch.float64)
    slope = float(torch.diff(fresnel_cos(cos, 1.0, 1.5)).abs().max() / (cos[1] - cos[0]))
    err = _normal_error(GlassObject(mesh=_ball(R_OUT), placed=True), CENTRE)
    for obj in (GlassObject(mesh=_ball(R_OUT), ior=1.5, placed=True), _water_glass(core_ior=1.5)):
        res = _tracer(obj).trace(np.zeros((144, 3)), _rays(0.45))  # sin(incidence) <= 0.9: cos >= 0.43
        through = res.kind == HitKind.OBSERVED
        assert through.sum() > 100 and (res.interface_transmission[~through] <= 1).all()
        # entry and exit normals each off radial by <= err: the two angles differ by a few err
        np.testing.assert_allclose(
            res.interface_transmission[through], 1.0 - res.fresnel[through], atol=8 * err * slope
        )


def test_warps_of_a_glass_of_water_carry_each_media_absorption():
    """The warps' transmittance of a nested object is exp(-optical depth) of each pixel's path, each
    medium with its own absorption."""
    from snell_bench.optics import compute_warps

    sg, sw = (1.0, 0.2, 0.0), (0.0, 0.5, 2.0)
    obj = _water_glass(absorption=(sg, sw))
    cam = Camera.from_fov(48, 36, 30.0)
    ws = compute_warps(np.full(cam.shape, 8.0), cam, obj, pano_height=8)
    m = ws.object_mask
    assert ws.absorbs and (ws.optical_depth[~m] == 0).all()
    np.testing.assert_allclose(ws.transmittance(), np.exp(-ws.optical_depth.astype(np.float64)), rtol=1e-6)
    # per pixel the optical depth lies between the path length times the smaller and the larger sigma
    lo, hi = np.minimum(sg, sw), np.maximum(sg, sw)
    L = ws.path_length[m][:, None].astype(np.float64)
    assert (ws.optical_depth[m] >= L * lo - 1e-6).all() and (ws.optical_depth[m] <= L * hi + 1e-6).all()


def test_interfaces_of_nested_overlapping_and_separate_shells():
    """Each face's two media: nested balls, a ball beside another (now allowed: each is air outside),
    a core of lower priority (no interface), and refusals of a face that crosses another shell's
    surface and of two shells sharing a surface."""
    from snell_bench.optics.media import interface_faces

    def pairs(obj):  # (shell, medium behind, medium in front) of every face
        behind, front = interface_faces(obj)
        return sorted({(int(k), int(b), int(f)) for k, b, f in zip(obj.face_medium, behind, front)})

    assert pairs(_water_glass()) == [(0, 0, -1), (1, 1, 0)]  # glass|air, water|glass
    assert pairs(_water_glass(core_priority=0, glass_priority=1)) == [(0, 0, -1), (1, 0, 0)]  # no water surface
    beside = _ball(R_IN)
    beside.apply_translation([2.0, 0.0, 0.0])
    obj = GlassObject.nested([(_ball(R_OUT), Medium(1.5)), (beside, Medium(1.333, priority=1))], placed=True)
    assert pairs(obj) == [(0, 0, -1), (1, 1, -1)]
    crossing = _ball(R_IN)
    crossing.apply_translation([R_OUT, 0.0, 0.0])  # half in, half out: its faces cross the ball's surface
    obj = GlassObject.nested([(_ball(R_OUT), Medium(1.5)), (crossing, Medium(1.333, priority=1))], placed=True)
    with pytest.raises(ValueError, match="crosses the surface of shell"):
        interface_faces(obj)
    obj = GlassObject.nested([(_ball(R_OUT), Medium(1.5)), (_ball(R_OUT), Medium(1.333, priority=1))], placed=True)
    with pytest.raises(ValueError, match="lies on the surface of shell"):
        interface_faces(obj)
