"""The generation job: images, the full prompt, the method's switches, its summary."""

import json

import numpy as np
import pytest
import torch
from PIL import Image

from snell_bench.config import compose

TINY = [
    "job=generate",
    "scene.width=128",
    "scene.height=64",
    "scene.supersample=1",
    "warps.pano_height=64",
    "warps.cache_dir=null",
    "sampler.steps=4",
    "sampler.progress=false",
]


@pytest.mark.parametrize("model", ["analytic", "tiny_flux"])
def test_generate_job_writes_images(tmp_path, model):
    from snell_bench.experiment.generate import run_generate

    source = ["scene.source=procedural"] if model == "tiny_flux" else []  # a generator on a procedural scene
    summary = run_generate(
        compose([*TINY, f"model={model}", *source, "sampler.dump_every=2", f"output_dir={tmp_path}"])
    )
    for name in ("image.png", "panorama.png", "I_minus.png", "mask.png", "summary.json", "step000_main_sync.png"):
        assert (tmp_path / name).is_file(), name
    assert summary["model"] == model and summary["model_calls"]["pano"] == 4
    assert np.asarray(Image.open(tmp_path / "image.png")).shape == (64, 128, 3)
    # the generator is conditioned on the full prompt, the object's noun in place of {object}
    assert "{object}" not in summary["prompt"] and "glass sphere" in summary["prompt"]
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved["prompt"] == summary["prompt"] and set(saved["timings_s"]) >= {"scene", "warps", "sampling"}


def test_refraction_psnr_against_numpy():
    """PSNR of the object region against π^R(I⁻), recomputed with numpy on a hand-made warp."""
    from types import SimpleNamespace

    from snell_bench.metrics.refraction import refraction_psnr

    rng = np.random.default_rng(0)
    i_minus = torch.from_numpy(rng.random((1, 3, 8, 10), dtype=np.float32))
    ys, xs = np.mgrid[0:8, 0:10].astype(np.float32)
    coords = np.stack([9 - xs, ys], -1)  # a mirror in x: integer sources, so remap is exact
    mask = np.zeros((8, 10), bool)
    mask[2:6, 3:8] = True
    warps = SimpleNamespace(refraction=coords, object_mask=mask, refraction_valid=np.ones_like(mask))
    image = i_minus.clone()
    image[..., 2:6, 3:8] = 0.5
    target = i_minus[0].numpy()[:, ys.astype(int), (9 - xs).astype(int)]
    mse = np.mean((0.5 - target[:, mask]) ** 2)
    assert refraction_psnr(image, i_minus, warps) == pytest.approx(10 * np.log10(1 / mse), rel=1e-6)
    warps.refraction_valid = np.zeros_like(mask)
    assert refraction_psnr(image, i_minus, warps) is None  # no pixel: no number (never NaN in JSON)


def test_generate_job_applies_the_methods_switches(tmp_path):
    from snell_bench.experiment.generate import run_generate

    cfg = compose(
        [
            "job=generate",
            "method=adaptive",
            "object.ior=1.05",
            "scene.width=128",
            "scene.height=64",
            "scene.supersample=1",
            "warps.pano_height=64",
            "warps.cache_dir=null",
            "sampler.steps=3",
            "sampler.progress=false",
            "method.sampler.skip_panorama_above=0.0",
            f"output_dir={tmp_path}",
        ]
    )
    summary = run_generate(cfg)
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved["decisions"]["panorama"]["used"] is False and saved["decisions"]["panorama"]["skip_above"] == 0.0
    assert summary["model_calls"]["pano"] == 0
    assert saved["decisions"]["reflection"]["min_fresnel"] == 0.01  # from conf/method/adaptive.yaml
    assert saved["warps"]["far_background"]["tolerance_px"] == 1.0
    assert not (tmp_path / "panorama.png").exists()
