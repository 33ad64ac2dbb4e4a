"""scene.source=generated: I⁻ from p⁻ by the generator at the cell's seed, depth and intrinsics from
a depth estimator, the object placed on the segmented surface, every stage and the cache; tiny
random-weight models (their outputs mean nothing, so the supporting plane is fixed here)."""

import json

import numpy as np
import pytest

from snell_bench.config import compose

TINY = [
    "+experiment=smoke",
    "scene.source=generated",
    "model=tiny_flux",
    "depth=tiny_depth_pro",
    "segment=tiny_sam3",
    "scene.width=96",
    "scene.height=64",
    "warps.pano_height=32",
    "warps.cache_dir=null",
    "sampler.steps=2",
    "sampler.levels=2",
    "reference.spp=1",
    "grid.scenes=[living_room]",
    "grid.methods=[snellcaster,t2i]",
    "grid.report=false",
]


@pytest.fixture
def fixed_plane(monkeypatch):
    """A table 0.3 below the camera, 2 in front (random depth has no real plane)."""
    from snell_bench.scene import placement

    calls = []

    def plane(depth, camera, **kwargs):
        calls.append(kwargs)
        return placement.SupportPlane(
            point=np.array([0.0, 0.3, 2.0]),
            normal=np.array([0.0, -1.0, 0.0]),
            inliers=100,
            pixel=np.array([48.0, 40.0]),
        )

    monkeypatch.setattr(placement, "find_support_plane", plane)
    return calls


def test_generated_scene_runs_every_stage_and_caches_its_image(tmp_path, fixed_plane):
    from snell_bench.experiment.runner import run_grid

    cfg = compose(
        [*TINY, f"scene.cache_dir={tmp_path / 'scenes'}", f"runs_dir={tmp_path / 'runs'}", f"output_dir={tmp_path}"]
    )
    summary = run_grid(cfg)
    assert summary["ok"] == 2 and summary["failed"] == 0, summary
    cells = {
        m: json.loads((tmp_path / f"runs/smoke/living_room-0/sphere/{m}/metrics.json").read_text())
        for m in ("snellcaster", "t2i")
    }
    info = cells["snellcaster"]["scene_info"]
    assert info["seed"] == 0 and info["cached"] is False and "clean, empty top" in info["prompt"]  # p⁻, variation 0
    assert cells["t2i"]["scene_info"]["seed"] == 0  # the baselines share the scene's seed
    assert cells["snellcaster"]["scene_source"] == "generated" and cells["snellcaster"]["model"] == "tiny_flux"
    assert fixed_plane and fixed_plane[0]["region"].shape == (64, 96)  # the segmented surface was used
    cached = list((tmp_path / "scenes").glob("*/I_minus.npy"))
    assert len(cached) == 1
    saved = (
        np.asarray(
            __import__("PIL.Image", fromlist=["Image"]).open(
                tmp_path / "runs/smoke/living_room-0/sphere/_inputs/I_minus.png"
            ),
            np.float64,
        )
        / 255
    )
    np.testing.assert_allclose(saved, np.load(cached[0]), atol=0.5 / 255 + 1e-6)
    # a second run recomputes the cells but reads I⁻ from the cache, and gives the same images
    again = run_grid(
        compose(
            [
                *TINY,
                f"scene.cache_dir={tmp_path / 'scenes'}",
                f"runs_dir={tmp_path / 'runs'}",
                "grid.recompute=true",
                f"output_dir={tmp_path}",
            ]
        )
    )
    assert again["ok"] == 2
    redo = json.loads((tmp_path / "runs/smoke/living_room-0/sphere/snellcaster/metrics.json").read_text())
    assert redo["scene_info"]["cached"] is True and redo["metrics"] == cells["snellcaster"]["metrics"]


def test_generated_scene_needs_a_text_to_image_model_and_a_depth_estimator(tmp_path):
    from snell_bench import pipeline

    with pytest.raises(ValueError, match="model=tiny_flux"):
        pipeline.load_scene(compose(["scene.source=generated", "output_dir=/tmp/x"]))  # analytic: built from a scene
    with pytest.raises(ValueError, match="depth estimator"):
        pipeline.load_scene(
            compose(
                [
                    "scene.source=generated",
                    "model=tiny_flux",
                    "scene.width=96",
                    "scene.height=64",
                    "sampler.steps=1",
                    f"scene.cache_dir={tmp_path}",
                    "output_dir=/tmp/x",
                ]
            )
        )


def test_the_real_models_are_named_by_the_same_keys():
    cfg = compose(["scene.source=generated", "model=flux_dev", "depth=moge2", "segment=sam3", "output_dir=/tmp/x"])
    assert cfg.model.generator._target_.endswith("FluxGenerator.from_pretrained")
    assert cfg.depth.estimator._target_.startswith("snell_bench.models.depth.MoGe2")
    assert cfg.segment.segmenter._target_.endswith("Sam3Segmenter") and cfg.segment.path == "facebook/sam3"
    assert cfg.scene.surface == "polished wooden coffee table"
