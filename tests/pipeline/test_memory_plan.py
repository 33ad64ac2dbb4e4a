"""The memory plan of one GPU node, checked on the CPU with FLUX.1's real modules on ``meta``
(shapes and parameter bytes, no data): FLUX.1-dev, Fill and Kontext share their text encoders and
VAE (loaded once), the pool offloads the generator before the relighter only when both do not
fit ``models.memory_gb``, and FLUX.2-dev runs with diffusers' offloading when it does not fit.

References: the published sizes of the FLUX.1-dev checkpoint's files in bfloat16
(``transformer/`` 23.80 GB, ``text_encoder_2/`` 9.52 GB, ``text_encoder/`` 246 MB, ``vae/``
168 MB); FLUX.2-dev's model card (32 B transformer, 24 B Mistral text encoder).
"""

import pytest
import torch

from snell_bench.config import compose
from snell_bench.models import shared
from snell_bench.models.external import load_pipeline, offload_mode
from snell_bench.models.sizes import node_weights_bytes
from snell_bench.pipeline.cell import build
from snell_bench.pipeline.pool import ModelPool, model_bytes

GB = 10**9
GiB = 2**30
#: bytes of the FLUX.1-dev checkpoint's weight files (the headers add < 0.1 %)
PUBLISHED = {"transformer": 23.80e9, "text_encoder_2": 9.52e9, "text_encoder": 0.246e9, "vae": 0.168e9}


@pytest.fixture(scope="module")
def nodes():
    cfg = compose(["model=flux_dev", "model.random_init=true", "model.device=meta", "model.dtype=bfloat16"])
    return cfg.model


@pytest.fixture(autouse=True)
def fresh_registry():
    shared.clear()
    yield
    shared.clear()


def test_random_flux_has_the_published_sizes(nodes):
    gen = build(nodes.generator)
    assert gen.random_weights and gen.device.type == "meta" and gen.dtype == torch.bfloat16
    for name, size in PUBLISHED.items():
        got = model_bytes(getattr(gen.pipe, name))
        assert abs(got - size) <= 0.01 * size, (name, got, size)  # published sizes are rounded to 3 digits


def test_fill_and_kontext_share_the_text_encoders_and_vae(nodes):
    gen = build(nodes.generator)
    relighter = build(nodes.relighter)
    fill = build(nodes.fill)
    for name in ("text_encoder", "text_encoder_2", "vae"):
        assert getattr(relighter.pipe, name) is getattr(gen.pipe, name)
        assert getattr(fill, name) is getattr(gen.pipe, name)
    assert relighter.pipe.transformer is not gen.pipe.transformer
    assert fill.transformer.config.in_channels == 384 and gen.pipe.transformer.config.in_channels == 64
    # the size known before loading counts only what is not loaded yet: Kontext's transformer
    assert node_weights_bytes(nodes.relighter) == model_bytes(relighter.pipe.transformer)
    # together: one copy of the shared parts
    pool = ModelPool()
    pool.put("generator", "g", gen)
    pool.put("relighter", "r", relighter)
    assert pool.held_bytes() == model_bytes(gen) + model_bytes(relighter.pipe.transformer)


def _events(pool):
    return [(x.event, x.label) for x in pool.loads]


@pytest.mark.parametrize("budget_gb, offloads", [(70, False), (40, True)])
def test_the_generator_is_offloaded_before_the_relighter_only_when_both_do_not_fit(nodes, budget_gb, offloads):
    pool = ModelPool(budget_gb, offload=True)
    get = {
        "gen": lambda: pool.get(
            "generator",
            "g",
            lambda: build(nodes.generator),
            label="flux",
            size=lambda: node_weights_bytes(nodes.generator),
        )[0],
        "kontext": lambda: pool.get(
            "relighter",
            "r",
            lambda: build(nodes.relighter),
            label="kontext",
            size=lambda: node_weights_bytes(nodes.relighter),
        )[0],
    }
    gen = get["gen"]()
    one = model_bytes(gen)
    assert 33.0 * GB < one < 34.5 * GB
    relighter = get["kontext"]()  # a relit cell: sample, then relight
    assert pool.held_bytes() <= pool.budget
    gen_again = get["gen"]()  # the next cell samples again
    assert gen_again is gen and pool.held_bytes() <= pool.budget
    events = _events(pool)
    if not offloads:  # 33.7 + 23.8 GB (the shared 10 GB once) = 57.5 GB fit 70 GiB: nothing moves
        assert events == [("load", "flux"), ("load", "kontext")]
        assert pool.held_bytes() == one + model_bytes(relighter.pipe.transformer)
    else:
        assert events == [
            ("load", "flux"),
            ("offload", "flux"),
            ("load", "kontext"),
            ("offload", "kontext"),
            ("restore", "flux"),
        ]
        # the generator's offload moved all but what Kontext shares after loading: its transformer
        moved = {x.event: x.bytes for x in pool.loads if x.label == "flux" and x.event != "load"}
        assert moved["offload"] == one  # nothing shared yet when it made room
        assert moved["restore"] == model_bytes(gen.pipe.transformer)  # the shared part never left
        assert pool.resident() == ["flux"]
    assert len([e for e in events if e[0] == "load"]) == 2  # every model loads once


def test_offload_mode_of_flux2_dev():
    """FLUX.2-dev in bfloat16 (model card: 32 B + 24 B parameters, VAE ~84 M): ~112 GB."""
    sizes = {"transformer": 64 * GB, "text_encoder": 48 * GB, "vae": 168 * 10**6}
    assert offload_mode(sizes, None) == "none"
    assert offload_mode(sizes, int(0.9 * 141 * GB)) == "none"  # an H200's 141 GB
    assert offload_mode(sizes, int(0.9 * 80 * GB)) == "model"  # an 80 GB A100 / H100: one component at a time
    assert offload_mode(sizes, 40 * GB) == "sequential"  # a 48 GB GPU: layer by layer


def test_random_init_is_for_flux_pipelines_only():
    with pytest.raises(ValueError, match="random_init"):
        load_pipeline("Qwen/Qwen-Image", pipeline="QwenImagePipeline", device="meta", random_init=True)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_offload_moves_the_weights_to_host_memory_and_back_on_cuda():
    """On a GPU the plan moves real bytes: the offloaded generator's weights leave the device and
    come back unchanged; a model on the host is released instead (nothing to gain by moving it)."""
    from snell_bench.models.tiny_flux import TinyFluxGenerator

    gen = TinyFluxGenerator(seed=0, device="cuda")
    before = {k: v.detach().cpu().clone() for k, v in gen.pipe.transformer.state_dict().items()}
    size = model_bytes(gen)
    pool = ModelPool(1.5 * size / GiB)
    pool.get("generator", "g", lambda: gen, label="tiny", size=lambda: size)
    pool.get("other", "o", lambda: TinyFluxGenerator(seed=1, device="cuda"), label="other", size=lambda: size)
    assert next(gen.pipe.transformer.parameters()).device.type == "cpu"
    pool.get("generator", "g", lambda: gen, label="tiny")
    assert next(gen.pipe.transformer.parameters()).device.type == "cuda"
    after = gen.pipe.transformer.state_dict()
    assert all(torch.equal(before[k], after[k].cpu()) for k in before)
    assert [e for e, _ in _events(pool)] == ["load", "offload", "load", "offload", "restore"]
