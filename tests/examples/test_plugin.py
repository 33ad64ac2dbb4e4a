"""The example plugin (examples/snell_bench_example), installed with pip as a user would, runs in
the smoke grid beside Snellcaster: its method (by entry point, and by a method YAML of a user's
config folder) and its metric appear in every table; the standalone script makes images from an
exported kit alone, and method=images scores them."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "snell_bench_example"
TINY = [
    "scene.width=160",
    "scene.height=96",
    "warps.pano_height=64",
    "sampler.steps=8",
    "reference.spp=4",
    "reference.true_spp=1",
]
METHODS = "[snellcaster,t2i,physics_only,physics_only_refraction,images]"


def _run(args, env, cwd):
    proc = subprocess.run(args, env=env, cwd=cwd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"{args}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc


@pytest.fixture(scope="module")
def plugged(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("plugin")
    source = tmp / "src"
    shutil.copytree(EXAMPLE, source)  # pip builds in the source folder: keep the repository clean
    site = tmp / "site"
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "-q",
            "--no-deps",
            "--no-build-isolation",
            "--target",
            str(site),
            str(source),
        ],
        dict(os.environ),
        tmp,
    )
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "PYTHONPATH": os.pathsep.join([str(site), str(REPO)])}
    common = ["+experiment=smoke", *TINY, f"warps.cache_dir={tmp / 'cache'}", f"export.dir={tmp / 'kits'}"]
    _run([sys.executable, "-m", "snell_bench", *common, "job=export", "export.warps=true"], env, tmp)
    made = _run(
        [
            sys.executable,
            str(REPO / "examples" / "make_images.py"),
            str(tmp / "kits" / "smoke"),
            str(tmp / "made"),
            "--score",
        ],
        env,
        tmp,
    )
    _run(
        [
            sys.executable,
            "-m",
            "snell_bench",
            *common,
            f"grid.methods={METHODS}",
            f"method.images={tmp / 'made'}",
            "metrics.extra=[masked_ssim]",
            f"hydra.searchpath=[file://{REPO / 'examples' / 'conf'}]",
        ],
        env,
        tmp,
    )
    return tmp, made.stdout


def _record(tmp, group, method):
    return json.loads((tmp / "runs" / "smoke" / group / "sphere" / method / "metrics.json").read_text())


def test_the_plugins_method_and_metric_are_in_every_table(plugged):
    tmp, _ = plugged
    table = (tmp / "reports" / "smoke" / "method_table.md").read_text()
    rows = [line.split("|")[1].strip() for line in table.splitlines() if line.startswith("| ")]
    for row in ("Physics only (I⁻ through π^R)", "Physics only, refraction alone", "Snellcaster", "Images: made"):
        assert row in rows, row
    assert "SSIM (masked) ↑" in table
    assert "SSIM (masked)" in (tmp / "reports" / "smoke" / "scene_table.md").read_text()
    page = (tmp / "reports" / "smoke" / "index.html").read_text()
    assert "Physics only (I⁻ through π^R)" in page and "SSIM (masked)" in page


def test_every_cell_scored_the_plugins_metric(plugged):
    tmp, _ = plugged
    for group in ("living_room-0", "kitchen-0"):
        for method in ("snellcaster", "t2i", "physics_only", "physics_only_refraction", "images"):
            rec = _record(tmp, group, method)
            assert rec["status"] == "ok", (group, method, rec.get("reason"))
            assert -1.0 <= rec["metrics"]["masked_ssim"] <= 1.0, (group, method)
        refr = _record(tmp, group, "physics_only_refraction")
        assert refr["method_kind"] == "physics_only" and refr["physics_only"] == {"reflection": False}


def test_the_scripts_images_are_the_physics_only_answer(plugged):
    """make_images.py samples the kit's I⁻ (8-bit) at the kit's π^R with scipy; the plugin samples
    the float I⁻ at the same π^R with kornia: both bilinear, so inside the object they differ by
    the 8-bit rounding of I⁻ (at most 0.5/255) and the rounding of the output, at most one level."""
    from PIL import Image

    tmp, stdout = plugged
    for group in ("living_room-0", "kitchen-0"):
        ours = np.asarray(Image.open(tmp / "made" / group / "sphere.png")).astype(int)
        plugin = tmp / "runs" / "smoke" / group / "sphere" / "physics_only_refraction" / "image.png"
        assert np.abs(ours - np.asarray(Image.open(plugin)).astype(int)).max() <= 1, group
        scored = _record(tmp, group, "images")["metrics"]
        assert f"{group}/sphere: " in stdout and f"psnr {scored['psnr']:.4g}" in stdout  # --score: the same number


def test_the_masked_ssim_is_scikit_images(monkeypatch):
    """Over the pixels scikit-image averages (all but its window's half-width, 5 px for sigma 1.5, at
    the border) the plugin's value is scikit-image's own mean SSIM; identical images score 1."""
    from skimage.metrics import structural_similarity

    from snell_bench.metrics import ScoreInputs

    monkeypatch.syspath_prepend(str(EXAMPLE))
    from snell_bench_example.metrics import GRAY, MASKED_SSIM

    rng = np.random.default_rng(1)
    gen, ref = rng.random((40, 48, 3)), rng.random((40, 48, 3))
    full = np.zeros((40, 48), bool)
    full[5:-5, 5:-5] = True
    expected = structural_similarity(
        gen @ GRAY, ref @ GRAY, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False
    )
    assert MASKED_SSIM.compute(ScoreInputs(gen, ref, full)) == pytest.approx(expected, rel=1e-12)
    assert MASKED_SSIM.compute(ScoreInputs(gen, gen, full)) == pytest.approx(1.0, abs=1e-12)
    sys.modules.pop("snell_bench_example.metrics", None)
    sys.modules.pop("snell_bench_example", None)
