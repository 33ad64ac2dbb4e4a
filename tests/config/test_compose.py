"""The configuration: the groups shipped in the package, composition, the structured schema."""

import importlib.resources
import os
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from snell_bench.config import compose, group_options
from snell_bench.config.sampler import SamplerSettings

REPO = Path(__file__).resolve().parents[2]


def test_config_groups_ship_inside_the_package():
    conf = importlib.resources.files("snell_bench.conf")
    assert conf.joinpath("config.yaml").is_file()
    for group in ("scene", "object", "method", "model", "preset", "experiment"):
        assert group_options(group), group
    assert "snellcaster" in group_options("method") and "base_method" not in group_options("method")


def test_compose_records_its_overrides_and_later_overrides_win():
    cfg = compose(
        [
            "+experiment=smoke",
            "scene=kitchen",
            "scene=office",
            "sampler.steps=3",
            "sampler.steps=5",
            "output_dir=/tmp/x",
        ]
    )
    assert cfg.scene.name == "office" and cfg.sampler.steps == 5
    assert list(cfg.overrides) == [
        "+experiment=smoke",
        "scene=kitchen",
        "scene=office",
        "sampler.steps=3",
        "sampler.steps=5",
        "output_dir=/tmp/x",
    ]


@pytest.mark.parametrize(
    "group", ["scene", "object", "method", "model", "preset", "recipe", "experiment", "depth", "segment"]
)
def test_every_entry_of_every_group_composes(group):
    """Each file of a group composes with the schema, and a method's switches are keys of the
    sampler and warp schemas (merging them would fail otherwise)."""
    from snell_bench.pipeline import apply_method

    for name in group_options(group):
        prefix = "+" if group == "experiment" else ""
        cfg = apply_method(compose([f"{prefix}{group}={name}", "output_dir=/tmp/x"]))
        assert isinstance(OmegaConf.to_object(cfg.sampler), SamplerSettings), (group, name)
        if group == "object":
            factories = ("snell_bench.scene.objects.GlassObject.", "snell_bench.scene.vessels.")
            assert cfg.object.factory._target_.startswith(factories), name
        if group == "model":
            assert cfg.model.generator._target_.startswith("snell_bench.models."), name


def test_unknown_keys_are_errors():
    from hydra.errors import ConfigCompositionException

    with pytest.raises(ConfigCompositionException):
        compose(["sampler.stepz=3", "output_dir=/tmp/x"])
    from snell_bench.pipeline import apply_method

    cfg = compose(["+method.sampler.dpaa=false", "output_dir=/tmp/x"])  # a method switch the sampler lacks
    with pytest.raises(Exception, match="dpaa"):
        apply_method(cfg)


def test_check_reproducible_names_the_changed_key():
    from snell_bench.experiment.plan import check_reproducible

    cfg = compose(["+experiment=smoke", "output_dir=/tmp/x"])
    check_reproducible(cfg)
    cfg.reference.spp = 3
    with pytest.raises(ValueError, match="reference.spp"):
        check_reproducible(cfg)


def test_cli_prints_the_composed_config():
    out = subprocess.run(
        [sys.executable, "-m", "snell_bench", "+experiment=smoke", "--cfg", "job"],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
        env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )
    cfg = OmegaConf.create(out.stdout)
    assert cfg.experiment_name == "smoke" and cfg.grid.methods == ["snellcaster", "t2i"]


@pytest.mark.parametrize(
    "overrides, run_dir, job_name",
    [
        (["+experiment=smoke"], "runs/smoke/logs/", "smoke"),
        (["+experiment=ablation", "runs_dir=/data/r"], "/data/r/ablation/logs/", "ablation"),
        (["+experiment=tradeoff"], "runs/tradeoff/logs/", "tradeoff"),
        (["job=preview", "scene=kitchen", "object=fox"], "runs/preview/kitchen-0/fox", "default"),
    ],
)
def test_a_sweep_logs_under_its_experiment(overrides, run_dir, job_name):
    """Each sweep's Hydra log goes to ``<runs_dir>/<experiment>/logs/<time>/<experiment>.log``, so
    no grid overwrites another's; a preview keeps its folder per scene and object."""
    from hydra import compose as hydra_compose

    from snell_bench.config import config_context

    with config_context():
        cfg = hydra_compose(config_name="config", overrides=overrides, return_hydra_config=True)
    assert str(cfg.hydra.run.dir).startswith(run_dir), cfg.hydra.run.dir
    assert cfg.hydra.job.name == job_name
    assert str(cfg.hydra.sweep.dir).startswith(run_dir.split("/logs/")[0] if "/logs/" in run_dir else "runs/default")
