"""The documented commands of the paper's tables with only the tiny models swapped in
(``model=tiny_flux depth=tiny_depth_pro segment=tiny_sam3``): the paper's scene pipeline end to end
on CPU (I⁻ generated from p⁻ at the cell's seed, depth estimated, the object placed on the
segmented surface), every cell ok, and records that show the scene source, I⁻'s seed and the main
branch started from I⁻'s own noise."""

import json

import numpy as np
import pytest

from snell_bench.config import compose
from snell_bench.experiment.runner import run_grid

TINY_MODELS = ["model=tiny_flux", "depth=tiny_depth_pro", "segment=tiny_sam3"]
SMALL = [
    "scene.width=96",
    "scene.height=64",
    "warps.pano_height=32",
    "sampler.steps=2",
    "sampler.levels=2",
    "reference.spp=2",
    "reference.unobserved_spp=4",
]


def _records(root, experiment):
    return {
        p.parent.relative_to(root / experiment).as_posix(): json.loads(p.read_text())
        for p in sorted((root / experiment).rglob("metrics.json"))
        if "_inputs" not in p.parts
    }


def _check_scene_pipeline(records, sampled=("snellcaster", "t2i")):
    assert records
    for name, r in records.items():
        assert r["status"] == "ok", (name, r.get("reason"))
        assert r["scene_source"] == "generated" and "generator_on_procedural" not in r
        assert r["scene_info"]["seed"] == r["variation"]  # seed 0 + the variation: I⁻'s seed is the cell's
        assert "clean, empty" in r["scene_info"]["prompt"] or "empty" in r["scene_info"]["prompt"]  # p⁻
        if r["method"] in sampled:
            noise = r["initial_noise"]
            assert noise["same"] is True and noise["i_minus"] == noise["main"], name


def test_the_main_command_with_the_tiny_models_runs_the_papers_scene_pipeline(tmp_path):
    cfg = compose(
        [
            "+experiment=main",
            *TINY_MODELS,
            *SMALL,
            "grid.scenes=[living_room]",
            "grid.variations=[0]",
            "grid.objects=[sphere]",
            "grid.methods=[snellcaster,t2i]",
            f"scene.cache_dir={tmp_path / 'scenes'}",
            f"runs_dir={tmp_path / 'runs'}",
            f"reports_dir={tmp_path / 'reports'}",
            f"output_dir={tmp_path}",
        ]
    )
    summary = run_grid(cfg)
    assert summary["ok"] == 2 and summary["failed"] == summary["skipped"] == 0, summary
    records = _records(tmp_path / "runs", "main")
    _check_scene_pipeline(records)
    # the object stands on the tiny depth model's floor, 0.5 m below the camera (y down)
    placed = np.asarray(
        __import__("trimesh").load(tmp_path / "runs/main/living_room-0/sphere/_inputs/object.ply").vertices
    )
    assert abs(placed[:, 1].max() - 0.5) < 0.01
    table = (tmp_path / "reports/main/method_table.md").read_text()
    assert "scenes: generated" in table and "text-to-image generator on procedural" not in table


def test_a_named_procedural_scene_under_a_text_to_image_generator_is_said_under_every_table(tmp_path):
    cfg = compose(
        [
            "+experiment=smoke",
            "model=tiny_flux",
            "scene.source=procedural",
            *SMALL,
            "grid.scenes=[living_room]",
            "grid.methods=[t2i]",
            f"runs_dir={tmp_path / 'runs'}",
            f"reports_dir={tmp_path / 'reports'}",
            f"output_dir={tmp_path}",
        ]
    )
    assert run_grid(cfg)["ok"] == 1
    (record,) = _records(tmp_path / "runs", "smoke").values()
    assert record["scene_source"] == "procedural" and record["generator_on_procedural"] is True
    for table in (tmp_path / "reports/smoke").glob("*_table.md"):
        assert "1 cell with a text-to-image generator on procedural scenes" in table.read_text(), table.name


@pytest.mark.slow
def test_every_method_of_the_main_grid_runs_with_the_tiny_models(tmp_path):
    """Table 1's six methods (Snellcaster, the FLUX text-to-image and Fill baselines, FLUX.2,
    Qwen-Image, SD3.5) on two scenes and two objects of the paper's grid."""
    cfg = compose(
        [
            "+experiment=main",
            *TINY_MODELS,
            *SMALL,
            "grid.scenes=[living_room,cave]",
            "grid.variations=[0]",
            "grid.objects=[sphere,fox]",
            f"scene.cache_dir={tmp_path / 'scenes'}",
            f"runs_dir={tmp_path / 'runs'}",
            f"reports_dir={tmp_path / 'reports'}",
            f"output_dir={tmp_path}",
        ]
    )
    summary = run_grid(cfg)
    assert summary["ok"] == 24 and summary["failed"] == summary["skipped"] == 0, summary
    records = _records(tmp_path / "runs", "main")
    _check_scene_pipeline(records)
    # the external baselines ran tiny random pipelines of their own architectures (model.pipelines)
    classes = {
        "flux2_dev": "Flux2Pipeline",
        "qwen_image": "QwenImagePipeline",
        "sd35_large": "StableDiffusion3Pipeline",
    }
    for name, r in records.items():
        if r["method"] in classes:
            assert r["pipeline"]["pipeline"] == classes[r["method"]], name
