"""The Cycles reference (snell_bench.render.cycles): the missing-environment error, the frame, and
(slow, with `make setup-cycles`) Cycles against Mitsuba on the refraction itself, both unlit."""

import numpy as np
import pytest
import trimesh

from snell_bench.render.cycles import CyclesUnavailable, default_blender_python, find_blender_python, to_blender
from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject

_LUMA = np.array([0.299, 0.587, 0.114])


def test_a_missing_blender_python_names_the_key_and_the_make_target(tmp_path):
    with pytest.raises(CyclesUnavailable, match=r"reference\.blender_python=.*make setup-cycles"):
        find_blender_python(tmp_path / "no-python")


def test_blenders_frame_is_the_camera_frame_turned_z_up():
    # forward (camera z) is Blender's +y, down (camera y) is Blender's -z, right stays x
    np.testing.assert_allclose(to_blender([[0, 0, 1], [0, 1, 0], [1, 0, 0]]), [[0, 1, 0], [0, 0, -1], [1, 0, 0]])
    assert np.linalg.det(to_blender(np.eye(3))) == pytest.approx(1.0)  # a rotation: cross products keep


def _scene():
    camera = Camera.from_fov(160, 120, 60.0)
    depth = np.full(camera.shape, 3.0)
    y, x = np.mgrid[0:120, 0:160]
    # a smooth texture (period 24 px): the renderers' pixel footprints differ little on it
    img = np.stack(
        [0.5 + 0.25 * np.sin(2 * np.pi * x / 24), 0.5 + 0.25 * np.cos(2 * np.pi * y / 24), 0.4 + 0 * x], -1
    ).astype(np.float32)
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=0.3)
    mesh.apply_translation([0.0, 0.0, 2.0])
    return img, depth, camera, GlassObject(mesh, ior=1.5, name="sphere", placed=True)


@pytest.mark.slow
def test_cycles_and_mitsuba_agree_on_the_refraction_unlit():
    if not default_blender_python().exists():
        pytest.skip(f"no Blender environment at {default_blender_python()}: run `make setup-cycles`")
    pytest.importorskip("mitsuba", reason="Mitsuba is the render extra: make setup EXTRAS=test,render")
    from snell_bench.render import ReferenceSettings, render_reference
    from snell_bench.render.cycles import render_cycles

    img, depth, camera, obj = _scene()
    m = render_reference(img, depth, camera, obj, ReferenceSettings(spp=242, reflection=False, seed=0))
    c0, c1 = (render_cycles(img, depth, camera, obj, spp=256, seed=s, lighting="unlit", ior=None) for s in (0, 1))
    mask = m.mask
    assert mask.sum() > 1000

    def mse(a, b):
        return float(np.mean(((a - b)[mask] @ _LUMA) ** 2))

    # noise variances: Cycles' from two seeds (E (c0 - c1)^2 = 2 v_C), Mitsuba's from its halves
    v_cycles = mse(c0.image, c1.image) / 2.0
    v_mitsuba = 10.0 ** (-m.self_noise_db / 10.0)
    # what is not noise: Cycles' 1-px box over nearest texels vs Mitsuba's texel-exact footprints, a
    # blur of the texture (amplitude 0.25, period 24 px, minified up to 3x through the sphere) by at
    # most 0.25 (pi / 8)^2 / 6 = 0.0064 in value; twice the noise for the variance estimates' spread
    bound = 2.0 * (v_cycles + v_mitsuba) + 0.0064**2
    assert mse(c0.image, m.image) <= bound, (10 * np.log10(1 / mse(c0.image, m.image)), 10 * np.log10(1 / bound))
    # and outside the object both show I⁻ (the box filter over nearest texels: the same blur bound),
    # but for the image's outermost pixels: the mesh ends at their centres, so half of each sees the world
    out = ~c0.object_mask & ~m.object_mask
    out[[0, -1], :] = out[:, [0, -1]] = False
    assert float(np.mean(((c0.image - img)[out] @ _LUMA) ** 2)) <= 0.0064**2
