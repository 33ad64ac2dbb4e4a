"""object.rest: a flat base lifted onto the highest point of a rough support under it."""

import numpy as np
import pytest

from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.resting import rest_on_surface

UP = np.array([0.0, 0.0, -1.0])  # a floor facing the camera: up points at it


def _scene(bump: float):
    """A camera looking at a floor at z = 2 with a bump of height ``bump`` under the object, and a
    cylinder of size 0.4 placed 1e-3 above the floor (as the plane placement leaves it)."""
    cam = Camera.from_fov(120, 120, 40.0)
    P = cam.unproject(np.full(cam.shape, 2.0))
    depth = np.full(cam.shape, 2.0)
    depth[np.hypot(P[..., 0] - 0.05, P[..., 1]) < 0.05] -= bump  # a stone under the base, off its axis
    T = np.diag([0.4, 0.4, 0.4, 1.0])
    T[:3, :3] = 0.4 * np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # canonical y up -> -z
    T[:3, 3] = [0.0, 0.0, 2.0 - 1e-3]
    obj = GlassObject.cylinder().transformed(T, up=UP)
    return cam, depth, obj


def _height_above_base(obj, cam, depth) -> float:
    P = cam.unproject(depth).reshape(-1, 3)
    h = P @ UP
    bottom = (obj.vertices @ UP).min()
    under = np.hypot(P[:, 0], P[:, 1]) < 0.13
    return float((h[under] - bottom).max())


def test_a_stone_under_the_base_lifts_the_object_onto_it():
    """Lift = the stone's height inside the base + the clearance, to the float32 ray caster's
    rounding (a few ulps of the 2.8 m its rays span: 8 x 2^-24 x 2.8 < 2e-6)."""
    tol = 2e-6
    cam, depth, obj = _scene(0.01)
    assert _height_above_base(obj, cam, depth) == pytest.approx(0.01 - 1e-3, abs=1e-9)  # the stone is inside the base
    rested, lift = rest_on_surface(obj, depth, cam, clearance=1e-3)
    assert lift == pytest.approx(0.01 - 1e-3 + 1e-3 * 0.4, abs=tol)
    assert _height_above_base(rested, cam, depth) == pytest.approx(-1e-3 * 0.4, abs=tol)
    np.testing.assert_allclose(
        rested.vertices - obj.vertices, np.broadcast_to(lift * UP, obj.vertices.shape), atol=1e-12
    )


def test_a_flat_support_and_tall_neighbours_leave_it_where_it_is():
    cam, depth, obj = _scene(0.0)
    assert rest_on_surface(obj, depth, cam)[1] == 0.0  # nothing inside the base
    cam, depth, obj = _scene(0.3)  # 0.3 is 75 % of the size: something else, not the support
    assert rest_on_surface(obj, depth, cam)[1] == 0.0


def test_an_unplaced_object_is_refused():
    cam, depth, _ = _scene(0.0)
    with pytest.raises(ValueError, match="placed object with an up direction"):
        rest_on_surface(GlassObject.cylinder(), depth, cam)
