"""The paper's ablation under both recipes, end to end from the command line: every cell finishes on
the tiny random FLUX and on the mixture stand-in, and the report holds Tables 1-4 with every metric
column (a metric without weights is a column of "—" with its reason, not a missing column)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

#: A small size: the ablation's 6 scenes x 7 methods in a few seconds per cell.
SMALL = [
    "scene.width=96",
    "scene.height=64",
    "warps.pano_height=32",
    "warps.cache_dir=null",
    "sampler.steps=6",
    "sampler.levels=3",
    "reference.spp=8",
    "reference.cycles_spp=16",  # recipe=authors renders the reference in Blender Cycles
    "reference.unobserved_spp=4",
    "reference.true_spp=1",
    "relight.candidates=1",
]

#: Column headers of the paper's tables: Table 1 (CLIP, ImageReward, PSNR, LPIPS), Table 2 (MAE,
#: PSNR, LPIPS), Table 3 (per scene: CLIP, ImageReward, PSNR, LPIPS), Table 4 (MAE, PSNR, LPIPS,
#: CLIP, ImageReward).
EVERY_METRIC = ("PSNR", "MAE", "LPIPS", "CLIP", "ImageReward")


@pytest.mark.slow
@pytest.mark.parametrize("model", ["tiny_flux", "mixture"])
@pytest.mark.parametrize("recipe", ["paper", "authors"])
def test_the_ablation_runs_under_each_recipe(tmp_path, recipe, model):
    cmd = [
        sys.executable,
        "-m",
        "snell_bench",
        "+experiment=ablation",
        f"recipe={recipe}",
        f"model={model}",
        # a text-to-image model runs the paper's scene pipeline: the tiny depth and segmentation models
        *(["depth=tiny_depth_pro", "segment=tiny_sam3"] if model == "tiny_flux" else []),
        # the authors' centre-ray anchor needs a surface under the segmented box's centre, which random
        # models do not give at 96 x 64 (the tiny depth's floor is cut at depth edges near the horizon):
        # their placement is tested on hand-made depth in tests/scene/test_placement_anchor.py
        *(["object.anchor=plane"] if model == "tiny_flux" and recipe == "authors" else []),
        *SMALL,
        f"runs_dir={tmp_path / 'runs'}",
        f"reports_dir={tmp_path / 'reports'}",
        f"hydra.run.dir={tmp_path / 'log'}",
    ]
    subprocess.run(cmd, cwd=REPO, check=True, timeout=1200, env={**os.environ, "HF_HUB_OFFLINE": "1"})
    records = [json.loads(p.read_text()) for p in (tmp_path / "runs" / "ablation").rglob("metrics.json")]
    assert len(records) == 6 * 7
    failed = [(r.get("scene"), r.get("method"), r.get("error")) for r in records if r["status"] != "ok"]
    assert not failed
    assert all(r.get("recipe", recipe) == recipe for r in records)
    reports = tmp_path / "reports" / "ablation"
    text = "\n".join(p.read_text() for p in sorted(reports.rglob("*.md")))
    for table in ("Table 1", "Table 2", "Table 3", "Table 4"):
        assert table in text, table
    for metric in EVERY_METRIC:
        assert metric in text, metric
