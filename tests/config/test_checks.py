"""Config checks before any work: unknown keys and unusable values name the key, the value and the fix."""

import pytest
from hydra.errors import ConfigCompositionException

from snell_bench.config import ConfigError, check_config, compose, max_levels, unknown_keys


@pytest.mark.parametrize(
    "override,expected",
    [
        ("+warps.max_bounce=1", "warps.max_bounce: no setting has this name (did you mean warps.max_bounces?)"),
        ("+object.iorr=3", "object.iorr: no setting has this name (did you mean object.ior?)"),
        ("+sampler.stepz=3", "did you mean sampler.steps?"),
        (
            "+method.sampler.dpaa=false",
            "method.sampler.dpaa: no setting has this name (did you mean method.sampler.dpa?)",
        ),
        ("+method.warps.roii=false", "did you mean method.warps.roi?"),
        ("+banana=1", "banana: no setting has this name"),
    ],
)
def test_a_key_no_schema_knows_is_an_error(override, expected):
    cfg = compose([override])
    assert any(expected in line for line in unknown_keys(cfg)), unknown_keys(cfg)
    with pytest.raises(ConfigError, match="no setting has this name"):
        check_config(cfg)


def test_free_form_nodes_and_every_shipped_config_pass():
    from snell_bench.config import group_options

    for ov in (
        [],
        ["+experiment=smoke"],
        ["+experiment=ablation"],
        ["+experiment=tradeoff"],
        ["+experiment=photo"],
        ["model=flux_dev"],
        ["+object.factory.subdivisions=4"],  # a _target_ node takes any argument
    ):
        check_config(compose(ov))
    for group in ("method", "object", "scene", "model", "depth", "segment", "preset", "recipe"):
        for name in group_options(group):
            assert not unknown_keys(compose([f"{group}={name}"])), (group, name)


@pytest.mark.parametrize(
    "overrides,expected",
    [
        (["scene.width=0"], "scene.width=0: must be a positive multiple of model.multiple=8"),
        (["scene.width=170"], "use scene.width=168 or scene.width=176"),
        (["model=tiny_flux", "scene.height=100"], "model.multiple=16; use scene.height=96 or scene.height=112"),
        (["seed=-1"], "seed=-1: must be an integer >= 0"),
        (["scene.variation=-1"], "scene.variation=-1: must be an integer >= 0"),
        (["object.yaw_deg=nan"], "object.yaw_deg=nan: must be a finite number"),
        (["object.size=-1"], "object.size=-1.0: must be a finite number > 0 or null"),
        (["object.relative_size=0"], "object.relative_size=0.0: must be a finite number > 0"),
        (["object.ior=abc"], "object.ior='abc': unknown material 'abc'"),
        (
            ["sampler.levels=20"],
            "sampler.levels=20: the 720x1280 image (scene.height x scene.width) has at most 9 pyramid levels",
        ),
        (["sampler.steps=0"], "sampler.steps must be an integer >= 1, got 0"),
        (["sampler.sync=maybe"], "sampler.sync='maybe' is unknown"),
        (["warps.max_bounces=0"], "warps.max_bounces=0: must be an integer >= 1"),
        (["object=spot", "object.path=/nonexistent.obj"], "object.path='/nonexistent.obj': no such mesh file"),
        (["object=spot", "object.path=datasets"], "object.path='datasets' is a folder, not a mesh file"),
        (["model.dtype=float17"], "model.dtype='float17' is unknown; use one of ['bfloat16'"),
        (["model.device=tpu9"], "model.device='tpu9' is not a device"),
        (["scene.source=image"], "scene.source=image needs scene.image: set scene.image=PATH"),
        (["scene=tum_office", "scene.image=/no.png"], "scene.image='/no.png': no such image file"),
        (["scene=tum_office", "scene.depth=/no.png"], "scene.depth='/no.png': no such depth file"),
        (["segment=mask"], "segment=mask needs segment.mask: set segment.mask=PATH"),
        (["metrics.lpips_weights=/no.pth"], "metrics.lpips_weights='/no.pth': no such file"),
        (
            ["warps.pano_height=16", "sampler.levels=5"],
            "the 16x32 panorama (warps.pano_height) has at most 4 pyramid levels",
        ),
    ],
)
def test_unusable_values_name_the_key_the_value_and_the_fix(overrides, expected):
    with pytest.raises(ConfigError) as e:
        check_config(compose(overrides))
    assert expected in str(e.value), str(e.value)


def test_every_problem_is_reported_at_once():
    with pytest.raises(ConfigError) as e:
        check_config(compose(["seed=-1", "scene.width=0", "object.yaw_deg=nan"]))
    assert len(e.value.problems) == 3 and str(e.value).startswith("3 settings are unusable")


def test_a_method_switch_is_checked_with_the_method_applied():
    check_config(compose(["method=no_lpw", "sampler.levels=20"]))  # no LPW: one level whatever levels says


@pytest.mark.parametrize(
    "overrides,expected",
    [
        (["grid.objects=[sphere:abc]"], "grid.objects: entry 'sphere:abc': 'abc' is neither a number"),
        (["grid.variations=[abc]"], "grid.variations: entry 'abc' is not an integer >= 0"),
        (["grid.variations=[-1]"], "grid.variations: entry -1 is not an integer >= 0"),
        (["grid.methods=[t2i,t2i]"], "grid.methods lists 't2i' more than once"),
        (["grid.methods=[magic]"], "grid.methods: unknown method 'magic'"),
        (["grid.scenes=[]"], "grid.scenes=[]: must be a non-empty list"),
    ],
)
def test_grid_entries_are_checked(overrides, expected):
    with pytest.raises(ConfigError) as e:
        check_config(compose(["+experiment=smoke", *overrides]))
    assert expected in str(e.value), str(e.value)


def test_material_names_are_accepted_in_grid_objects():
    check_config(compose(["+experiment=smoke", "grid.objects=[sphere:water,sphere:1.45,sphere]"]))


def test_max_levels_is_what_the_pyramid_warp_takes():
    import torch

    from snell_bench.imaging.pyramid import pyramid_warp

    for h, w in ((96, 160), (20, 20), (9, 64)):
        L = max_levels(h, w)
        ys, xs = torch.meshgrid(
            torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij"
        )
        coords = torch.stack([xs, ys], -1)[None]
        pyramid_warp(torch.rand(1, 3, h, w), coords, levels=L, collapse=False)
        with pytest.raises((RuntimeError, ValueError)):
            pyramid_warp(torch.rand(1, 3, h, w), coords, levels=L + 1, collapse=False)


@pytest.mark.skipif(__import__("torch").cuda.is_available(), reason="checks a machine without CUDA")
def test_an_explicit_cuda_device_without_cuda_is_an_error():
    with pytest.raises(
        ConfigError, match=r"model.device='cuda': this machine has no CUDA device; use model.device=cpu"
    ):
        check_config(compose(["model=tiny_flux", "model.device=cuda"]))


@pytest.mark.parametrize(
    "overrides,expected",
    [
        (["grid.scenes=[kitchen,kitchen]"], "grid.scenes lists 'kitchen' more than once"),
        (["grid.scenes=[]"], "grid.scenes=[]: must be a non-empty list"),
        (["grid.scenes=[nope]"], "grid.scenes: unknown scene 'nope'"),
        (["grid.presets=[fast,fast]"], "grid.presets lists 'fast' more than once"),
        (["grid.presets=[quick]"], "grid.presets: unknown preset 'quick'"),
        (["grid.objects=[sphere:abc]"], "grid.objects: entry 'sphere:abc': 'abc' is neither a number"),
        (["grid.variations=[-1]"], "grid.variations: entry -1 is not an integer >= 0"),
        (["grid.only=[nope]"], "grid.only: unknown axes ['nope']"),
        (
            ["+grid.axes.baseline='sampler.steps=4'", "grid.only=[baseline]"],
            "grid.axes.baseline: 'baseline' is reserved",
        ),
        (["grid.axes.steps='sampler.steps=4,4'", "grid.only=[steps]"], "duplicate setting label(s) ['steps=4']"),
    ],
)
def test_sweep_entries_are_checked(overrides, expected):
    with pytest.raises(ConfigError) as e:
        check_config(compose(["+experiment=tradeoff", *overrides]))
    assert expected in str(e.value), str(e.value)


@pytest.mark.parametrize(
    "override, choice",
    [
        ("reference.sampler=sobol", "orthogonal"),
        ("model.pano_prior=nope", "observed"),
        ("grid.on_change=ignore", "recompute"),
        ("scene.source=photo", "generated"),
        ("scene.depth_kind=disparity", "range"),
        ("job=nope", "export"),
        ("metrics.protocol=ours", "authors"),
        ("metrics.clip_text=both", "object"),
        ("method.prompt=both", "object"),
        ("warps.normals=smooth", "interpolated"),
    ],
)
def test_a_value_outside_its_choices_fails_when_composed(override, choice):
    """The choices are enums of the schema: Hydra names the override and OmegaConf the choices."""
    with pytest.raises(ConfigCompositionException) as e:
        compose([override])
    text = f"{e.value} {e.value.__cause__}"
    assert override in text and "expected one of" in text and choice in text, text


def test_a_method_kind_names_a_registered_kind_or_a_target():
    """method.kind is a registry name (built-in kinds, installed plugins), not a closed enum: an
    unknown one is found when checked, naming the kinds and method._target_."""
    with pytest.raises(ConfigError) as e:
        check_config(compose(["method.kind=magic"]))
    text = str(e.value)
    assert "method.kind='magic' is unknown" in text and "images" in text and "method._target_" in text
    with pytest.raises(ConfigError, match=r"method._target_='no_such_pkg.Thing' cannot be imported"):
        check_config(compose(["method._target_=no_such_pkg.Thing"]))
    check_config(compose(["method=images", "method.images=/tmp"]))  # a built-in kind


def test_the_choices_are_the_stages_own():
    """Each enum lists exactly what the stage that reads it accepts."""
    from snell_bench.config import METHOD_KINDS, PanoPrior, Protocol, RefSampler
    from snell_bench.methods import BUILTIN
    from snell_bench.metrics.functional import PROTOCOLS
    from snell_bench.render.pieces import SAMPLERS
    from snell_bench.scene.sources import PANO_PRIORS

    assert set(RefSampler.values()) == set(SAMPLERS)
    assert tuple(BUILTIN) == METHOD_KINDS
    assert set(Protocol.values()) == set(PROTOCOLS)
    assert set(PanoPrior.values()) == set(PANO_PRIORS)
