"""The default job through Hydra: config composition and the refraction preview."""

import json
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from PIL import Image

from snell_bench.config import register_configs

CONF = str(Path(__file__).resolve().parents[2] / "conf")
register_configs()


def make_cfg(overrides):
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return compose("config", overrides=overrides)


def test_root_config_composes_with_defaults():
    cfg = make_cfg(["output_dir=/tmp/x"])
    assert cfg.job == "preview" and cfg.scene.kind == "room" and cfg.object.shape == "sphere"
    assert cfg.scene.width == 1280 and cfg.scene.height == 720 and cfg.warps.pano_height == 1024
    assert "experiment" not in cfg  # kept out of the defaults list so +experiment=NAME works


def test_unknown_object_shape_and_missing_mesh_are_clear(tmp_path):
    from snell_bench.experiment.inputs import make_object

    cfg = make_cfg(["object=spot", "object.path=/nonexistent/fox.ply", f"output_dir={tmp_path}"])
    with pytest.raises(FileNotFoundError, match="object.path"):
        make_object(cfg.object)
    cfg = make_cfg(["object.shape=torus", f"output_dir={tmp_path}"])
    with pytest.raises(ValueError, match="object.shape"):
        make_object(cfg.object)


@pytest.mark.parametrize("scene,obj", [("living_room", "sphere"), ("landscape", "spot")])
def test_preview_writes_a_glass_composite(tmp_path, scene, obj):
    from snell_bench.experiment.preview import run_preview

    cfg = make_cfg(
        [
            f"scene={scene}",
            f"object={obj}",
            "scene.width=192",
            "scene.height=108",
            "scene.supersample=1",
            "warps.pano_height=64",
            "warps.cache_dir=null",
            f"output_dir={tmp_path}",
        ]
    )
    summary = run_preview(cfg)
    for name in ("I_minus.png", "mask.png", "warp.png", "panorama.png", "composite.png", "preview.png", "summary.json"):
        assert (tmp_path / name).is_file(), name
    assert summary["warps"]["object_pixels"] > 50
    i_minus = np.asarray(Image.open(tmp_path / "I_minus.png"))
    comp = np.asarray(Image.open(tmp_path / "composite.png"))
    mask = np.asarray(Image.open(tmp_path / "mask.png")) > 0
    assert i_minus.shape == comp.shape == (108, 192, 3)
    np.testing.assert_array_equal(comp[~mask], i_minus[~mask])  # unchanged outside the glass
    assert np.abs(comp[mask].astype(int) - i_minus[mask]).mean() > 5  # the glass shows something else
    json.loads((tmp_path / "summary.json").read_text())


def test_experiment_overrides_compose():
    cfg = make_cfg(["+experiment=quick", "output_dir=/tmp/x"])
    assert (cfg.scene.width, cfg.scene.height, cfg.warps.pano_height) == (640, 360, 256)
    assert cfg.object.shape == "sphere"  # untouched groups keep their defaults


@pytest.mark.parametrize("model", ["analytic", "tiny_flux"])
def test_generate_job_writes_images(tmp_path, model):
    from snell_bench.experiment.generate import run_generate

    cfg = make_cfg(
        [
            "job=generate",
            f"model={model}",
            "scene.width=128",
            "scene.height=64",
            "scene.supersample=1",
            "warps.pano_height=64",
            "warps.cache_dir=null",
            "sampler.steps=4",
            "sampler.progress=false",
            "sampler.dump_every=2",
            f"output_dir={tmp_path}",
        ]
    )
    summary = run_generate(cfg)
    for name in ("image.png", "panorama.png", "I_minus.png", "mask.png", "summary.json", "step000_main_sync.png"):
        assert (tmp_path / name).is_file(), name
    assert summary["model"] == model and summary["model_calls"]["pano"] == 4
    assert np.asarray(Image.open(tmp_path / "image.png")).shape == (64, 128, 3)


def test_presets_and_experiments_compose_in_order():
    """An experiment picks the balanced preset; preset=NAME on the command line replaces that
    choice; single keys override both."""
    bal = make_cfg(["+experiment=smoke", "output_dir=/tmp/x"])
    assert (bal.scene.width, bal.scene.height, bal.warps.pano_height, bal.sampler.steps) == (640, 360, 512, 20)
    paper = make_cfg(["+experiment=ablation", "preset=paper", "output_dir=/tmp/x"])
    assert (paper.scene.width, paper.scene.height, paper.warps.pano_height) == (1280, 720, 1024)
    assert paper.grid.methods[0] == "snellcaster"  # the experiment's grid is kept
    fast = make_cfg(["preset=fast", "sampler.steps=6", "output_dir=/tmp/x"])
    assert (fast.sampler.steps, fast.sampler.levels, fast.warps.pano_height, fast.reference.spp) == (6, 3, 256, 4)
    assert make_cfg(["output_dir=/tmp/x"]).scene.width == 1280  # no preset: the schema's paper size


def test_generate_job_applies_the_methods_switches(tmp_path):
    from snell_bench.experiment.generate import run_generate

    cfg = make_cfg(["job=generate", "method=adaptive", "object.ior=1.05", "scene.width=128", "scene.height=64",
                    "scene.supersample=1", "warps.pano_height=64", "warps.cache_dir=null", "sampler.steps=3",
                    "sampler.progress=false", "method.sampler.skip_panorama_above=0.0", f"output_dir={tmp_path}"])
    summary = run_generate(cfg)
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved["decisions"]["panorama"] == {"used": False, "observed_share": pytest.approx(saved["decisions"]["panorama"]["observed_share"]), "skip_above": 0.0}
    assert summary["model_calls"]["pano"] == 0
    assert saved["decisions"]["reflection"]["min_fresnel"] == 0.01  # from conf/method/adaptive.yaml
    assert saved["warps"]["far_background"]["tolerance_px"] == 1.0
    assert not (tmp_path / "panorama.png").exists()
