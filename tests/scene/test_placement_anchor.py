"""The ``centre_ray`` anchor (the authors' placement) on hand-made depth maps with closed-form answers."""

import math

import numpy as np
import pytest
from omegaconf import OmegaConf

from snell_bench.models.segment import SurfaceMask
from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import (
    CENTRE_RAY_LIFT,
    anchor_pixel,
    centre_ray_support,
    centre_ray_transform,
    place_object,
)
from snell_bench.scene.sources import SceneInputs

UP = np.array([0.0, -1.0, 0.0])
#: a segmented box low in the 160 x 140 image, on the floor: its centre is pixel (79.5, 114.5)
LOW = SurfaceMask(np.ones((140, 160), bool), box=(60.0, 100.0, 100.0, 130.0))
#: float32 vertices carry a relative rounding of 2**-24 (6e-8); scene coordinates here are < 4 m,
#: so a hit point recomputed from a float32 triangle is good to ~1e-6 m.
POINT_ATOL = 1e-6
#: the hit triangle's normal from float32 corners ~1 cm apart (a pixel at 1.5 m, f ~ 110 px): an
#: angle error of ~3e-7 m / 1e-2 m = 3e-5 rad.
NORMAL_ATOL = 1e-4


def plane_depth(cam, normal, offset):
    """z-depth of the plane ``normal . x = offset`` seen from the origin (NaN where the ray misses)."""
    d = cam.pixel_rays(normalize=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = offset / (d @ normal)
    return np.where(t > 0, t, np.nan)


def tilted_floor(cam, tilt_deg=12.0, drop=0.9):
    """A floor ``drop`` below the camera whose up normal is turned by ``tilt_deg`` about z."""
    a = math.radians(tilt_deg)
    n_up = np.array([math.sin(a), -math.cos(a), 0.0])  # unit, pointing up
    # points x with n_up . x = -drop lie 'drop' below the camera along n_up
    return plane_depth(cam, n_up, -drop), n_up, -drop


# ---------------------------------------------------------------------------- the pixel
def test_anchor_pixel_is_the_centre_of_the_box():
    cam = Camera.from_fov(40, 30, 60)
    assert np.array_equal(anchor_pixel(None, cam), [19.5, 14.5])  # the optical axis
    region = np.zeros(cam.shape, bool)
    region[10:21, 4:9] = True  # pixels 4..8 x 10..20: edges 4..9 and 10..21
    assert np.array_equal(anchor_pixel(region, cam), [6.0, 15.0])
    # SAM 3's predicted box wins over the mask's own box: X = 12 at the pixel edge is pixel 11.5
    boxed = SurfaceMask(region, box=(10.0, 2.0, 14.0, 8.0))
    assert np.array_equal(anchor_pixel(boxed, cam), [11.5, 4.5])
    with pytest.raises(ValueError, match="segment"):
        anchor_pixel(np.zeros(cam.shape, bool), cam)


# ---------------------------------------------------------------------------- the hit
@pytest.mark.parametrize("pixel", [(80.0, 120.0), (50.0, 110.25), (130.5, 115.0)])
def test_the_ray_meets_a_tilted_plane_where_it_should(pixel):
    cam = Camera.from_fov(160, 140, 70)
    depth, n_up, offset = tilted_floor(cam)
    plane = centre_ray_support(depth, cam, pixel, up_hint=UP)
    d = cam.pixel_rays(np.array(pixel), normalize=False)
    np.testing.assert_allclose(plane.point, d * offset / (n_up @ d), rtol=0, atol=POINT_ATOL)
    np.testing.assert_allclose(plane.normal, n_up, rtol=0, atol=NORMAL_ATOL)
    assert plane.normal @ UP > 0 and np.array_equal(plane.pixel, pixel)


def test_the_ray_meets_the_top_of_a_box_not_the_floor_behind_it():
    """A box 0.4 m tall on a level floor 1 m below the camera: the ray through the centre of its
    top (a region) stops on the top, at height -0.6, with the normal straight up."""
    cam = Camera.from_fov(160, 120, 60)
    floor = plane_depth(cam, UP, -1.0)
    top = plane_depth(cam, UP, -0.6)
    pts = cam.unproject(np.nan_to_num(top))
    on_top = (np.abs(pts[..., 0]) < 0.3) & (pts[..., 2] > 1.8) & (pts[..., 2] < 2.4) & np.isfinite(top)
    depth = np.where(on_top, top, floor)
    region = on_top.copy()
    plane = centre_ray_support(depth, cam, anchor_pixel(region, cam), up_hint=UP)
    assert plane.point @ UP == pytest.approx(-0.6, abs=POINT_ATOL)
    np.testing.assert_allclose(plane.normal, UP, rtol=0, atol=NORMAL_ATOL)
    assert 1.8 < plane.point[2] < 2.4


def test_a_ray_into_a_hole_names_the_keys():
    cam = Camera.from_fov(40, 30, 60)
    depth = plane_depth(cam, UP, -1.0)
    depth[:, 15:25] = np.nan  # the image centre has no depth
    with pytest.raises(ValueError, match="object.anchor=plane"):
        centre_ray_support(depth, cam, anchor_pixel(None, cam), up_hint=UP)


# ---------------------------------------------------------------------------- the pose
def test_the_transform_on_a_level_surface_keeps_the_camera_axes():
    v = GlassObject.pyramid().vertices
    T = centre_ray_transform(v, 0.5, np.array([0.1, 0.8, 2.0]), UP, UP)
    # local x -> camera x, local y (up) -> -y, local z -> -z (towards the camera)
    np.testing.assert_allclose(T[:3, :3], 0.5 * np.diag([1.0, -1.0, -1.0]), rtol=0, atol=1e-15)
    bottom = v[v[:, 1] == v[:, 1].min()].mean(axis=0)
    np.testing.assert_allclose(T[:3, :3] @ bottom + T[:3, 3], [0.1, 0.8 - CENTRE_RAY_LIFT, 2.0], atol=1e-12)


@pytest.mark.parametrize("tilt_deg", [0.0, 12.0])
def test_a_sphere_turns_about_its_centre_and_rises_5_mm(tilt_deg):
    """The authors turn the object about the mean of its vertices, so a sphere's centre stays at the
    hit point + (radius + 5 mm) along up whatever the tilt; its bottom vertex goes to centre - r n."""
    cam = Camera.from_fov(160, 140, 70)
    depth, n_up, _ = tilted_floor(cam, tilt_deg)
    sphere = GlassObject.sphere(subdivisions=3)
    size = 0.3
    placed = place_object(sphere, depth, cam, size=size, anchor="centre_ray", region=LOW)
    hit = centre_ray_support(depth, cam, (79.5, 114.5), up_hint=UP)
    centre = hit.point + (size / 2 + CENTRE_RAY_LIFT) * UP
    # the icosphere's vertex mean is its centre up to rounding (its vertices pair up as +-v)
    np.testing.assert_allclose(placed.vertices.mean(axis=0), centre, rtol=0, atol=1e-9)
    i = np.argmin(sphere.vertices[:, 1])
    np.testing.assert_allclose(placed.vertices[i], centre - size / 2 * hit.normal, rtol=0, atol=1e-9)
    np.testing.assert_allclose(placed.up, hit.normal, rtol=0, atol=1e-12)
    np.testing.assert_allclose(hit.normal, n_up, rtol=0, atol=NORMAL_ATOL)


def test_a_pyramid_on_a_tilted_surface_lies_flat_on_it_but_off_the_hit_point():
    """The base (the lowest vertices) ends up perpendicular to the normal, at the vertex mean minus
    its height along the normal: 2 h sin(tilt / 2) away from the hit point, plus 5 mm up."""
    cam = Camera.from_fov(160, 140, 70)
    depth, n_up, _ = tilted_floor(cam, 20.0)
    pyr = GlassObject.pyramid()
    v = pyr.vertices
    size = 0.4
    placed = place_object(pyr, depth, cam, size=size, anchor="centre_ray", region=LOW)
    hit = centre_ray_support(depth, cam, (79.5, 114.5), up_hint=UP)
    base = v[:, 1] == v[:, 1].min()
    h = size * (v[:, 1].mean() - v[base, 1].mean())
    heights = placed.vertices[base] @ hit.normal
    assert np.ptp(heights) < 1e-12  # the base lies in a plane perpendicular to the normal
    mean = hit.point + (h + CENTRE_RAY_LIFT) * UP
    np.testing.assert_allclose(placed.vertices.mean(axis=0), mean, rtol=0, atol=1e-9)
    base_centre = placed.vertices[base].mean(axis=0)
    np.testing.assert_allclose(base_centre, mean - h * hit.normal, rtol=0, atol=1e-9)
    tilt = math.acos(float(hit.normal @ UP))
    off = base_centre - CENTRE_RAY_LIFT * UP - hit.point
    assert np.linalg.norm(off) == pytest.approx(2 * h * math.sin(tilt / 2), rel=1e-9)


def test_the_plane_anchor_is_unchanged_and_unknown_anchors_are_refused():
    cam = Camera.from_fov(160, 140, 70)
    depth, _, _ = tilted_floor(cam, 0.0)
    a = place_object(GlassObject.sphere(subdivisions=2), depth, cam, size=0.3)
    b = place_object(GlassObject.sphere(subdivisions=2), depth, cam, size=0.3, anchor="plane")
    assert np.array_equal(a.vertices, b.vertices)
    with pytest.raises(ValueError, match="object.anchor='middle'"):
        place_object(GlassObject.sphere(subdivisions=1), depth, cam, anchor="middle")


def test_the_pipeline_places_by_object_anchor_inside_the_region():
    from snell_bench.pipeline.inputs import place

    cam = Camera.from_fov(160, 120, 60)
    depth = plane_depth(cam, UP, -1.0).astype(np.float32)
    scene = SceneInputs(image=np.zeros((*cam.shape, 3), np.float32), depth=depth, camera=cam, up=None, source=None)
    cfg = OmegaConf.create(
        dict(name="sphere", size=0.2, relative_size=0.25, yaw_deg=0.0, max_tilt_deg=30.0, anchor="centre_ray")
    )
    region = SurfaceMask(np.ones(cam.shape, bool), box=(100.0, 80.0, 140.0, 120.0))  # centre pixel (119.5, 99.5)
    obj = place(GlassObject.sphere(subdivisions=2), scene, cfg, region=region)
    d = cam.pixel_rays(np.array([119.5, 99.5]), normalize=False)
    hit = d * -1.0 / (UP @ d)
    np.testing.assert_allclose(obj.vertices.mean(axis=0), hit + (0.1 + CENTRE_RAY_LIFT) * UP, rtol=0, atol=POINT_ATOL)


def test_object_anchor_is_checked_by_the_schema():
    from snell_bench.config.errors import ConfigError
    from snell_bench.config.schema import ObjectConfig

    assert ObjectConfig().anchor == "plane"
    with pytest.raises(ConfigError, match="object.anchor='centre'"):
        ObjectConfig(anchor="centre")


def test_without_a_region_the_ray_aims_at_the_fitted_plane():
    """The image centre of a level camera sees the horizon: the ray goes through the pixel where
    the RANSAC plane's centre is seen instead, so the hit is that centre (on the same plane)."""
    from snell_bench.scene.placement import find_support_plane

    cam = Camera.from_fov(160, 140, 70)
    depth, n_up, offset = tilted_floor(cam, 0.0)
    plane = find_support_plane(depth, cam, seed=0)
    placed = place_object(GlassObject.sphere(subdivisions=3), depth, cam, size=0.3, anchor="centre_ray", seed=0)
    hit = centre_ray_support(depth, cam, plane.pixel, up_hint=UP)
    np.testing.assert_allclose(hit.point, plane.point, rtol=0, atol=POINT_ATOL)
    np.testing.assert_allclose(placed.vertices.mean(axis=0), hit.point + (0.15 + CENTRE_RAY_LIFT) * UP, atol=1e-9)
