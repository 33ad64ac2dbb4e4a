"""Geometry of the reference render (no Mitsuba): the extended background grid, its subdivision
into texel pieces, the flaps at depth edges, the inward box and the object's arrays."""

import numpy as np

from snell_bench.render.geometry import (
    background_geometry,
    flaps,
    grid_triangle_ids,
    inward_box,
    object_arrays,
    object_mask,
    object_rect,
    subdivide,
    triangulate_grid,
)
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import bounding_box_mesh, build_background
from snell_bench.scene.objects import GlassObject

h, w = 12, 16


def camera() -> Camera:
    return Camera.from_fov(w, h, 60.0)


def background(depth):
    cam = camera()
    bg = build_background(depth, cam, 0.05)
    return cam, bg, background_geometry(bg, depth, cam, 0.05)


def test_grid_ids_identify_grid_triangles_in_any_order():
    f = triangulate_grid(4, 5)
    assert f.shape == (2 * 3 * 4, 3) and f.dtype == np.int64
    ids, ok = grid_triangle_ids(f, 5)
    assert ok.all() and len(np.unique(ids)) == len(f)
    ids_rolled, _ = grid_triangle_ids(np.roll(f, 1, axis=1), 5)
    assert np.array_equal(ids, ids_rolled)
    assert not grid_triangle_ids(np.array([[0, 1, 2]]), 5)[1].any()


def test_smooth_plane_is_all_observed():
    depth = np.full((h, w), 2.0)
    cam, bg, geo = background(depth)
    assert geo.vertices.shape == ((h + 2) * (w + 2), 3)
    assert len(geo.open) == 0 and len(geo.observed) == 2 * (h + 1) * (w + 1)
    assert np.allclose(geo.vertices[:, 2], 2.0)
    v, f, uv = flaps(geo, cam)
    assert len(v) == len(f) == len(uv) == 0


def test_subdivision_pieces_show_one_texel():
    x = np.arange(w)[None, :].repeat(h, 0)
    depth = 2.0 + 0.05 * x  # tilted: a side's image midpoint is not its 3-D midpoint
    cam, bg, geo = background(depth)
    v, f, uv = subdivide(geo, cam.shape, geo.observed)
    assert len(f) == 4 * len(geo.observed)
    # every piece's centroid in the image lies inside the texel that its uv centroid names
    pix, _ = cam.project(v[f].mean(axis=1).astype(np.float64))
    tex = uv[f].mean(axis=1) * [w, h] - 0.5
    assert np.all(np.floor(tex + 0.5) == np.floor(pix + 0.5))
    # the new vertices are the sides' image midpoints: half-way between pixel centres, a quarter
    # pixel in from the border ring (which is half a pixel wide)
    pv, _ = cam.project(v.astype(np.float64))
    assert np.allclose(4 * pv, np.round(4 * pv), atol=1e-3)
    assert len(np.unique(np.round(4 * pv).astype(int), axis=0)) == len(v)


def test_flaps_at_a_depth_step_lie_at_pixel_depth():
    x = np.arange(w)[None, :].repeat(h, 0)
    depth = np.where(x < w // 2, 2.0, 5.0)
    cam, bg, geo = background(depth)
    assert len(geo.open) > 0
    v, f, uv = flaps(geo, cam)
    assert len(f) > 0 and v.dtype == np.float32 and uv.dtype == np.float32
    assert set(np.unique(np.round(v[:, 2], 5))) <= {2.0, 5.0}


def test_inward_box_normals_point_inside():
    bv, bf = bounding_box_mesh(np.array([[0.0, 0.0, 1.0], [1.0, 2.0, 3.0]]))
    f = inward_box(bv, bf)
    v = bv.astype(np.float64)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(np.einsum("ij,ij->i", n, v.mean(axis=0) - v[f].mean(axis=1)) > 0)


def test_object_arrays_mask_and_rect(small_camera):
    T = np.eye(4)
    T[:3, :3] *= 0.5
    T[:3, 3] = (0.0, -0.25, 3.0)
    obj = GlassObject.sphere(subdivisions=2).transformed(T)
    v, f, n = object_arrays(obj)
    assert len(v) == 3 * len(obj.faces) and np.array_equal(f.reshape(-1), np.arange(len(v)))
    assert np.allclose(v, np.asarray(obj.vertices)[np.asarray(obj.faces)].reshape(-1, 3))
    depth = np.full(small_camera.shape, 10.0)
    m = object_mask(depth, small_camera, obj)
    assert m.sum() > 100
    x0, y0, x1, y1 = object_rect(small_camera, obj)
    ys, xs = np.nonzero(m)
    assert x0 <= xs.min() and xs.max() < x1 and y0 <= ys.min() and ys.max() < y1
    # nothing is in front of a background closer than the object
    assert not object_mask(np.full(small_camera.shape, 1.0), small_camera, obj).any()
