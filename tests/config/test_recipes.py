"""The recipes: ``recipe=paper`` (the default) and ``recipe=authors`` set every switch of the recipe
table, with the values read from the paper's text and the authors' released code (written out here,
not read from the table), and win over a preset where both set a key."""

from pathlib import Path

import pytest
from omegaconf import OmegaConf

from snell_bench.config import compose, group_options
from snell_bench.config.recipes import RECIPES, SWITCHES, recipe_values

PAPER_PAGE = Path(__file__).resolve().parents[2] / "docs" / "paper.md"

#: What the paper's text says, switch by switch (DESIGN §4-5).
PAPER = {
    "sampler.schedule": "flux",
    "sampler.sde": False,
    "sampler.encode": "mean",
    "sampler.quantize": False,
    "sampler.sync_last_step": True,
    "sampler.tt_mode": "guided",
    "sampler.tt_renoise": "exact",
    "sampler.tt_window_floor": False,
    "sampler.lpw_pano": True,
    "sampler.dpa_domain": "image",
    "sampler.pano_to_main": "frame",
    "sampler.latent_dtype": "float32",
    "model.dtype": None,
    "model.vae_tiling": True,
    "depth.edge_rtol": None,
    "segment.instance": "union",
    "object.anchor": "plane",
    "warps.back_faces": False,
    "warps.normals": "interpolated",
    "warps.recipe_max_bounces": None,
    "warps.half_pixel_shift": False,
    "warps.reflection_parallax": True,
    "warps.pano_center": "bbox",
    "warps.pano_axes": "level",
    "reference.reflection": False,
    "reference.renderer": "mitsuba",
    "reference.ior": None,
    "reference.mask": "unobserved",
    "metrics.protocol": "paper",
    "metrics.files": "png",
    "baselines.object_phrase": None,
    "baselines.flux_steps": None,
    "baselines.fill_steps": None,
    "baselines.fill_guidance": None,
    "baselines.qwen_model_id": "Qwen/Qwen-Image",
    "baselines.qwen_cfg": True,
    "relight.lora": None,
}

#: What the authors' code does (inference.py, generate_dual_view.py, their scheduler, callbacks,
#: eval/masked_metrics.py, utils/render_gt.py, utils/add_shadows.py).
AUTHORS = {
    "sampler.schedule": "linear",
    "sampler.sde": True,
    "sampler.encode": "sample",
    "sampler.quantize": True,
    "sampler.sync_last_step": False,
    "sampler.tt_mode": "guided",
    "sampler.tt_renoise": "euler_maruyama",
    "sampler.tt_window_floor": True,
    "sampler.lpw_pano": False,
    "sampler.dpa_domain": "image",
    "sampler.pano_to_main": "frame",
    "sampler.latent_dtype": "float16",
    "model.dtype": "float16",
    "model.vae_tiling": False,
    "depth.edge_rtol": 0.1,
    "segment.instance": "first",
    "object.anchor": "centre_ray",
    "warps.back_faces": True,
    "warps.normals": "face",
    "warps.recipe_max_bounces": 12,
    "warps.half_pixel_shift": True,
    "warps.reflection_parallax": False,
    "warps.pano_center": "centroid",
    "warps.pano_axes": "camera",
    "reference.reflection": False,
    "reference.renderer": "cycles",
    "reference.ior": 1.5,
    "reference.mask": "authors",
    "metrics.protocol": "authors",
    "metrics.files": "jpeg",
    "baselines.object_phrase": "a solid transparent glass {object}",
    "baselines.flux_steps": 28,
    "baselines.fill_steps": 30,
    "baselines.fill_guidance": 30.0,
    "baselines.qwen_model_id": "Qwen/Qwen-Image-2512",
    "baselines.qwen_cfg": False,
    "relight.lora": "kontext-community/relighting-kontext-dev-lora-v3",
    "relight.candidates": 3,
}


def _values(cfg, keys):
    return {k: OmegaConf.select(cfg, k) for k in keys}


def test_the_recipe_group_ships_both_recipes():
    assert sorted(group_options("recipe")) == sorted(RECIPES)


def test_the_table_holds_the_paper_and_the_authors_values():
    assert recipe_values("paper") == PAPER
    assert recipe_values("authors") == AUTHORS
    with pytest.raises(ValueError, match="recipe=paper or recipe=authors"):
        recipe_values("mine")


@pytest.mark.parametrize("name,expected", [("paper", PAPER), ("authors", AUTHORS)])
def test_a_composed_recipe_sets_every_switch(name, expected):
    cfg = compose([f"recipe={name}", "output_dir=/tmp/x"])
    assert cfg.recipe == name
    assert _values(cfg, expected) == expected


def test_paper_is_the_default():
    cfg = compose(["output_dir=/tmp/x"])
    assert cfg.recipe == "paper"
    assert _values(cfg, PAPER) == PAPER


def test_the_recipe_wins_over_the_preset_and_the_command_line_wins_over_both():
    cfg = compose(["preset=paper", "recipe=authors", "output_dir=/tmp/x"])
    assert cfg.relight.candidates == 3  # the preset says 20
    assert cfg.sampler.steps == 20 and cfg.scene.width == 1280  # the preset's cost settings stay
    cfg = compose(["recipe=authors", "sampler.sde=false", "output_dir=/tmp/x"])
    assert cfg.sampler.sde is False and cfg.sampler.encode == "sample"


def test_the_authors_interaction_limit_leaves_the_presets_key_alone():
    """The presets set warps.max_bounces (a cost setting); the authors' 12 is a key of its own that
    replaces it in compute_warps, whatever the preset and the order of the defaults."""
    for preset, bounces in (("fast", 4), ("paper", 8)):
        cfg = compose([f"preset={preset}", "recipe=authors", "output_dir=/tmp/x"])
        assert (cfg.warps.max_bounces, cfg.warps.recipe_max_bounces) == (bounces, 12)
        cfg = compose([f"preset={preset}", "output_dir=/tmp/x"])
        assert (cfg.warps.max_bounces, cfg.warps.recipe_max_bounces) == (bounces, None)


def test_an_experiment_keeps_the_recipe():
    cfg = compose(["+experiment=ablation", "recipe=authors", "output_dir=/tmp/x"])
    assert _values(cfg, AUTHORS) == AUTHORS


@pytest.mark.parametrize("method", ["t2i", "inpaint"])
def test_the_baselines_keep_a_plain_pipeline_step_under_either_recipe(method):
    """The authors' baselines are plain diffusers pipelines (deterministic Euler on FLUX's shifted
    schedule): the recipe's sampler switches are the synchronised sampler's, not theirs."""
    from snell_bench.pipeline import apply_method

    for recipe in RECIPES:
        s = apply_method(compose([f"recipe={recipe}", f"method={method}", "output_dir=/tmp/x"])).sampler
        assert (s.sync, s.sde, s.schedule, s.stochastic) == ("none", False, "flux", False), recipe


def test_an_unknown_recipe_names_the_choices():
    from hydra.errors import ConfigCompositionException

    with pytest.raises(ConfigCompositionException, match="recipe"):
        compose(["recipe=mine", "output_dir=/tmp/x"])


def test_the_docs_table_lists_every_switch():
    text = PAPER_PAGE.read_text()
    section = text[text.index("## The recipes, switch by switch") :]
    for s in SWITCHES:
        assert f"`{s.key}`" in section, s.key
