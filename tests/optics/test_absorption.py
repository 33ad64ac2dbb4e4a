"""Absorption (Beer–Lambert): the path length the tracer sums inside the glass against closed forms
(a sphere's chord, a long box whose walls reflect totally), the warps' transmittance, the tint of the
refracted colour, and the config that sets it."""

import math

import numpy as np
import pytest
import torch
import trimesh

from snell_bench.config import compose
from snell_bench.config.errors import ConfigError
from snell_bench.config.materials import absorption_coefficients, absorption_problem
from snell_bench.imaging.blend import absorb
from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear
from snell_bench.optics import HitKind, WarpSet, compute_warps
from snell_bench.optics.tracer import SceneTracer
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import build_background
from snell_bench.scene.objects import GlassObject

N_GLASS = 1.5
U32 = 2.0**-24  # float32 unit roundoff (Open3D casts float32 rays)


def _sphere(subdivisions: int, z: float = 3.0, **kw) -> GlassObject:
    T = np.eye(4)
    T[:3, 3] = [0.0, -0.5, z]  # the unit-diameter sphere (bottom at the origin) centred at (0, 0, z)
    return GlassObject.sphere(ior=N_GLASS, subdivisions=subdivisions, **kw).transformed(T)


def _tracer(obj: GlassObject, depth: float = 30.0, **kw) -> SceneTracer:
    cam = Camera.from_fov(16, 12, 90.0)
    return SceneTracer(build_background(np.full(cam.shape, depth), cam), obj, **kw)


def _sag(obj: GlassObject, center: np.ndarray, radius: float) -> float:
    """How far inside the sphere the mesh's faces lie at most: ``R`` minus the smallest distance from
    the centre to a face's plane (the vertices lie on the sphere)."""
    v = obj.vertices[obj.faces] - center  # (F, 3, 3)
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return radius - float(np.abs(np.einsum("ij,ij->i", n, v[:, 0])).min())


def _normal_error(obj: GlassObject, center: np.ndarray) -> float:
    """The largest angle (radians) between a corner's shading normal and the radial direction there
    (the corner normals average the faces around a vertex: close to radial, not exactly)."""
    cn = obj.corner_normals()
    r = obj.vertices[obj.faces] - center
    r /= np.linalg.norm(r, axis=-1, keepdims=True)
    return float(np.arccos(np.clip((cn * r).sum(-1), -1.0, 1.0)).max())


def test_sphere_chord_matches_the_closed_form():
    """A ray at impact parameter ``b`` crosses a sphere of radius ``R`` along the chord
    ``L = 2R sqrt(1 - b^2 / (n^2 R^2))`` (first pass; no total reflection inside a sphere).

    Tolerance from the mesh: its faces lie up to ``delta`` (the sag) inside the sphere, so the entry
    and exit points move by at most ``delta / cos(theta_i)`` and ``delta / cos(theta_t)`` along the
    ray; the shading normal there is off the true one by the corner normals' error ``gamma``
    (measured) plus ``delta tan(theta_i) / R`` (the point is elsewhere on the sphere), which turns
    the refracted ray by that times ``cos(theta_i) / (n cos(theta_t))`` and the chord by
    ``2R sin(theta_t)`` times that. Each segment starts ``eps`` off the surface, and float32 ray
    casting at 3 m adds a few ulps; a factor 2 of margin on the sum."""
    R, center = 0.5, np.array([0.0, 0.0, 3.0])
    obj = _sphere(6)
    tr = _tracer(obj)
    delta, gamma = _sag(obj, center, R), _normal_error(obj, center)
    b = np.linspace(0.0, 0.8 * R, 25)
    az = np.linspace(0.0, 2 * np.pi, 25, endpoint=False)  # every azimuth, so every face orientation
    alpha = np.arcsin(b / np.linalg.norm(center))
    d = np.stack([np.sin(alpha) * np.cos(az), np.sin(alpha) * np.sin(az), np.cos(alpha)], axis=1)
    res = tr.trace(np.zeros_like(d), d)
    assert (res.kind == HitKind.OBSERVED).all() and (res.bounces == 2).all()
    sin_i = b / R
    cos_i, sin_t = np.sqrt(1 - sin_i**2), sin_i / N_GLASS
    cos_t = np.sqrt(1 - sin_t**2)
    exact = 2 * R * cos_t
    turn = (gamma + delta * sin_i / (R * cos_i)) * cos_i / (N_GLASS * cos_t)
    bound = 2 * (delta / cos_i + delta / cos_t + 2 * R * sin_t * turn + 2 * tr.eps + 64 * U32 * np.linalg.norm(center))
    err = np.abs(res.path_length - exact)
    assert (err <= bound).all(), (err.max(), bound.min())
    assert err.max() < 0.01 * R  # and the bound is not vacuous


def test_total_reflections_inside_a_long_box_keep_the_axial_length():
    """A box whose front and back faces are normal to the view axis: a ray refracts in at
    ``theta_t`` to the axis, reflects totally off the side walls (incidence ``90° - theta_t`` above
    the critical angle) without changing its axial component, and leaves through the back face: its
    length inside is ``D / cos(theta_t)`` whatever the number of reflections. Flat faces: exact up
    to the ``eps`` offsets and float32 casting."""
    depth, half = 10.0, 1.0
    box = trimesh.creation.box(extents=[2 * half, 2 * half, depth])
    box.apply_translation([0.0, 0.0, 3.0 + depth / 2])
    obj = GlassObject(mesh=box, ior=N_GLASS, name="box", placed=True)
    tr = _tracer(obj, depth=40.0, max_bounces=32)
    alpha = np.radians(np.linspace(2.0, 16.0, 8))
    az = np.radians(np.linspace(0.0, 80.0, 8))
    d = np.stack([np.sin(alpha) * np.cos(az), np.sin(alpha) * np.sin(az), np.cos(alpha)], axis=1)
    res = tr.trace(np.zeros_like(d), d)
    assert (res.kind != HitKind.TRAPPED).all() and res.bounces.max() > 2  # reflections happened
    cos_t = np.sqrt(1 - (np.sin(alpha) / N_GLASS) ** 2)
    bound = 2 * (res.bounces * tr.eps + 64 * U32 * (3.0 + depth) * res.bounces)
    np.testing.assert_array_less(np.abs(res.path_length - depth / cos_t), bound)


def test_warps_carry_the_path_length_and_the_transmittance():
    cam = Camera.from_fov(48, 36, 50.0)
    sigma = absorption_coefficients([0.4, 0.7, 0.9], 1.0)  # per metre: the colour after 1 m
    obj = _sphere(4).with_absorption(sigma)
    ws = compute_warps(np.full(cam.shape, 6.0), cam, obj, pano_height=8)
    m = ws.object_mask
    assert (ws.path_length[~m] == 0).all() and (ws.path_length[m] > 0).all()
    T = ws.transmittance()
    np.testing.assert_allclose(T, np.exp(-ws.path_length[..., None].astype(np.float64) * sigma), rtol=1e-6)
    assert (T[~m] == 1).all()
    centre = np.unravel_index(np.argmax(np.where(m, ws.path_length, 0)), m.shape)
    assert abs(ws.path_length[centre] - 1.0) < 0.01  # the diameter, through the middle
    clear = compute_warps(np.full(cam.shape, 6.0), cam, _sphere(4), pano_height=8)
    assert not clear.absorbs and (clear.transmittance() == 1).all()
    np.testing.assert_array_equal(clear.path_length, ws.path_length)  # geometry alone
    assert clear.input_hash != ws.input_hash  # a cache entry is the material's too


def test_warps_round_trip_keeps_the_absorption(tmp_path):
    cam = Camera.from_fov(24, 18, 50.0)
    obj = _sphere(2).with_absorption((1.0, 0.5, 0.0))
    ws = compute_warps(np.full(cam.shape, 6.0), cam, obj, pano_height=8)
    back = WarpSet.load(ws.save(tmp_path / "w.npz"))
    assert back.absorption == (1.0, 0.5, 0.0)
    np.testing.assert_array_equal(back.path_length, ws.path_length)


def test_absorb_tints_in_linear_rgb_and_keeps_clear_pixels_bit_for_bit():
    g = torch.Generator().manual_seed(0)
    refr = torch.rand(1, 3, 5, 7, generator=g)
    T = np.ones((5, 7, 3), np.float32)
    T[1:4, 2:5] = [0.25, 0.5, 1.0]
    out = absorb(refr, T)
    expected = linear_to_srgb(srgb_to_linear(refr) * torch.from_numpy(T).permute(2, 0, 1)[None])
    torch.testing.assert_close(out, expected)
    keep = torch.from_numpy((T == 1).all(-1))
    assert torch.equal(out[..., keep], refr[..., keep])


# ---------------------------------------------------------------------------- config
def test_a_colour_at_a_thickness_is_sigma():
    sigma = absorption_coefficients([0.5, 0.25, 1.0], 0.2)
    assert sigma == pytest.approx((math.log(2) / 0.2, math.log(4) / 0.2, 0.0))
    assert math.exp(-sigma[0] * 0.2) == pytest.approx(0.5)


@pytest.mark.parametrize(
    ("color", "distance", "match"),
    [
        ([0.0, 0.5, 0.5], 0.1, "object.absorption.color"),
        ([0.5, 0.5], 0.1, "object.absorption.color"),
        ([0.5, 1.2, 0.5], 0.1, "object.absorption.color"),
        ([0.5, 0.5, 0.5], 0.0, "object.absorption.distance"),
        ([0.5, 0.5, 0.5], float("nan"), "object.absorption.distance"),
    ],
)
def test_bad_absorption_names_the_key(color, distance, match):
    assert match in absorption_problem(color, distance)
    with pytest.raises(ValueError, match=match):
        absorption_coefficients(color, distance)


def test_the_config_builds_a_tinted_object():
    from omegaconf import OmegaConf

    from snell_bench.config.checks import check_config
    from snell_bench.pipeline.inputs import build_object

    cfg = compose(["object.absorption.color=[0.5,0.8,1.0]", "object.absorption.distance=0.05"])
    obj = build_object(cfg.object)
    assert obj.absorption == pytest.approx(absorption_coefficients([0.5, 0.8, 1.0], 0.05))
    clear = build_object(compose([]).object)
    assert clear.absorption == (0.0, 0.0, 0.0) and not clear.absorbs
    bad = compose(["object.absorption.color=[0.5,0.8,0]"])
    with pytest.raises(ConfigError, match=r"object.absorption.color=\[0.5, 0.8, 0\]"):
        check_config(bad)
    assert OmegaConf.select(compose([]), "object.absorption.color") == [1.0, 1.0, 1.0]


def test_the_cycles_reference_refuses_a_tinted_object_before_any_work():
    from snell_bench.config.checks import check_config

    with pytest.raises(ConfigError, match=r"object.absorption.color=\[0.55, 0.8, 0.95\]: the Cycles reference"):
        check_config(compose(["object=tinted_sphere", "reference.renderer=cycles"]))
    check_config(compose(["object=tinted_sphere", "reference.renderer=cycles", "reference.enabled=false"]))
