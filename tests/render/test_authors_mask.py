"""The authors' metric mask (snell_bench.render.authors_mask) on a glass sphere before a plane,
against the closed form of the refraction through a sphere; and their hole filling on hand-made masks."""

import numpy as np
import pytest
import trimesh

from snell_bench.render.authors_mask import authors_mask, fill_small_holes
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import build_background

CENTRE, RADIUS, PLANE_Z, IOR = np.array([0.0, 0.0, 2.0]), 0.3, 6.0, 1.5


def _refract(d, n, eta):
    cos_i = -np.sum(d * n, -1, keepdims=True)
    k = 1.0 - eta**2 * (1.0 - cos_i**2)
    return eta * d + (eta * cos_i - np.sqrt(k)) * n  # a sphere entered from outside has no TIR


def _closed_form(camera):
    """Per pixel: the first hit is the sphere (exact), and where the path, refracted in and out of
    the exact sphere, lands on the plane z = PLANE_Z (signed distance, in pixels, inside the rectangle of
    pixel centres that the depth mesh spans), and the impact parameter over the radius."""
    d = camera.pixel_rays()
    b = d @ CENTRE
    disc = b**2 - (CENTRE @ CENTRE - RADIUS**2)
    hit = disc > 0
    t1 = b - np.sqrt(np.where(hit, disc, 0.0))
    p1 = t1[..., None] * d
    n1 = (p1 - CENTRE) / RADIUS
    d1 = _refract(d, n1, 1.0 / IOR)
    p2 = p1 - 2.0 * np.sum(d1 * (p1 - CENTRE), -1, keepdims=True) * d1
    n2 = (p2 - CENTRE) / RADIUS
    d2 = _refract(d1, -n2, IOR)
    u = (PLANE_Z - p2[..., 2]) / d2[..., 2]
    land = p2 + u[..., None] * d2
    px, _ = camera.project(land.reshape(-1, 3))
    px = px.reshape(*camera.shape, 2)
    W, H = camera.width, camera.height
    margin = np.minimum.reduce([px[..., 0], W - 1 - px[..., 0], px[..., 1], H - 1 - px[..., 1]])
    margin = np.where(d2[..., 2] > 0, margin, -np.inf)
    impact = np.sqrt(np.maximum(0.0, 1.0 - b**2 / (CENTRE @ CENTRE))) * np.linalg.norm(CENTRE) / RADIUS
    return hit, margin, impact, u


@pytest.fixture(scope="module")
def sphere_scene():
    camera = Camera.from_fov(160, 120, 60.0)
    depth = np.full(camera.shape, PLANE_Z)
    bg = build_background(depth, camera, 0.05)
    sphere = trimesh.creation.icosphere(subdivisions=6, radius=RADIUS)
    sphere.apply_translation(CENTRE)
    mask, silhouette = authors_mask(camera, (bg.vertices, bg.faces), (sphere.vertices, sphere.faces), ior=IOR)
    return camera, sphere, mask, silhouette


def test_the_silhouette_is_the_spheres_outline(sphere_scene):
    camera, sphere, _, silhouette = sphere_scene
    hit, _, impact, _ = _closed_form(camera)
    # the mesh is inscribed: its outline lies within its sagitta (< 0.1 % of the radius at
    # subdivision 6, far below a pixel) of the exact one, so only pixels at the outline may differ
    differ = hit != silhouette
    assert differ.sum() <= 0.02 * hit.sum()
    assert np.all(impact[differ & hit] > 0.97)


def test_the_mask_is_where_the_refracted_path_lands_on_the_plane(sphere_scene):
    camera, sphere, mask, silhouette = sphere_scene
    hit, margin, impact, u = _closed_form(camera)
    core = hit & silhouette & (impact <= 0.9)
    expected = margin >= 0
    # the path is traced with face normals: they are off the sphere's normals by at most eps; two
    # refractions at impact <= 0.9 R turn the exit direction by at most 8 eps (the exit's angular
    # gain n cos(theta_t) / cos(theta_i) <= 2.74 there, plus the entry's <= 1), so a path can land
    # on the wrong side of the mesh's edge only within 8 eps * u (in pixels) of it
    fn = sphere.face_normals
    radial = sphere.triangles.mean(axis=1) - CENTRE
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    tri = sphere.triangles - CENTRE
    corner = tri / np.linalg.norm(tri, axis=2, keepdims=True)
    eps = float(np.max(np.arccos(np.clip(np.einsum("fj,fkj->fk", fn, corner), -1.0, 1.0))))
    tol_px = 8.0 * eps * u * camera.K[0, 0] / PLANE_Z
    wrong = core & (mask != expected)
    assert np.all(np.abs(margin[wrong]) <= tol_px[wrong] + 1.0)
    assert wrong.sum() <= 0.05 * core.sum()
    # the geometry puts the mesh's edge inside the sphere's image: both outcomes occur
    assert (core & expected).sum() > 50 and (core & ~expected).sum() > 50
    assert not (mask & ~silhouette).any()


class TestFillSmallHoles:
    def test_a_pinhole_inside_the_region_is_filled(self):
        mask = np.ones((7, 7), bool)
        mask[3, 3] = False
        out = fill_small_holes(mask, np.ones((7, 7), bool))
        assert out.all()

    def test_only_inside_the_region_and_with_six_neighbours(self):
        mask = np.zeros((7, 7), bool)
        mask[2:5, 2:5] = True
        mask[3, 3] = False  # 8 set neighbours, but outside the region: stays
        region = np.ones((7, 7), bool)
        region[3, 3] = False
        out = fill_small_holes(mask, region)
        assert not out[3, 3]
        # every pixel around the block has at most 3 set neighbours: nothing grows
        np.testing.assert_array_equal(out, mask)

    def test_a_slot_fills_at_once_and_a_wide_hole_stays(self):
        mask = np.ones((9, 9), bool)
        mask[4, 2:7] = False  # each slot pixel has its 3 neighbours above and 3 below set
        mask[1:3, 1:3] = False  # each pixel of a 2 x 2 hole has only 5 set neighbours
        out = fill_small_holes(mask, np.ones((9, 9), bool))
        assert out[4].all()
        assert not out[1:3, 1:3].any()
