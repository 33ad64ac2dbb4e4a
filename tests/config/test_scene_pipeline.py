"""The scene pipeline a documented command runs: a text-to-image generator (FLUX.1-dev, the tiny
random FLUX) selects the paper's (I⁻ generated from p⁻; FLUX.1-dev adds MoGe-2 depth and SAM 3
placement), the CPU stand-ins keep procedural scenes, a photo keeps its own source, and a generator
on a procedural scene is a named choice that every record and table says."""

import subprocess
import sys

import pandas as pd
import pytest

from snell_bench.config import compose
from snell_bench.pipeline import apply_method, generator_on_procedural, initial_noise_record, scene_pipeline_record

PAPER_EXPERIMENTS = ["main", "ablation", "ior_sweep", "time_travel"]


def _cfg(*overrides):
    return compose([*overrides, "output_dir=/tmp/x"])


@pytest.mark.parametrize("experiment", PAPER_EXPERIMENTS)
def test_flux_dev_runs_the_papers_scene_pipeline(experiment):
    cfg = _cfg(f"+experiment={experiment}", "model=flux_dev", "preset=paper")
    assert str(cfg.scene.source) == "generated"
    assert cfg.depth.name == "moge2" and cfg.segment.name == "sam3"
    assert not generator_on_procedural(cfg) and scene_pipeline_record(cfg) == {}


@pytest.mark.parametrize("experiment", PAPER_EXPERIMENTS)
@pytest.mark.parametrize("model", ["analytic", "mixture", "sleeping"])
def test_the_cpu_stand_ins_stay_on_procedural_scenes(experiment, model):
    cfg = _cfg(f"+experiment={experiment}", f"model={model}")
    assert str(cfg.scene.source) == "procedural" and cfg.depth.name == "none" and cfg.segment.name == "ransac"
    assert not generator_on_procedural(cfg)


def test_the_tiny_models_swap_in_for_the_real_ones():
    cfg = _cfg("+experiment=main", "model=tiny_flux", "depth=tiny_depth_pro", "segment=tiny_sam3")
    assert str(cfg.scene.source) == "generated"
    assert (cfg.depth.name, cfg.segment.name) == ("tiny_depth_pro", "tiny_sam3")
    # the command line wins over the model's choice of depth and segmentation models
    cfg = _cfg("+experiment=main", "model=flux_dev", "depth=tiny_depth_pro", "segment=ransac")
    assert (str(cfg.scene.source), cfg.depth.name, cfg.segment.name) == ("generated", "tiny_depth_pro", "ransac")


@pytest.mark.parametrize("scene", ["living_room", "kitchen", "cave", "desert", "landscape"])
def test_every_paper_scene_is_generated_by_a_text_to_image_model(scene):
    """The grid composes each cell with ``scene=<name>``: the scene's config must not pin a source."""
    assert str(_cfg("model=flux_dev", f"scene={scene}").scene.source) == "generated"
    assert str(_cfg(f"scene={scene}").scene.source) == "procedural"


def test_a_photo_keeps_its_own_source_under_any_model():
    for model in ("flux_dev", "tiny_flux", "analytic"):
        assert str(_cfg("+experiment=photo", f"model={model}").scene.source) == "image"


def test_a_generator_on_a_procedural_scene_is_a_named_choice_and_recorded():
    cfg = apply_method(_cfg("+experiment=main", "model=flux_dev", "scene.source=procedural"))
    assert str(cfg.scene.source) == "procedural" and generator_on_procedural(cfg)
    assert scene_pipeline_record(cfg) == {"generator_on_procedural": True}


def test_the_provenance_line_says_when_a_generator_ran_on_procedural_scenes():
    from snell_bench.reports.collect import provenance_line

    rows = [
        {"model": "flux", "scene_source": "procedural", "status": "ok", "generator_on_procedural": True},
        {"model": "flux", "scene_source": "procedural", "status": "ok", "generator_on_procedural": True},
    ]
    line = provenance_line(pd.DataFrame(rows))
    assert "2 cells with a text-to-image generator on procedural scenes (scene.source=procedural)" in line
    plain = provenance_line(pd.DataFrame([{"model": "analytic", "scene_source": "procedural", "status": "ok"}]))
    assert "text-to-image generator" not in plain


def test_initial_noise_record_compares_the_two_draws():
    a, b = "sha256:" + "0" * 64, "sha256:" + "1" * 64
    assert initial_noise_record({"initial_noise": a}, {"initial_noise": a}) == {
        "initial_noise": {"i_minus": a, "main": a, "same": True}
    }
    assert initial_noise_record({"initial_noise": a}, {"initial_noise": b})["initial_noise"]["same"] is False
    assert initial_noise_record(None, {"initial_noise": a}) == {}  # a procedural scene: nothing to compare
    assert initial_noise_record({"initial_noise": a}, {}) == {}  # a method that did not sample


def test_cfg_job_shows_the_generated_source_moge2_and_sam3():
    """The documented Table 1 command, printed: the scene pipeline is visible before any work."""
    out = subprocess.run(
        [sys.executable, "-m", "snell_bench", "+experiment=main", "model=flux_dev", "preset=paper", "--cfg", "job"],
        capture_output=True,
        text=True,
        env={**__import__("os").environ, "HF_HUB_OFFLINE": "1"},
        check=True,
    ).stdout
    assert "  source: generated" in out
    assert "depth:\n  name: moge2" in out and "segment:\n  name: sam3" in out


def test_a_generated_scene_without_a_depth_estimator_stops_before_any_work():
    from snell_bench.config import ConfigError, check_config

    with pytest.raises(ConfigError, match="depth=tiny_depth_pro segment=tiny_sam3") as e:
        check_config(_cfg("+experiment=smoke", "model=tiny_flux", "scene.height=352"))
    assert "scene.source=procedural" in str(e.value)
    with pytest.raises(ConfigError, match="needs a text-to-image generator"):
        check_config(_cfg("+experiment=smoke", "scene.source=generated", "depth=tiny_depth_pro"))
    check_config(_cfg("+experiment=smoke", "model=tiny_flux", "scene.height=352", "depth=tiny_depth_pro"))


def test_a_named_blender_python_that_is_not_there_stops_before_any_work():
    from snell_bench.config import ConfigError, check_config

    with pytest.raises(ConfigError, match="reference.blender_python='/nonexistent/python': not an executable"):
        check_config(_cfg("+experiment=smoke", "recipe=authors", "reference.blender_python=/nonexistent/python"))
    check_config(_cfg("+experiment=smoke", "recipe=authors"))  # null: the installed one, or the cell says why not
