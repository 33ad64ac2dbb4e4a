"""Baselines through diffusers, on tiny random FLUX pipelines saved to a folder (CPU, offline)."""

import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")

import warnings

import numpy as np
import pytest
import torch

from snell_bench.models import DeviceNotAvailableError, WeightsNotFoundError
from snell_bench.models.external import generate_external, inpaint_external
from snell_bench.models.tiny_flux import build_tiny_flux_pipeline

H, W = 32, 48
PROMPT = "a glass sphere on a wooden table"


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """A tiny ``FluxPipeline`` and a tiny ``FluxFillPipeline`` saved with ``save_pretrained``."""
    root = tmp_path_factory.mktemp("external")
    out = {}
    for name, fill in (("t2i", False), ("fill", True)):
        build_tiny_flux_pipeline(seed=0, fill=fill).save_pretrained(root / name)
        out[name] = str(root / name)
    return out


@pytest.fixture(scope="module")
def scene():
    g = torch.Generator().manual_seed(0)
    i_minus = torch.rand(1, 3, H, W, generator=g)
    mask = np.zeros((H, W), bool)
    mask[8:24, 16:36] = True
    return i_minus, mask


def generate(folders, seed):
    return generate_external(folders["t2i"], PROMPT, (H, W), seed=seed, steps=2, device="cpu")


def inpaint(folders, scene, seed):
    i_minus, mask = scene
    return inpaint_external(folders["fill"], PROMPT, i_minus, mask, seed=seed, steps=2, device="cpu")


@pytest.fixture(scope="module")
def generated(folders):
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*torch_dtype.*")  # diffusers' current dtype keyword
        return generate(folders, seed=1)


@pytest.fixture(scope="module")
def inpainted(folders, scene):
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*torch_dtype.*")
        return inpaint(folders, scene, seed=1)


def check_image(img):
    assert img.shape == (1, 3, H, W) and img.dtype == torch.float32 and img.device.type == "cpu"
    assert torch.isfinite(img).all() and img.min() >= 0 and img.max() <= 1


def test_fill_transformer_reads_latents_masked_latents_and_mask(folders):
    import json
    from pathlib import Path

    cfg = {k: json.loads((Path(folders[k]) / "transformer" / "config.json").read_text()) for k in folders}
    # packed: 16 latent channels x 4 + 16 masked-image channels x 4 + (8 x 8 mask pixels) x 4
    assert (cfg["fill"]["in_channels"], cfg["fill"]["out_channels"]) == (384, 64)
    assert (cfg["t2i"]["in_channels"], cfg["t2i"]["out_channels"]) == (64, 64)
    assert json.loads((Path(folders["fill"]) / "model_index.json").read_text())["_class_name"] == "FluxFillPipeline"


def test_generate_on_cpu(generated):
    check_image(generated)


def test_generate_is_deterministic_for_a_seed(folders, generated):
    assert torch.equal(generate(folders, seed=1), generated)


def test_generate_depends_on_the_seed(folders, generated):
    assert not torch.equal(generate(folders, seed=2), generated)


def test_inpaint_on_cpu(inpainted):
    check_image(inpainted)


def test_inpaint_is_deterministic_for_a_seed(folders, scene, inpainted):
    assert torch.equal(inpaint(folders, scene, seed=1), inpainted)


def test_inpaint_depends_on_the_seed(folders, scene, inpainted):
    assert not torch.equal(inpaint(folders, scene, seed=2), inpainted)


def test_dtype_is_applied(folders):
    from diffusers import AutoPipelineForText2Image

    from snell_bench.models.external import _load

    pipe = _load(AutoPipelineForText2Image, folders["t2i"], "cpu", "bf16")
    assert pipe.transformer.dtype == torch.bfloat16 and pipe.device.type == "cpu"
    assert _load(AutoPipelineForText2Image, folders["t2i"], "cpu", None).transformer.dtype == torch.float32


def test_missing_weights_name_the_config_key(tmp_path, scene):
    i_minus, mask = scene
    for model_id in (str(tmp_path / "no_such_model"), "nobody-here/no-such-model"):
        with pytest.raises(WeightsNotFoundError, match="method.model_id"):
            generate_external(model_id, PROMPT, (H, W), steps=1, device="cpu")
        with pytest.raises(WeightsNotFoundError, match="method.model_id"):
            inpaint_external(model_id, PROMPT, i_minus, mask, steps=1, device="cpu")


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
def test_no_cuda_and_no_device(folders, scene):
    i_minus, mask = scene
    with pytest.raises(DeviceNotAvailableError, match="device='cpu'"):
        generate_external(folders["t2i"], PROMPT, (H, W), steps=1)
    with pytest.raises(DeviceNotAvailableError, match="model.device"):
        inpaint_external(folders["fill"], PROMPT, i_minus, mask, steps=1)
    with pytest.raises(DeviceNotAvailableError):
        generate_external(folders["t2i"], PROMPT, (H, W), steps=1, device="cuda")
