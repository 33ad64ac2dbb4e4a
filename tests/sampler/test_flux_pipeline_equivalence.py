"""The text-to-image baseline equals diffusers' ``FluxPipeline.__call__`` on the same components.

Tiny random FLUX (CPU): the project's loop (``text_to_image`` and ``sample(sync="none")``, which
are bit-identical) against the pipeline itself, given the same initial noise as packed ``latents``.
"""

import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import pytest
import torch
from tolerances import reordering_tolerance

from snell_bench.models.tiny_flux import TinyFluxGenerator
from snell_bench.sampler.text_to_image import text_to_image

PROMPT = "a glass sphere on a wooden table"
STEPS = 4


def flux_reduction(H, W):
    """The longest reduction of the tiny FLUX at H x W: the joint attention over the 512 T5 tokens
    and the (H / 16) (W / 16) packed latent tokens. The loop and the pipeline compute the same float32
    image in other summation orders (other matrix shapes), and the schedules differ by the float32
    rounding of each sigma (at most 2**-24 sigma: one more rounding per step, of the size the bound
    counts), so they agree to ``reordering_tolerance(flux_reduction(H, W), image)``."""
    return 512 + (H // 16) * (W // 16)


def pipeline_image(gen, H, W, seed, steps=STEPS):
    """``FluxPipeline.__call__`` from ``gen``'s components, started from the noise the project's
    loop draws for ``seed`` (unpacked ``(1, 16, H/8, W/8)``, packed for the pipeline)."""
    pipe = gen.pipe
    z0 = torch.randn((1,) + gen.geometry.latent_shape(H, W), generator=torch.Generator().manual_seed(seed))
    packed = pipe._pack_latents(z0, 1, 16, H // 8, W // 8)
    out = pipe(
        prompt=PROMPT,
        height=H,
        width=W,
        num_inference_steps=steps,
        guidance_scale=gen.guidance,
        latents=packed.to(gen.dtype),
        output_type="pt",
    ).images
    return out.float()


@pytest.fixture(scope="module")
def gen32():
    return TinyFluxGenerator(seed=0)


@pytest.mark.parametrize("hw", [(64, 64), (96, 160)])
def test_float32_equals_flux_pipeline(gen32, hw):
    H, W = hw
    ours = text_to_image(gen32, PROMPT, H, W, steps=STEPS, seed=3)
    ref = pipeline_image(gen32, H, W, seed=3)
    assert ours.shape == ref.shape == (1, 3, H, W)
    assert (ours - ref).abs().max() <= reordering_tolerance(flux_reduction(H, W), ref)


def test_guidance_is_the_pipelines(gen32):
    """A different guidance scale changes both the same way (the model input, not CFG)."""
    g = TinyFluxGenerator(seed=0, guidance=7.0)
    ours = text_to_image(g, PROMPT, 64, 64, steps=2, seed=1)
    ref = pipeline_image(g, 64, 64, seed=1, steps=2)
    assert (ours - ref).abs().max() <= reordering_tolerance(flux_reduction(64, 64), ref)
    assert (ours - text_to_image(gen32, PROMPT, 64, 64, steps=2, seed=1)).abs().max() > 1e-4


def test_bfloat16_latents_as_the_pipeline():
    """In bfloat16 the pipeline holds its latents in bfloat16 between steps (and rounds each step's
    ``dt * v`` to bfloat16). ``latent_dtype="model"`` does the same: equal up to the pipeline's
    post-processing in bfloat16 (one bfloat16 step of 1/512 at most); the default keeps float32
    latents and differs by ~2e-2 on the tiny model."""
    gen = TinyFluxGenerator(seed=0, dtype="bfloat16")
    H = W = 64
    ref = pipeline_image(gen, H, W, seed=5)
    as_pipe = text_to_image(gen, PROMPT, H, W, steps=STEPS, seed=5, latent_dtype="model")
    f32 = text_to_image(gen, PROMPT, H, W, steps=STEPS, seed=5)
    err_pipe = float((as_pipe - ref).abs().max())
    err_f32 = float((f32 - ref).abs().max())
    assert err_pipe <= 1 / 512 + 1e-6, err_pipe
    assert err_f32 > 5 * err_pipe, (err_pipe, err_f32)
