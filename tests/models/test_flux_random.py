"""FLUX.1's modules with random weights: built on ``meta``, materialised on the CPU here (the
same code materialises them on a GPU), deterministic per seed, finite through the network."""

import math
from types import SimpleNamespace

import pytest
import torch

from snell_bench.models import flux_random as fr
from snell_bench.models.flux import FluxGenerator


def test_clip_materialised_with_its_position_ids_and_torch_default_bounds():
    a = fr.random_module(fr._clip, device="cpu", dtype=torch.bfloat16, seed=3)
    b = fr.random_module(fr._clip, device="cpu", dtype=torch.bfloat16, seed=3)
    c = fr.random_module(fr._clip, device="cpu", dtype=torch.bfloat16, seed=4)
    pa, pb, pc = (dict(m.named_parameters()) for m in (a, b, c))
    assert all(torch.equal(pa[k], pb[k]) for k in pa)  # one seed, one model
    assert any(not torch.equal(pa[k], pc[k]) for k in pa)
    ids = a.embeddings.position_ids
    assert ids.dtype == torch.long and torch.equal(ids[0], torch.arange(77))
    w = pa["encoder.layers.0.mlp.fc1.weight"]  # (3072, 768): uniform in +-1/sqrt(768)
    bound = 1 / math.sqrt(768)
    assert w.dtype == torch.bfloat16 and w.abs().max() <= bound * (1 + 2**-7)
    # a uniform's standard deviation is bound / sqrt(3); 2.4 M draws: well within 1 %
    assert abs(w.float().std().item() - bound / math.sqrt(3)) < 0.01 * bound
    assert torch.all(pa["final_layer_norm.weight"] == 1)
    assert torch.all(pa["final_layer_norm.bias"] == 0)
    out = a(torch.randint(0, 49408, (1, 77))).last_hidden_state
    assert out.shape == (1, 77, 768) and torch.isfinite(out).all()


@pytest.fixture(scope="module")
def small_flux():
    """FLUX.1-dev's widths with one double and one single block and a one-layer T5-XXL,
    materialised on the CPU in bf16 (~1 GB instead of 34)."""
    from transformers import T5Config, T5EncoderModel

    from snell_bench.models.tiny_text import clip_tokenizer_from_open_clip_vocab, t5_byte_tokenizer

    kw = dict(device="cpu", dtype=torch.bfloat16)
    parts = SimpleNamespace(
        vae=fr.random_module(fr._vae, seed=1, **kw),
        text_encoder_2=fr.random_module(
            lambda: T5EncoderModel(T5Config(**{**fr.T5_XXL_ENCODER, "num_layers": 1})), seed=2, **kw
        ),
        text_encoder=fr.random_module(fr._clip, seed=3, **kw),
        tokenizer=clip_tokenizer_from_open_clip_vocab(),
        tokenizer_2=t5_byte_tokenizer(),
    )
    pipe = fr.build_random_flux_pipeline(
        "dev", shared=parts, transformer={"num_layers": 1, "num_single_layers": 1}, **kw
    )
    return FluxGenerator(pipe, device="cpu", dtype=torch.bfloat16)


def test_velocity_and_vae_are_finite_in_bfloat16(small_flux):
    g = small_flux
    assert g.random_weights
    cond = g.condition(["a glass sphere on a table"])
    assert cond.data["prompt_embeds"].shape == (1, 512, 4096)
    z = torch.randn(1, 16, 8, 8, generator=torch.Generator().manual_seed(0))
    v = g.velocity(z, 0.7, cond)
    assert v.shape == z.shape and torch.isfinite(v).all()
    img = g.decode(z)
    assert img.shape == (1, 3, 64, 64) and torch.isfinite(img).all()
    assert torch.isfinite(g.encode(img)).all()


def test_meta_pipelines_have_no_data_and_the_right_kinds():
    for kind, cls in (("dev", "FluxPipeline"), ("fill", "FluxFillPipeline"), ("kontext", "FluxKontextPipeline")):
        pipe = fr.build_random_flux_pipeline(kind)
        assert type(pipe).__name__ == cls and pipe.random_weights
        assert all(p.device.type == "meta" for p in pipe.transformer.parameters())
    with pytest.raises(ValueError, match="unknown FLUX pipeline kind"):
        fr.build_random_flux_pipeline("schnell")
