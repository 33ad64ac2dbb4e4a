"""Support-plane detection (Open3D RANSAC) and object placement."""

import dataclasses
import math

import numpy as np
import pytest

from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import SupportPlane, find_support_plane, place_object


def ray_plane_depth(cam, normal, offset):
    """z-depth of the plane ``normal . x = offset`` (inf where the ray misses it)."""
    d = cam.pixel_rays(normalize=False)
    with np.errstate(divide="ignore"):
        t = offset / (d @ normal)
    return np.where(t > 0, t, np.inf)


def table_scene(cam, pitch_deg=15.0):
    """A level floor 0.8 m below the camera and a wall 6 m ahead, the camera pitched down."""
    a = math.radians(pitch_deg)
    up = np.array([0.0, -math.cos(a), -math.sin(a)])  # world up in the pitched camera's frame
    fwd_h = np.array([0.0, -math.sin(a), math.cos(a)])  # horizontal forward
    floor = ray_plane_depth(cam, -up, 0.8)
    wall = ray_plane_depth(cam, fwd_h, 6.0)
    return np.minimum(floor, wall), up


def test_finds_level_floor_of_a_pitched_camera():
    cam = Camera.from_fov(160, 120, 70)
    depth, up = table_scene(cam)
    plane = find_support_plane(depth, cam)
    assert plane.normal @ up > math.cos(math.radians(0.5))
    assert (plane.point @ up) == pytest.approx(-0.8, abs=2e-3)
    x, y = plane.pixel
    assert y > cam.height / 2  # below the horizon


def test_no_horizontal_surface_is_a_clear_error():
    cam = Camera.from_fov(64, 48, 60)
    wall = np.full(cam.shape, 3.0)
    with pytest.raises(ValueError, match="no horizontal supporting surface"):
        find_support_plane(wall, cam)


def test_place_object_stands_on_the_plane():
    cam = Camera.from_fov(160, 120, 70)
    depth, up = table_scene(cam)
    obj = place_object(GlassObject.sphere(subdivisions=3), depth, cam, size=0.4)
    heights = obj.vertices @ obj.up
    plane = find_support_plane(depth, cam)
    bottom = heights.min() - plane.point @ plane.normal
    assert bottom == pytest.approx(1e-3 * 0.4, abs=1e-6)  # the lift
    assert np.ptp(heights) == pytest.approx(0.4, rel=1e-6)
    assert np.all(obj.vertices[:, 2] > 0) and obj.placed
    with pytest.raises(ValueError, match="already placed"):
        place_object(obj, depth, cam)
    with pytest.raises(ValueError, match="size"):
        place_object(GlassObject.sphere(subdivisions=1), depth, cam, size=-1.0)


def test_deterministic():
    """The same seed gives the same plane (every field) and the same placed object, bit for bit."""
    cam = Camera.from_fov(160, 120, 70)
    depth, _ = table_scene(cam)
    a, b = find_support_plane(depth, cam, seed=3), find_support_plane(depth, cam, seed=3)
    for f in dataclasses.fields(SupportPlane):
        assert np.array_equal(getattr(a, f.name), getattr(b, f.name)), f.name
    oa = place_object(GlassObject.sphere(subdivisions=2), depth, cam, seed=3, yaw_deg=20.0)
    ob = place_object(GlassObject.sphere(subdivisions=2), depth, cam, seed=3, yaw_deg=20.0)
    assert oa.placed and ob.placed
    for f in dataclasses.fields(GlassObject):
        if f.name == "mesh":
            assert np.array_equal(oa.mesh.vertices, ob.mesh.vertices)
            assert np.array_equal(oa.mesh.faces, ob.mesh.faces)
        elif f.compare:
            assert np.array_equal(getattr(oa, f.name), getattr(ob, f.name)), f.name
    np.testing.assert_allclose(oa.up, a.normal, atol=1e-12)  # up is the (re-normalised) plane normal
    assert np.array_equal(oa.corner_normals(), ob.corner_normals())
    assert oa.content_hash() == ob.content_hash()


def test_ransac_runs_every_iteration_so_the_plane_does_not_depend_on_thread_timing(monkeypatch):
    """Open3D's early stop inside its parallel RANSAC loop made the same seed give different planes
    within one process; the placement asks for every iteration (probability 1)."""
    import open3d as o3d

    from snell_bench.scene.camera import Camera
    from snell_bench.scene.placement import find_support_plane

    seen = []
    orig = o3d.geometry.PointCloud.segment_plane

    def spy(self, *args, **kwargs):
        seen.append(kwargs.get("probability"))
        return orig(self, *args, **kwargs)

    monkeypatch.setattr(o3d.geometry.PointCloud, "segment_plane", spy)
    cam = Camera.from_fov(64, 48, 60.0)
    ys = np.arange(48)[:, None] - cam.K[1, 2] + 0.5
    depth = np.where(ys > 0, cam.K[1, 1] * 1.0 / np.maximum(ys, 1e-3), 50.0) * np.ones((1, 64))  # a floor 1 below
    find_support_plane(np.minimum(depth, 50.0), cam, seed=0)
    assert seen and all(p == 1.0 for p in seen)
