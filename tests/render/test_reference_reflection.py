"""``render_reference(reflection=...)``: the physically complete dielectric against the paper's
refraction-only reference, on a glass sphere in front of a uniform emitting plane (closed forms at
normal incidence)."""

import math

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")

from conftest import sphere_at  # noqa: E402
from render_testing import far_from_object, forced_cpu_variant  # noqa: E402

from snell_bench.imaging.color import srgb_to_linear  # noqa: E402
from snell_bench.render.reference import ReferenceSettings, render_reference  # noqa: E402
from snell_bench.scene.camera import Camera  # noqa: E402

IOR = 1.5
F0 = ((IOR - 1.0) / (IOR + 1.0)) ** 2  # Fresnel reflectance at normal incidence: 0.04
SPP, PATCH = 256, 7  # samples per pixel; the central PATCH x PATCH pixels are averaged


@pytest.fixture(scope="module", autouse=True)
def cpu_variant():
    with forced_cpu_variant():
        yield


@pytest.fixture(scope="module")
def scene():
    """A 48 x 48 camera (60 degrees), a sphere of radius 1.2 at z = 3 (about 36 px across) and a
    plane at z = 6 of uniform sRGB 0.8; nothing else emits (rays that leave see black)."""
    cam = Camera.from_fov(48, 48, 60.0)
    depth = np.full(cam.shape, 6.0, np.float32)
    image = np.full((48, 48, 3), 0.8, np.float32)
    return cam, depth, image, sphere_at([0.0, 0.0, 3.0], 1.2), float(srgb_to_linear(np.float32(0.8)))


def centre_ratio(scene, **kwargs):
    """Mean linear radiance of the central patch over the plane's radiance ``L``."""
    cam, depth, image, obj, L = scene
    ref = render_reference(
        image,
        depth,
        cam,
        obj,
        ReferenceSettings(spp=SPP, seed=1, sampler="independent", self_noise=False, unobserved_spp=1, **kwargs),
    )
    a = (48 - PATCH) // 2
    return float(ref.linear[a : a + PATCH, a : a + PATCH].mean() / L), ref


def tolerance(p):
    """Every sample is L or 0 (delta lobes of weight 1 in and out), so the patch mean is a
    Bernoulli mean of ``PATCH^2 SPP`` draws: 5 standard deviations, plus F0^2 for paths of two or
    more internal reflections (their share, which off the axis may end on black instead of the
    plane), plus the change of F over the patch (incidence below 14 degrees: F < 0.0401)."""
    return 5 * math.sqrt(p * (1 - p) / (PATCH**2 * SPP)) + F0**2 + 1e-4


# the closed forms at normal incidence: entry weight w_in, then the exit transmits 1 - F and
# reflects F back, whose exit towards the camera sees black and whose next reflection returns:
# L w_in (1 - F) (1 + F^2 + F^4 + ...) = L w_in (1 - F) / (1 - F^2) = L w_in / (1 + F)
WITH_REFLECTION = (1 - F0) / (1 + F0)  # the dielectric: entry weight 1 - F (0.923)
REFRACTION_ONLY = 1 / (1 + F0)  # the authors' render_gt: entry weight 1 (0.962)


def test_expected_values_are_told_apart():
    assert REFRACTION_ONLY - WITH_REFLECTION > 2 * max(tolerance(WITH_REFLECTION), tolerance(REFRACTION_ONLY))


def test_with_reflection_entry_loses_fresnel(scene):
    ratio, ref = centre_ratio(scene, reflection=True)
    assert abs(ratio - WITH_REFLECTION) < tolerance(WITH_REFLECTION), ratio
    assert ref.reflection and ref.summary()["reflection"] is True


def test_refraction_only_transmits_camera_rays_with_weight_one(scene):
    """``reflection=False``: no first-surface reflection and no Fresnel loss at the entry, the
    exit's Fresnel split kept (not the geometric ``fresnel=False`` render, which gives exactly L)."""
    ratio, ref = centre_ratio(scene, reflection=False)
    assert abs(ratio - REFRACTION_ONLY) < tolerance(REFRACTION_ONLY), ratio
    assert not ref.reflection and ref.summary()["reflection"] is False
    geometric, _ = centre_ratio(scene, fresnel=False)
    assert abs(geometric - 1.0) < 1e-5  # every sample follows the refraction path with weight 1


def test_refraction_only_is_the_same_outside_the_object(scene):
    cam, depth, image, obj, L = scene
    kwargs = dict(spp=4, seed=0, sampler="independent", self_noise=False, unobserved_spp=1)
    a = render_reference(image, depth, cam, obj, ReferenceSettings(reflection=True, **kwargs))
    b = render_reference(image, depth, cam, obj, ReferenceSettings(reflection=False, **kwargs))
    out = far_from_object(a.object_mask)  # pixels whose footprints miss the object
    assert out.sum() > 500
    np.testing.assert_array_equal(a.object_mask, b.object_mask)
    np.testing.assert_allclose(b.linear[out], a.linear[out], atol=1e-6)  # both L
