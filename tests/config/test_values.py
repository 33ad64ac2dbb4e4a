"""Values that pass a type check but would fail or mislead later are refused before any work, each
line naming the full key, the bad value and the fix: the camera (``scene.intrinsics``,
``scene.fov_deg``, ``scene.up``), the panorama's size against the generator's block, the sampler,
the IOR against ``object.ior_range``, and every other range of the schema."""

import math

import numpy as np
import pytest

from snell_bench.config import ConfigError, SamplerSettings, check_config, compose
from snell_bench.config.camera import MAX_FOV_DEG, edge_stretch, min_fov_deg
from snell_bench.experiment.plan import check_reproducible
from snell_bench.scene.camera import Camera

PHOTO = ["scene=tum_office", "scene.intrinsics=null"]  # a photo whose camera the field of view gives


def problems(overrides) -> str:
    with pytest.raises(ConfigError) as e:
        check_config(compose(overrides))
    return str(e.value)


def check(overrides, *expected):
    text = problems(overrides)
    for part in expected:
        assert part in text, text


# ---------------------------------------------------------------------------- the camera
@pytest.mark.parametrize(
    "overrides, expected",
    [
        (["scene=tum_office", "scene.intrinsics=[nan,525,319.5,239.5]"], "scene.intrinsics=[nan, 525, 319.5, 239.5]"),
        (["scene=tum_office", "scene.intrinsics=[inf,525,319.5,239.5]"], "scene.intrinsics=[inf, 525, 319.5, 239.5]"),
        (["scene=tum_office", "scene.intrinsics=[a,b,c,d]"], "must hold finite numbers (no NaN, inf or text)"),
        (["scene=tum_office", "scene.intrinsics=[525,525,319.5]"], "must be a list of 4 numbers, got 3 values"),
        (["scene=tum_office", "scene.intrinsics=[0,525,319.5,239.5]"], "the focal lengths fx, fy must be > 0"),
        (["scene=tum_office", "scene.intrinsics=[525,-1,319.5,239.5]"], "the focal lengths fx, fy must be > 0"),
    ],
)
def test_intrinsics_are_four_finite_numbers_with_positive_focal_lengths(overrides, expected):
    check(overrides, expected, "e.g. scene.intrinsics=[525,525,319.5,239.5]")


@pytest.mark.parametrize(
    "up, expected",
    [
        ("[0,0,0]", "scene.up=[0, 0, 0]: a direction cannot be zero"),
        ("[0.0,-0.0,0.0]", "a direction cannot be zero"),
        ("[0,-1]", "scene.up=[0, -1]: must be a list of 3 numbers, got 2 values"),
        ("[0,nan,-1]", "must hold finite numbers"),
        ("[0,-1,inf]", "must hold finite numbers"),
    ],
)
def test_up_is_a_nonzero_finite_direction(up, expected):
    check([f"scene.up={up}"], expected, "e.g. scene.up=[0,-1,0]")


@pytest.mark.parametrize(
    "overrides, expected",
    [
        ([*PHOTO, "scene.fov_deg=179"], "scene.fov_deg=179.0: must be at most 150 degrees"),
        ([*PHOTO, "scene.fov_deg=180"], "a pinhole camera sees less than 180 degrees across"),
        ([*PHOTO, "scene.fov_deg=0"], "scene.fov_deg=0.0: a field of view is an angle > 0"),
        ([*PHOTO, "scene.fov_deg=-30"], "scene.fov_deg=-30.0: a field of view is an angle > 0"),
        ([*PHOTO, "scene.fov_deg=nan"], "scene.fov_deg=nan: must be a finite number"),
        ([*PHOTO, "scene.fov_deg=1"], "scene.fov_deg=1.0: at object.relative_size=0.25 the object"),
        ([*PHOTO, "scene.fov_deg=10", "object.relative_size=0.5"], "it fits from scene.fov_deg=28.1"),
        (["scene.fov_deg=60"], "scene.fov_deg=60.0: scene.source=procedural renders with its own camera"),
        (["scene=tum_office", "scene.fov_deg=60"], "are both set: the camera takes one"),
        (PHOTO, "scene.source=image with scene.depth needs the camera"),
    ],
)
def test_the_field_of_view_is_one_a_pinhole_camera_and_the_object_allow(overrides, expected):
    check(overrides, expected, "scene.fov_deg")


def test_fields_of_view_inside_the_range_pass():
    for fov in (min_fov_deg(0.25) + 0.01, 60, MAX_FOV_DEG):
        check_config(compose([*PHOTO, f"scene.fov_deg={fov}"]))
    check_config(compose([*PHOTO, "scene.fov_deg=1", "object.size=0.01"]))  # an absolute size: any angle > 0


def test_the_narrowest_field_of_view_frames_the_object_exactly():
    """At ``min_fov_deg(r)`` an object ``r`` times its distance wide projects onto the whole frame
    width (the camera's own projection, not the formula)."""
    for r in (0.05, 0.25, 1.0):
        cam = Camera.from_fov(640, 480, min_fov_deg(r))
        d = 2.7
        (u0, _), (u1, _) = cam.project(np.array([[-r * d / 2, 0.0, d], [r * d / 2, 0.0, d]]))[0]
        assert u1 - u0 == pytest.approx(640, rel=1e-9)


def test_the_edge_stretch_is_the_pinhole_cameras():
    """The angle one pixel spans at the centre over that at the frame's edge, measured with the
    camera's rays, is ``edge_stretch``: 4 at 120 degrees, 14.9 at the widest accepted."""

    def span(cam, u, h=1e-4):
        a, b = cam.pixel_rays(np.array([[u - h / 2, cam.K[1, 2]], [u + h / 2, cam.K[1, 2]]]))
        return math.atan2(float(np.linalg.norm(np.cross(a, b))), float(a @ b))  # no cancellation

    for fov in (60.0, 120.0, MAX_FOV_DEG):
        cam = Camera.from_fov(1000, 500, fov)
        assert span(cam, cam.K[0, 2]) / span(cam, -0.5) == pytest.approx(edge_stretch(fov), rel=1e-3)
    assert edge_stretch(120.0) == pytest.approx(4.0) and edge_stretch(MAX_FOV_DEG) == pytest.approx(14.93, abs=0.01)


# ---------------------------------------------------------------------------- the panorama
@pytest.mark.parametrize(
    "overrides, key, mult, lo, hi",
    [
        (["warps.pano_height=100"], "warps.pano_height", 8, 96, 104),
        (
            ["warps.pano_height=100", "model=tiny_flux", "scene.source=procedural", "scene.height=352"],
            "warps.pano_height",
            16,
            96,
            112,
        ),
        (["warps.pano_height=4"], "warps.pano_height", 8, None, 8),
        (["+method.warps.pano_height=60"], "method.warps.pano_height", 8, 56, 64),
    ],
)
def test_the_panorama_is_a_multiple_of_the_generators_block(overrides, key, mult, lo, hi):
    text = problems(["+experiment=smoke", *overrides])
    value = int(overrides[0].split("=")[1])
    assert f"{key}={value}: the {value}x{2 * value} panorama" in text and f"model.multiple={mult}" in text, text
    use = [f"{key}={h} ({h}x{2 * h})" for h in (lo, hi) if h is not None]
    assert f"use {' or '.join(use)}" in text, text
    for h in (lo, hi):  # the suggestions pass (both sides multiples of the block, 2:1)
        if h is not None and h >= 16:
            check_config(compose(["+experiment=smoke", *overrides, f"{key}={h}"]))


def test_a_preview_only_traces_the_panorama():
    check_config(compose(["job=preview", "warps.pano_height=100"]))


# ---------------------------------------------------------------------------- the sampler
@pytest.mark.parametrize(
    "override, expected",
    [
        ("sampler.eta=2", "sampler.eta must be in [0, 1], got 2.0; the share of fresh noise"),
        ("sampler.eta=-0.5", "sampler.eta must be in [0, 1], got -0.5"),
        ("sampler.eta=nan", "sampler.eta must be in [0, 1], got nan"),
        ("sampler.lam=1.5", "sampler.lam must be in [0, 1], got 1.5"),
        ("sampler.reflection_min_fresnel=-1", "sampler.reflection_min_fresnel must be in [0, 1]"),
        ("sampler.skip_panorama_above=2", "sampler.skip_panorama_above must be in [0, 1] or null"),
        ("sampler.tt_window=[0.2]", "sampler.tt_window=[0.2]: must be a list of 2 numbers, got 1 value"),
        ("sampler.tt_window=[0.9,0.1]", "sampler.tt_window must be [start, end] with 0 <= start <= end <= 1"),
        ("sampler.tt_window=[0.2,nan]", "sampler.tt_window=[0.2, nan]: must hold finite numbers"),
        ("sampler.steps=0", "sampler.steps must be an integer >= 1, got 0"),
        ("sampler.tt_repeats_main=0", "sampler.tt_repeats_main must be an integer >= 1, got 0"),
        ("sampler.dump_every=-1", "sampler.dump_every must be an integer >= 0, got -1"),
        ("+method.sampler.eta=2", "method.sampler.eta must be in [0, 1], got 2.0"),
        ("+method.sampler.steps=abc", "method.sampler.steps='abc': Value 'abc' of type 'str' could not be converted"),
        ("+method.warps.max_bounces=abc", "method.warps.max_bounces='abc'"),
    ],
)
def test_sampler_values_name_their_key(override, expected):
    text = problems([override])
    assert expected in text and ("e.g." in text or "give a value" in text), text


def test_every_sampler_message_names_its_key_and_a_fix():
    bad = dict(
        steps=0, levels=0, tt_length=0, tt_repeats_main=0, tt_repeats_pano=0, dump_every=-1, eta=2.0, lam=2.0,
        reflection_min_fresnel=2.0, skip_panorama_above=2.0, tt_window=[0.8, 0.2], sync="x", latent_dtype="x",
        schedule="x", tt_mode="x", tt_renoise="x", encode="x", dpa_domain="x", pano_to_main="x",
    )  # fmt: skip
    with pytest.raises(ConfigError) as e:
        SamplerSettings(**bad)
    lines = e.value.problems
    assert len(lines) == len(bad)
    for name in bad:
        line = next(x for x in lines if x.startswith(f"sampler.{name}"))
        assert "e.g." in line or "use one of" in line, line


# ---------------------------------------------------------------------------- the IOR
def test_an_ior_below_the_range_says_how_to_model_a_bubble():
    assert problems(["object.ior=0.5"]) == (
        "object.ior=0.5: below object.ior_range=[1.0, 3.0] (a solid or liquid has an IOR >= 1); for an object "
        "optically thinner than its surroundings (an air bubble) lower it explicitly: object.ior_range=[0.5,3]"
    )
    check_config(compose(["object.ior=0.5", "object.ior_range=[0.5,3]"]))


@pytest.mark.parametrize(
    "overrides, expected",
    [
        (["object.ior=5"], "object.ior=5: above object.ior_range=[1.0, 3.0]"),
        (["object.ior=3.0001"], "raise it explicitly: object.ior_range=[1,3.0001]"),
        (["object.ior=0.9999"], "lower it explicitly: object.ior_range=[0.9999,3]"),
        (["object.ior_range=[0,3]"], "object.ior_range=[0, 3]: must be [low, high], two finite numbers"),
        (["object.ior_range=[3,1]"], "with 0 < low <= high; e.g. object.ior_range=[1,3]"),
        (["object.ior_range=[1]"], "object.ior_range=[1]: must be [low, high]"),
        (["object.ior_range=[1,inf]"], "object.ior_range=[1, inf]: must be [low, high]"),
        (["+experiment=smoke", "grid.objects=[sphere:0.5]"], "grid.objects: entry 'sphere:0.5': IOR 0.5 is below"),
        (["+experiment=smoke", "grid.objects=[sphere:9]"], "grid.objects: entry 'sphere:9': IOR 9 is above"),
        (["+experiment=tradeoff", "grid.objects=[sphere:0.2]"], "grid.objects: entry 'sphere:0.2': IOR 0.2 is below"),
        (
            ["+experiment=tradeoff", "+grid.axes.ior='object.ior=1.5,4'", "grid.only=[ior]"],
            "grid.axes.ior: 'object.ior=4': IOR 4 is above object.ior_range=[1.0, 3.0]",
        ),
    ],
)
def test_an_ior_outside_its_range_is_refused(overrides, expected):
    check(overrides, expected, "object.ior_range=[")


def test_iors_inside_the_range_pass():
    for ior in ("1.0", "3.0", "air", "diamond", "water"):
        check_config(compose([f"object.ior={ior}"]))
    check_config(compose(["+experiment=extremes"]))  # sphere:1.000001 and sphere:3.0
    check_config(compose(["+experiment=ior_sweep"]))
    check_config(compose(["+experiment=smoke", "grid.objects=[sphere:0.75]", "object.ior_range=[0.5,3]"]))


# ---------------------------------------------------------------------------- the other ranges
@pytest.mark.parametrize(
    "overrides, expected",
    [
        (["reference.unobserved_threshold=0"], "reference.unobserved_threshold=0.0: must be a number in (0, 1.0]"),
        (["reference.true_max_bounces=0"], "reference.true_max_bounces=0: must be an integer >= 1"),
        (["object.max_tilt_deg=0"], "object.max_tilt_deg=0.0: must be a number in (0, 90.0]"),
        (["segment.threshold=1.5"], "segment.threshold=1.5: must be a number in [0.0, 1.0]"),
        (["model.prior_std=0"], "model.prior_std=0.0: must be a finite number > 0"),
        (["model.glass_std=nan"], "model.glass_std=nan: must be a finite number > 0"),
        (["model.guidance=-1"], "model.guidance=-1.0: must be a number >= 0.0"),
        (["model.seed=-1"], "model.seed=-1: must be an integer >= 0"),
        (["models.host_memory_gb=0"], "models.host_memory_gb=0.0: must be a finite number > 0 or null"),
        (["method.steps=0"], "method.steps=0: must be an integer >= 1"),
        (["method.guidance=inf"], "method.guidance=inf: must be a number >= 0.0 or null"),
        (["relight.steps=0"], "relight.steps=0: must be an integer >= 1"),
        (["relight.lora_scale=nan"], "relight.lora_scale=nan: must be a finite number"),
        (["grid.converged_spp=0"], "grid.converged_spp=0: must be an integer >= 1"),
        (["scene=tum_office", "scene.max_side=0"], "scene.max_side=0: must be an integer >= 1"),
        (["scene=tum_office", "scene.max_side=4"], "scene.max_side=4: the photo's sides are cropped to multiples"),
        (["scene.kind=attic"], "scene.kind='attic': no procedural scene of this kind; use one of"),
        (["scene.source=generated", "scene.schedule=cosine"], "scene.schedule='cosine' is unknown; use one of"),
        (["warps.cache_dir=''"], "warps.cache_dir='': must be a folder, or null for no cache, not empty"),
        (["scene.cache_dir=' '"], "scene.cache_dir=' ': must be a folder"),
        (["runs_dir=''"], "runs_dir='': must be a folder; e.g. runs_dir=runs"),
        (["seed=9223372036854775808"], "seed=9223372036854775808: must be an integer <= 9223372036854775807"),
        (["+experiment=smoke", "grid.variations=[9223372036854775808]"], "grid.variations: entry 9223372036854775808"),
        (["tracker=tensorboard", "tracker.experiment=''"], "tracker.experiment='': the runs of tracker=tensorboard"),
    ],
)
def test_a_value_that_would_fail_later_is_refused_now(overrides, expected):
    check(overrides, expected)


def test_the_scene_kinds_are_the_procedural_scenes_own():
    from snell_bench.config.choices import SCENE_KINDS
    from snell_bench.scene.procedural.scene import SCENE_KINDS as OWN

    assert set(SCENE_KINDS) == set(OWN)


# ---------------------------------------------------------------------------- reproducibility
def test_the_reproducibility_check_takes_any_value():
    check_reproducible(compose(["scene=tum_office", "scene.intrinsics=[nan,525,319.5,239.5]"]))  # NaN == NaN here
    cfg = compose(["+experiment=smoke"])
    cfg.overrides = ["+experiment=no_such_experiment"]
    with pytest.raises(ValueError, match=r"the config's overrides \['\+experiment=no_such_experiment'\] do not"):
        check_reproducible(cfg)
    cfg.overrides = ["+experiment=smoke"]
    cfg.scene.width = 320
    with pytest.raises(ValueError, match=r"differs from what its overrides .* compose, at \['scene.width'\]"):
        check_reproducible(cfg)
