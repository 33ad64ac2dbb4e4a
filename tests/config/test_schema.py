"""The schema: each node's dataclass checks its own ranges; choices are enums that read as strings."""

import json

import pytest
from omegaconf import OmegaConf

from snell_bench.config import (
    Config,
    ConfigError,
    ModelsConfig,
    ObjectConfig,
    ReferenceConfig,
    SceneConfig,
    Source,
    WarpConfig,
    compose,
)


@pytest.mark.parametrize(
    "node, kwargs, expected",
    [
        (SceneConfig, {"variation": -1}, "scene.variation=-1: must be an integer >= 0"),
        (SceneConfig, {"fov_deg": 180.0}, "scene.fov_deg=180.0: must be at most 150 degrees"),
        (ObjectConfig, {"size": float("nan")}, "object.size=nan: must be a finite number > 0 or null"),
        (ObjectConfig, {"ior": "unobtainium"}, "object.ior='unobtainium': unknown material"),
        (ObjectConfig, {"up_axis": "w"}, "object.up_axis='w': use x, y or z"),
        (WarpConfig, {"max_bounces": 0}, "warps.max_bounces=0: must be an integer >= 1"),
        (ReferenceConfig, {"unobserved_threshold": 2.0}, "reference.unobserved_threshold=2.0: must be a number in"),
        (ModelsConfig, {"memory_gb": -1.0}, "models.memory_gb=-1.0: must be a finite number > 0 or null"),
    ],
)
def test_a_node_checks_its_own_ranges(node, kwargs, expected):
    with pytest.raises(ConfigError) as e:
        node(**kwargs)
    assert expected in str(e.value), str(e.value)


def test_all_problems_of_a_node_at_once():
    with pytest.raises(ConfigError) as e:
        SceneConfig(variation=-1, seed_offset=-2)
    assert len(e.value.problems) == 2


def test_the_defaults_pass_and_turning_a_composed_node_into_its_dataclass_checks_it():
    OmegaConf.structured(Config)  # builds every node with its defaults
    cfg = compose(["scene.variation=-3"])  # composing checks types and choices, not ranges
    with pytest.raises(ConfigError, match="scene.variation=-3"):
        OmegaConf.to_object(cfg.scene)


def test_a_choice_reads_writes_and_hashes_as_its_string():
    cfg = compose(["scene.source=image"])
    src = cfg.scene.source
    assert src is Source.image and src == "image" and str(src) == "image" and f"{src}" == "image"
    assert "source: image\n" in OmegaConf.to_yaml(cfg.scene)
    assert json.dumps({"s": src}) == '{"s": "image"}'
