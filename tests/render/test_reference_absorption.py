"""The Mitsuba reference of a tinted glass (an absorbing interior medium, ``volpathmis``): the centre of a
sphere against the closed-form series of its internal reflections, and a tinted sphere against the
warps' Fresnel combination with their transmittance."""

import math

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")

from render_testing import forced_cpu_variant, make_room, metric_pixels, psnr, warp  # noqa: E402

from snell_bench.config.materials import absorption_coefficients  # noqa: E402
from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear  # noqa: E402
from snell_bench.optics import compute_warps  # noqa: E402
from snell_bench.render.reference import ReferenceSettings, render_reference  # noqa: E402
from snell_bench.scene.camera import Camera  # noqa: E402
from snell_bench.scene.objects import GlassObject  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def cpu_variant():
    with forced_cpu_variant():
        yield


def test_sphere_centre_is_the_series_of_its_internal_reflections():
    """On the axis of a sphere (IOR n, diameter D, grey transmittance ``T = exp(-sigma D)``) in front
    of a uniform emitting plane ``L``, with black behind the camera: the light that reaches the
    camera went through the front face, crossed ``2k + 1`` times and left through the back, so the
    pixel is ``(1 - R)^2 T / (1 - R^2 T^2) L`` with ``R = ((n - 1) / (n + 1))^2`` (the front
    reflection and every path that leaves towards the camera see black).

    Tolerance: with albedo 0 and one sigma for all channels every sample is ``L`` or 0, so the
    mean of ``N`` independent samples has standard deviation ``L sqrt(p (1 - p) / N)``; four of
    them, plus the spread of the path length over the 3 x 3 central pixels (``b / R <= 0.2``:
    ``L`` changes by at most ``1 - sqrt(1 - 0.2^2 / n^2) < 0.9 %``, so ``T`` by ``sigma D`` times that)."""
    n, spp = 1.5, 4096
    cam = Camera.from_fov(33, 33, 30.0)
    T = np.eye(4)
    T[:3, 3] = [0.0, -0.5, 3.0]
    T_grey = 0.5
    obj = GlassObject.sphere(ior=n, subdivisions=5).transformed(T).with_absorption((-math.log(T_grey),) * 3)
    image = np.full((33, 33, 3), 0.6, np.float32)
    settings = ReferenceSettings(spp=spp, sampler="independent", self_noise=False, seed=1)
    ref = render_reference(image, np.full(cam.shape, 6.0, np.float32), cam, obj, settings)
    L = float(srgb_to_linear(np.float64(0.6)))
    got = srgb_to_linear(ref.image[15:18, 15:18].astype(np.float64)).mean() / L
    R = ((n - 1) / (n + 1)) ** 2
    p = (1 - R) ** 2 * T_grey / (1 - R**2 * T_grey**2)
    tol = 4 * math.sqrt(p * (1 - p) / (9 * spp)) + p * (-math.log(T_grey)) * 0.009
    assert abs(got - p) < tol, (got, p, tol)
    assert abs((1 - R) * T_grey - p) > tol  # the series is told apart from a single pass


def _warps_combination(image: np.ndarray, ws, interfaces: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``R π^-R + (1 - R) T π^R`` of I⁻ in linear RGB (sRGB out), and the same without ``T``;
    ``interfaces``: ``T`` also holds the Fresnel transmission of the path's later interfaces."""
    lin = srgb_to_linear(image)
    refl = warp(lin, np.where(ws.reflection_valid[..., None], ws.reflection, np.nan))
    F, refr = ws.fresnel[..., None], warp(lin, ws.refraction)
    T = ws.transmittance() * (ws.interface_transmission[..., None] if interfaces else 1.0)
    return linear_to_srgb(F * refl + (1 - F) * T * refr), linear_to_srgb(F * refl + (1 - F) * refr)


def test_tinted_sphere_matches_the_warps_transmittance():
    """Mitsuba's dielectric filled with the medium against ``R π^-R + (1 - R) T π^R`` in linear RGB,
    ``T`` the warps' ``exp(-sigma L)``: at least 30 dB inside the metric mask (clear: the same test
    with ``T = 1`` in test_reference.py)."""
    room = make_room()
    sigma = absorption_coefficients([0.4, 0.7, 0.9], room.obj.diameter)
    obj = room.obj.with_absorption(sigma)
    ws = compute_warps(room.depth, room.camera, obj, pano_height=16)
    ref = render_reference(room.image, room.depth, room.camera, obj, ReferenceSettings(spp=50, seed=0))
    expected, untinted = _warps_combination(room.image, ws)
    m = metric_pixels(ref, ws)
    assert m.sum() > 500
    assert psnr(ref.image, expected, m) >= 30
    assert psnr(ref.image, untinted, m) < 25  # the tint is what the reference shows


def test_a_glass_ball_of_tinted_water_matches_the_warps():
    """A glass sphere filled with tinted water to 0.85 of its radius (a glass of water's thin wall; two
    media, one Mitsuba surface per interface with the IORs and media of its two sides) against the
    warps' R π^-R + (1 - R) T π^R, T from each medium's absorption along the traced path: at least
    30 dB inside the metric mask, as the tinted sphere; the untinted combination is far. (A thick
    wall, a core of 0.6, scores 27 dB: rays meet the water near the glass-water critical angle,
    where Mitsuba splits them by Fresnel and the warps follow the refracted path alone.)"""
    from snell_bench.config.materials import Medium

    room = make_room()
    core = room.obj.mesh.copy()
    c = room.obj.center
    core.apply_translation(-c)
    core.apply_scale(0.85)
    core.apply_translation(c)
    sigma = absorption_coefficients([0.5, 0.75, 0.9], 0.85 * room.obj.diameter)
    obj = GlassObject.nested([(room.obj, Medium(1.5)), (core, Medium(1.333, sigma, priority=1))])
    ws = compute_warps(room.depth, room.camera, obj, pano_height=16)
    ref = render_reference(room.image, room.depth, room.camera, obj, ReferenceSettings(spp=50, seed=0))
    expected, untinted = _warps_combination(room.image, ws)
    m = metric_pixels(ref, ws)
    assert m.sum() > 500 and ws.absorbs
    assert psnr(ref.image, expected, m) >= 30
    assert psnr(ref.image, untinted, m) < 30


def test_a_tumbler_of_tinted_water_with_a_straw_matches_the_warps():
    """The config's glass of water (a tumbler, tinted water, a straw: glass, water, straw and air meet,
    one Mitsuba surface per pair of media that meet) against the warps' combination with each
    medium's absorption and the Fresnel transmission of the path's later interfaces: at least 30 dB
    inside the metric mask. Without that transmission the warps keep light that Mitsuba reflects away
    at the glass's floor and base, near their critical angle; without the tint, far below. The glass
    stands 1 % of its size above the table (a flat base on the depth mesh: see docs/materials.md)."""
    from snell_bench.scene.placement import place_object
    from snell_bench.scene.vessels import glass_of_water

    room = make_room()
    tinted = glass_of_water(straw=True, sections=96, water_absorption={"color": [0.5, 0.75, 0.9], "distance": 0.2})
    obj = place_object(tinted, room.depth, room.camera, lift=0.01)
    ws = compute_warps(room.depth, room.camera, obj, pano_height=16, max_bounces=16)
    ref = render_reference(room.image, room.depth, room.camera, obj, ReferenceSettings(spp=50, seed=0))
    expected, untinted = _warps_combination(room.image, ws, interfaces=True)
    paper, _ = _warps_combination(room.image, ws)
    m = metric_pixels(ref, ws)
    assert m.sum() > 300 and ws.absorbs
    assert psnr(ref.image, expected, m) >= 30
    assert psnr(ref.image, expected, m) > psnr(ref.image, paper, m) + 1
    assert psnr(ref.image, untinted, m) < 25
