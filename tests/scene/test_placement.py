"""Support-plane detection (Open3D RANSAC) and object placement."""

import dataclasses
import math

import numpy as np
import pytest
from tolerances import EPS64, reordering_tolerance

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


def test_a_size_that_does_not_fit_names_the_keys_and_the_largest_size_that_fits():
    cam = Camera.from_fov(160, 120, 70)
    depth, _ = table_scene(cam)
    sphere = GlassObject.sphere(subdivisions=3)
    with pytest.raises(ValueError, match=r"object.size=100 .*reaches behind the camera.*largest size") as e:
        place_object(sphere, depth, cam, size=100.0)
    largest = float(str(e.value).split("about object.size=")[1].split(" ")[0])
    placed = place_object(sphere, depth, cam, size=largest)  # the size it names fits
    assert placed.vertices[:, 2].min() > 0
    with pytest.raises(ValueError, match=r"behind the camera") as e:
        place_object(sphere, depth, cam, size=1.2 * largest / 0.9)
    with pytest.raises(ValueError, match=r"object.relative_size=100 x the distance"):
        place_object(sphere, depth, cam, relative_size=100.0)


def test_a_size_that_covers_no_pixel_names_the_keys_and_the_smallest_size():
    cam = Camera.from_fov(160, 120, 70)
    depth, _ = table_scene(cam)
    sphere = GlassObject.sphere(subdivisions=3)
    with pytest.raises(ValueError, match=r"spans only .* pixels .*too few to trace and score") as e:
        place_object(sphere, depth, cam, size=1e-6)
    smallest = float(str(e.value).split("object.size to at least ")[1].split(" ")[0])
    placed = place_object(sphere, depth, cam, size=smallest)  # the size it names is large enough
    pix, _ = cam.project(placed.vertices)
    assert np.min(np.ptp(pix, axis=0)) >= 4.0


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


# ---------------------------------------------------------------------------- a region to place in
TABLE_DROP, FLOOR_DROP = 0.5, 1.2  # metres below the camera


def table_and_floor(cam, pitch_deg=20.0):
    """Two horizontal planes seen by a pitched camera: a table top 0.5 m below it, filling the
    columns 10-55 % of the image, and the floor 1.2 m below elsewhere, a wall 5 m ahead.

    Returns ``(depth, up, table_region, floor_region)`` (the regions: where each plane is seen)."""
    a = math.radians(pitch_deg)
    up = np.array([0.0, -math.cos(a), -math.sin(a)])
    fwd_h = np.array([0.0, -math.sin(a), math.cos(a)])
    floor = ray_plane_depth(cam, -up, FLOOR_DROP)
    table = ray_plane_depth(cam, -up, TABLE_DROP)
    wall = ray_plane_depth(cam, fwd_h, 5.0)
    cols = np.arange(cam.width)[None, :] * np.ones((cam.height, 1))
    on_table = (cols >= 0.1 * cam.width) & (cols < 0.55 * cam.width) & (table < wall)
    depth = np.where(on_table, table, np.minimum(floor, wall))
    return depth, up, on_table, ~on_table & (floor < wall)


def golden_cases():
    """Inputs whose planes were recorded before ``region`` existed (``region=None`` must not change them)."""
    cam = Camera.from_fov(160, 120, 70)
    depth, up = table_scene(cam)
    holes = depth.copy()
    holes[::7, ::5] = np.nan
    holes[50:60] = 0.0
    cam2 = Camera.from_fov(200, 150, 75)
    two, up2, _, _ = table_and_floor(cam2)
    return {
        "floor": (depth, cam, dict(seed=0)),
        "floor-window": (depth, cam, dict(window=(0.3, 0.5), up_hint=up, seed=3)),
        "holes": (holes, cam, dict(seed=1)),
        "two-highest": (two, cam2, dict(up_hint=up2)),
        "two-largest": (two, cam2, dict(up_hint=up2, prefer="largest")),
        "two-central": (two, cam2, dict(up_hint=up2, prefer="central", seed=2)),
        "subsampled": (depth, cam, dict(seed=5, max_points=3000, num_iterations=200)),
    }


#: name -> (inliers, point, normal, pixel), computed by find_support_plane before it had ``region``.
GOLDEN = {
    "floor": (
        6624,
        [-6.245004513516506e-17, 0.3222733933184134, 1.8882219663331117],
        [0.0, -0.9659258262890685, -0.25881904510252063],
        [79.5, 79.00000000000058],
    ),
    "floor-window": (
        2160,
        [-8.716985466783456e-17, 0.16297706525392505, 2.4827239561288748],
        [0.0, -0.9659258262890682, -0.2588190451025208],
        [79.49999999999999, 66.9999999999997],
    ),
    "holes": (
        5493,
        [-0.005169035159932857, 0.36817374635592776, 1.7169195167117677],
        [4.780773651819592e-17, -0.9659258262890683, -0.2588190451025207],
        [79.15602826743672, 84.00000000000075],
    ),
    "two-highest": (
        7186,
        [-0.20223311715662687, 0.13737582516353303, 1.0846333684812253],
        [-0.0013206882720598438, -0.9394231893112759, -0.3427569505738993],
        [75.20097535572488, 91.00619150863905],
    ),
    "two-largest": (
        7186,
        [-0.20223311715662687, 0.13737582516353303, 1.0846333684812253],
        [-0.0013206882720598438, -0.9394231893112759, -0.3427569505738993],
        [75.20097535572488, 91.00619150863905],
    ),
    "two-central": (
        7216,
        [-0.20177879253709785, 0.13737020442889078, 1.0846313144176025],
        [-0.0013152954433060628, -0.9394437439759812, -0.3427006301457403],
        [75.25551815256165, 91.00554741545902],
    ),
    "subsampled": (
        1911,
        [0.005906271394030026, 0.3222733933184029, 1.8882219663331088],
        [-0.0, -0.9659258262890689, -0.25881904510251813],
        [79.85737449808583, 78.99999999999997],
    ),
}


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_without_a_region_the_plane_is_what_it_was(name):
    """``region=None`` (or no region argument) gives the planes recorded before regions existed, and
    the two calls agree bit for bit. (The recorded values were computed on another machine, whose
    LAPACK may sum in another order: they agree to the float64 rounding of reductions over the
    inliers.)"""
    depth, cam, kw = golden_cases()[name]
    a = find_support_plane(depth, cam, **kw)
    b = find_support_plane(depth, cam, region=None, **kw)
    for f in dataclasses.fields(SupportPlane):
        va, vb = np.asarray(getattr(a, f.name)), np.asarray(getattr(b, f.name))
        assert va.dtype == vb.dtype and va.tobytes() == vb.tobytes(), f.name
    inliers, point, normal, pixel = GOLDEN[name]
    assert a.inliers == inliers
    # the mean and the SVD of the centred inliers sum over them: float64 rounding of that many terms,
    # times the point's magnitude (< 2.5) or, for the normal, the SVD's sigma_1 / sigma_2 (< 3.7 here)
    atol = reordering_tolerance(inliers, 4.0, eps=EPS64)
    np.testing.assert_allclose(a.point, point, rtol=0, atol=atol)
    np.testing.assert_allclose(a.normal, normal, rtol=0, atol=atol)
    # projected with a focal length of ~115 pixels per unit of x / z: ~1e-10 for the above
    np.testing.assert_allclose(a.pixel, pixel, rtol=0, atol=1e-9)


def test_a_region_picks_the_plane_it_covers():
    cam = Camera.from_fov(200, 150, 75)
    depth, up, table, floor = table_and_floor(cam)
    for region, drop in ((table, TABLE_DROP), (floor, FLOOR_DROP)):
        plane = find_support_plane(depth, cam, up_hint=up, region=region)
        assert plane.normal @ up > math.cos(math.radians(0.5))
        assert plane.point @ up == pytest.approx(-drop, abs=2e-3)
        x, y = np.round(plane.pixel).astype(int)
        assert region[y, x]  # the object stands inside the region
        assert plane.inliers <= region.sum()
    # without a region the highest plane near the centre wins: the table
    assert find_support_plane(depth, cam, up_hint=up).point @ up == pytest.approx(-TABLE_DROP, abs=2e-3)


def test_a_region_outside_the_central_window_is_searched_anyway():
    """The window is ignored when a region is given: a strip of floor at the right edge."""
    cam = Camera.from_fov(200, 150, 75)
    depth, up, _, floor = table_and_floor(cam)
    edge = floor.copy()
    edge[:, : int(0.9 * cam.width)] = False  # the window covers columns 20-80 %
    plane = find_support_plane(depth, cam, up_hint=up, region=edge)
    assert plane.point @ up == pytest.approx(-FLOOR_DROP, abs=2e-3)
    assert plane.pixel[0] >= 0.9 * cam.width - 0.5


def test_with_a_region_the_dominant_plane_wins_by_default():
    """A region mostly on the floor with a bit of table (a segmentation that bleeds) keeps the
    floor: with a region ``prefer`` defaults to "largest"; "highest" can still be asked for."""
    cam = Camera.from_fov(200, 150, 75)
    depth, up, table, floor = table_and_floor(cam)
    rows = np.arange(cam.height)[:, None] * np.ones((1, cam.width), bool)
    region = floor | (table & (rows > 0.9 * cam.height))
    assert (region & table).sum() > 0.05 * region.sum()
    assert find_support_plane(depth, cam, up_hint=up, region=region).point @ up == pytest.approx(-FLOOR_DROP, abs=2e-3)
    high = find_support_plane(depth, cam, up_hint=up, region=region, prefer="highest")
    assert high.point @ up == pytest.approx(-TABLE_DROP, abs=2e-3)


def test_place_object_stands_in_the_region():
    cam = Camera.from_fov(200, 150, 75)
    depth, up, _, floor = table_and_floor(cam)
    obj = place_object(GlassObject.sphere(subdivisions=2), depth, cam, size=0.3, up_hint=up, region=floor)
    heights = obj.vertices @ obj.up
    assert heights.min() == pytest.approx(-FLOOR_DROP + 1e-3 * 0.3, abs=2e-3)
    again = place_object(GlassObject.sphere(subdivisions=2), depth, cam, size=0.3, up_hint=up, region=floor)
    assert np.array_equal(obj.vertices, again.vertices)  # deterministic


def test_a_region_without_valid_depth_names_the_keys():
    cam = Camera.from_fov(64, 48, 60)
    depth, up = table_scene(cam)
    empty = np.zeros(cam.shape, bool)
    holes = depth.copy()
    holes[30:40, 10:20] = np.nan
    patch = np.zeros(cam.shape, bool)
    patch[30:40, 10:20] = True
    for d, region in ((depth, empty), (holes, patch)):
        with pytest.raises(ValueError, match=r"surface has no valid depth.*`segment`.*`scene\.depth`"):
            find_support_plane(d, cam, up_hint=up, region=region)
        with pytest.raises(ValueError, match=r"surface has no valid depth.*`segment`.*`scene\.depth`"):
            place_object(GlassObject.sphere(subdivisions=1), d, cam, region=region)
    with pytest.raises(ValueError, match="region has shape"):
        find_support_plane(depth, cam, region=np.ones((48, 63), bool))
    with pytest.raises(TypeError, match="bool"):
        find_support_plane(depth, cam, region=np.ones(cam.shape, np.uint8))


def test_a_region_without_a_horizontal_plane_says_so():
    cam = Camera.from_fov(200, 150, 75)
    depth, up, table, floor = table_and_floor(cam)
    wall = ~table & ~floor & np.isfinite(depth)
    with pytest.raises(ValueError, match="no horizontal supporting surface found inside the supporting-surface region"):
        find_support_plane(depth, cam, up_hint=up, region=wall)
