"""A glass of water (with a straw): closed shells whose surfaces meet along shared rings, the media on
each face's two sides, the config that builds it, and the warps through it."""

import numpy as np
import pytest

from snell_bench.config import compose
from snell_bench.config.errors import ConfigError
from snell_bench.config.materials import absorption_coefficients
from snell_bench.optics.media import interface_faces
from snell_bench.scene.vessels import glass_of_water

GLASS, WATER, STRAW, AIR = 0, 1, 2, -1


def _pairs(obj) -> dict:
    """How many faces of each shell separate each pair of media (behind, in front)."""
    behind, front = interface_faces(obj)
    keys, counts = np.unique(np.stack([obj.face_medium, behind, front], 1), axis=0, return_counts=True)
    return {tuple(int(v) for v in k): int(c) for k, c in zip(keys, counts)}


def test_shells_are_closed_and_canonical():
    obj = glass_of_water(straw=True, sections=32)
    assert [m.ior for m in obj.media] == [1.5, 1.333, 1.49] and not obj.placed
    for k in range(3):
        shell = obj.mesh.submesh([np.flatnonzero(obj.face_medium == k)], append=True)
        assert shell.is_watertight and shell.volume > 0, k
    lo, hi = obj.mesh.bounds
    assert lo[1] == pytest.approx(0.0, abs=1e-12) and (hi - lo).max() == pytest.approx(1.0)
    np.testing.assert_allclose((lo + hi)[[0, 2]] / 2, 0.0, atol=1e-12)


def test_every_face_separates_the_media_the_geometry_says():
    """The glass's outside and its inner wall above the water meet air, the wall and floor below it
    water; the water's surface meets air (inside the straw too) and its part inside the glass is
    no interface; the straw meets water below the level and air above it."""
    n = 32
    plain = _pairs(glass_of_water(sections=n))
    assert set(plain) == {(GLASS, GLASS, AIR), (GLASS, GLASS, WATER), (WATER, WATER, AIR), (WATER, GLASS, GLASS)}
    # the water's surface: the disc inside the wall (a fan of n triangles) meets air
    assert plain[(WATER, WATER, AIR)] == n
    # the glass's inner wall below the level (2n) and its floor (a fan, n) meet water
    assert plain[(GLASS, GLASS, WATER)] == 3 * n
    straw = _pairs(glass_of_water(straw=True, sections=n))
    assert straw[(WATER, WATER, AIR)] == n + 2 * n  # the disc inside the straw, the annulus around it
    assert (WATER, STRAW, STRAW) in straw  # the surface's ring inside the straw's wall
    # the straw (a ring of 2n triangles per profile segment): its bottom and lower walls in water, its
    # upper walls and rim in air
    assert straw[(STRAW, STRAW, WATER)] == 6 * n and straw[(STRAW, STRAW, AIR)] == 6 * n


def test_bad_dimensions_are_refused():
    with pytest.raises(ValueError, match=r"wall \(0.4\) < radius \(0.35\)"):
        glass_of_water(wall=0.4)
    with pytest.raises(ValueError, match="fill"):
        glass_of_water(fill=1.2)
    with pytest.raises(ValueError, match="inner radius"):
        glass_of_water(straw=True, straw_radius=0.4)


def test_the_config_builds_it_with_the_glass_as_the_objects_material():
    from snell_bench.config.checks import check_config
    from snell_bench.pipeline.inputs import build_object

    cfg = compose(
        [
            "object=glass_of_water",
            "object.ior=crown_glass",
            "object.absorption.color=[0.9,1.0,0.9]",
            "object.absorption.distance=0.1",
            "object.factory.straw=true",
            "object.factory.sections=32",
            "object.factory.water_absorption={color:[0.5,0.8,1.0],distance:0.2}",
        ]
    )
    obj = build_object(cfg.object)
    assert [m.ior for m in obj.media] == [1.52, 1.333, 1.49] and obj.ior == 1.52
    assert obj.media[0].absorption == pytest.approx(absorption_coefficients([0.9, 1.0, 0.9], 0.1))
    assert obj.media[1].absorption == pytest.approx(absorption_coefficients([0.5, 0.8, 1.0], 0.2))
    with pytest.raises(ConfigError, match="object=glass_of_water is made of several media"):
        check_config(compose(["object=glass_of_water", "reference.renderer=cycles"]))


def test_warps_through_the_glass_see_the_room():
    """Placed on the table of a procedural room: the glass covers pixels, most of them see the room
    through glass and water, and the water's optical depth is its path in water times its sigma."""
    from snell_bench.optics import compute_warps
    from snell_bench.scene.placement import place_object
    from snell_bench.scene.procedural.scene import ProceduralScene

    r = ProceduralScene("room", 0).render(96, 64)
    tint = {"color": [0.5, 0.8, 0.9], "distance": 0.2}
    sigma = absorption_coefficients(tint["color"], tint["distance"])
    obj = place_object(glass_of_water(sections=48, water_absorption=tint), r.depth, r.camera)
    ws = compute_warps(r.depth, r.camera, obj, pano_height=8, max_bounces=16)
    m = ws.object_mask
    assert m.sum() > 100 and ws.refraction_valid[m].mean() > 0.7
    ratio = ws.optical_depth[m] / np.asarray(sigma, np.float32)
    # per pixel the water's share of the path (the same in each channel) is at most the whole path
    np.testing.assert_allclose(ratio[:, 0], ratio[:, 2], rtol=1e-5, atol=1e-6)
    assert (ratio[:, 0] <= ws.path_length[m] * (1 + 1e-5) + 1e-7).all() and (ratio[:, 0] > 0).any()
