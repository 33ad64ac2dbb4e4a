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
    "reference.reflection": False,
    "metrics.protocol": "paper",
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
    "reference.reflection": False,
    "metrics.protocol": "authors",
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
