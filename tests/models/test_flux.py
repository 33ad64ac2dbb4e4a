"""FluxGenerator on the tiny random FLUX (CPU, offline); real FLUX.1-dev only with -m "weights and gpu"."""

import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
from tolerances import reordering_tolerance

from snell_bench.models import DeviceNotAvailableError, Generator, WeightsNotFoundError
from snell_bench.models.flux import FluxGenerator
from snell_bench.models.tiny_flux import TinyFluxGenerator, build_tiny_flux_pipeline

PROMPTS = [
    "A cozy living room with a polished wooden coffee table close to the camera, with a big glass sphere on top.",
    "A high resolution equirectangular 360 degree panorama captured on top of a polished wooden coffee table.",
]
#: The longest reduction of a tiny FLUX velocity on an 8 x 8 latent: the joint attention over the 512 T5
#: tokens and the 4 x 4 packed latent tokens. A batch and its items, or a condition and its expansion,
#: compute the same float32 velocity in other summation orders (other matrix shapes).
VELOCITY_REDUCTION = 512 + 4 * 4


@pytest.fixture(scope="module")
def gen() -> FluxGenerator:
    return TinyFluxGenerator(seed=0)


@pytest.fixture(scope="module")
def cond2(gen):
    return gen.condition(PROMPTS, ["main", "pano"])


def rand_images(b, h, w, seed=0):
    return torch.rand(b, 3, h, w, generator=torch.Generator().manual_seed(seed))


def rand_latents(b, h, w, seed=0):
    return torch.randn(b, 16, h, w, generator=torch.Generator().manual_seed(seed))


class TestConstruction:
    def test_protocol(self, gen):
        assert isinstance(gen, Generator)
        assert gen.name == "tiny_flux"
        assert (gen.geometry.channels, gen.geometry.downscale, gen.geometry.multiple) == (16, 8, 16)
        assert gen.dtype == torch.float32 and gen.device.type == "cpu"

    def test_dtype_names(self, gen):
        assert FluxGenerator.from_pipeline(gen.pipe, dtype="fp32").dtype == torch.float32
        assert FluxGenerator.from_pipeline(gen.pipe, dtype="torch.float32").dtype == torch.float32
        with pytest.raises(ValueError, match="model.dtype"):
            FluxGenerator.from_pipeline(gen.pipe, dtype="float13")

    def test_modules_in_eval_mode(self, gen):
        p = gen.pipe
        for m in (p.transformer, p.vae, p.text_encoder, p.text_encoder_2):
            assert not m.training
            assert not any(q.requires_grad for q in m.parameters())

    def test_build_keeps_global_rng_and_is_seeded(self):
        state = torch.random.get_rng_state()
        a = build_tiny_flux_pipeline(seed=3)
        assert torch.equal(state, torch.random.get_rng_state())
        b = build_tiny_flux_pipeline(seed=3)
        c = build_tiny_flux_pipeline(seed=4)
        pa, pb, pc = (dict(p.transformer.named_parameters()) for p in (a, b, c))
        assert all(torch.equal(pa[k], pb[k]) for k in pa)
        assert any(not torch.equal(pa[k], pc[k]) for k in pa)

    def test_built_from_the_config(self):
        from hydra.errors import InstantiationException, MissingConfigException
        from hydra.utils import instantiate

        from snell_bench.config import compose

        g = instantiate(compose(["model=tiny_flux", "model.seed=1"]).model.generator)
        assert isinstance(g, TinyFluxGenerator) and isinstance(g, Generator) and g.seed == 1
        with pytest.raises(MissingConfigException, match="model/no_such_model"):
            compose(["model=no_such_model"])
        with pytest.raises(InstantiationException) as info:
            instantiate(compose(["model=flux_dev", "model.path=/nonexistent/flux"]).model.generator)
        assert isinstance(info.value.__cause__, WeightsNotFoundError) and "model.path" in str(info.value.__cause__)

    def test_clip_tokenizer_files(self, tmp_path):
        """Written atomically with the umask's mode; the tokenizer splits text as open_clip's does."""
        from open_clip.tokenizer import SimpleTokenizer
        from transformers import CLIPTokenizer

        from snell_bench.models.tiny_text import _write_clip_tokenizer_files

        folder = tmp_path / "tok"
        _write_clip_tokenizer_files(folder)
        assert sorted(p.name for p in folder.iterdir()) == ["merges.txt", "vocab.json"]  # no temporaries left
        mask = os.umask(0)
        os.umask(mask)
        assert all((folder / n).stat().st_mode & 0o777 == 0o666 & ~mask for n in ("merges.txt", "vocab.json"))
        tok = CLIPTokenizer.from_pretrained(str(folder), model_max_length=77)
        ref = SimpleTokenizer()
        for text in PROMPTS + ["Ünïcödé glass, 360° — ok?"]:
            ids = tok(text).input_ids
            assert ids[0] == ref.sot_token_id and ids[-1] == ref.eot_token_id
            assert ids[1:-1] == ref.encode(text)

    def test_import_is_light(self):
        code = "import sys, snell_bench.models; assert 'diffusers' not in sys.modules and 'transformers' not in sys.modules"
        subprocess.run([sys.executable, "-c", code], check=True, env={**os.environ, "HF_HUB_OFFLINE": "1"})


class TestWeightsAndDevice:
    def test_missing_folder(self):
        with pytest.raises(WeightsNotFoundError, match="model.path") as info:
            FluxGenerator.from_pretrained("/nonexistent/flux")
        assert "hf download" in str(info.value)

    def test_folder_without_model_index(self, tmp_path):
        with pytest.raises(WeightsNotFoundError, match="model_index.json"):
            FluxGenerator.from_pretrained(tmp_path, device="cpu")

    def test_hub_id_not_in_cache(self):
        with pytest.raises(WeightsNotFoundError, match="model.path"):
            FluxGenerator.from_pretrained("nobody-here/no-such-flux", device="cpu")

    def test_incomplete_folder(self, tmp_path):
        (tmp_path / "model_index.json").write_text(
            json.dumps({"_class_name": "FluxPipeline", "transformer": ["diffusers", "FluxTransformer2DModel"]})
        )
        with pytest.raises(WeightsNotFoundError, match="model.path"):
            FluxGenerator.from_pretrained(tmp_path, device="cpu")

    @pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
    def test_no_cuda_names_device_key(self, tmp_path):
        (tmp_path / "model_index.json").write_text("{}")
        with pytest.raises(DeviceNotAvailableError, match="model.device"):
            FluxGenerator.from_pretrained(tmp_path)
        with pytest.raises(DeviceNotAvailableError, match="model.device"):
            FluxGenerator.from_pretrained(tmp_path, device="cuda")


class TestVae:
    @pytest.mark.parametrize("hw", [(64, 64), (64, 128)])
    def test_latent_shapes(self, gen, hw):
        h, w = hw
        assert gen.geometry.latent_shape(h, w) == (16, h // 8, w // 8)
        z = gen.encode(rand_images(2, h, w))
        assert z.shape == (2, 16, h // 8, w // 8) and z.dtype == torch.float32
        x = gen.decode(z)
        assert x.shape == (2, 3, h, w) and x.dtype == torch.float32
        assert x.min() >= 0 and x.max() <= 1 and torch.isfinite(x).all()

    def test_size_not_multiple(self, gen):
        with pytest.raises(ValueError, match="multiple of 16"):
            gen.encode(rand_images(1, 64, 72))

    def test_normalisation(self, gen):
        vae = gen.pipe.vae
        x = rand_images(1, 64, 64)
        mode = vae.encode(x * 2 - 1).latent_dist.mode()
        torch.testing.assert_close(gen.encode(x), (mode - 0.1159) * 0.3611)
        z = rand_latents(1, 8, 8)
        ref = ((vae.decode(z / 0.3611 + 0.1159).sample + 1) / 2).clamp(0, 1)
        torch.testing.assert_close(gen.decode(z), ref)

    def test_encode_determinism(self, gen):
        x = rand_images(2, 64, 128)
        assert torch.equal(gen.encode(x), gen.encode(x))
        s1 = gen.encode(x, generator=torch.Generator().manual_seed(7))
        s2 = gen.encode(x, generator=torch.Generator().manual_seed(7))
        s3 = gen.encode(x, generator=torch.Generator().manual_seed(8))
        assert torch.equal(s1, s2)
        assert not torch.equal(s1, s3) and not torch.equal(s1, gen.encode(x))

    def test_encode_sample_is_mean_plus_std_times_the_generators_draw(self, gen):
        """``sampler.encode=sample``: the posterior draw from the run's generator, normalised like
        the mean."""
        x = rand_images(1, 32, 32)
        vae = gen.pipe.vae
        dist = vae.encode(x * 2 - 1).latent_dist
        n = torch.randn(dist.mean.shape, generator=torch.Generator().manual_seed(7))
        ref = (dist.mean + dist.std * n - vae.config.shift_factor) * vae.config.scaling_factor
        got = gen.encode(x, generator=torch.Generator().manual_seed(7))
        torch.testing.assert_close(got, ref, atol=1e-6, rtol=0)
        mean = (dist.mean - vae.config.shift_factor) * vae.config.scaling_factor
        torch.testing.assert_close(gen.encode(x), mean, atol=1e-6, rtol=0)
        assert float((got - mean).abs().max()) > 1e-3

    def test_tiled_vae(self):
        g = TinyFluxGenerator(seed=0, vae_tiling=True)
        g.pipe.vae.tile_sample_min_size, g.pipe.vae.tile_latent_min_size = 32, 4  # force tiles at test size
        z = g.encode(rand_images(1, 64, 192))
        assert z.shape == (1, 16, 8, 24) and torch.isfinite(z).all()
        x = g.decode(z)
        assert x.shape == (1, 3, 64, 192) and 0 <= x.min() and x.max() <= 1


class TestPacking:
    @pytest.mark.parametrize("hw", [(8, 16), (6, 10), (90, 160), (128, 256)])
    def test_round_trip(self, hw):
        from diffusers import FluxPipeline

        h, w = hw
        z = rand_latents(2, h, w)
        packed = FluxPipeline._pack_latents(z, 2, 16, h, w)
        assert packed.shape == (2, (h // 2) * (w // 2), 64)
        assert torch.equal(FluxPipeline._unpack_latents(packed, h * 8, w * 8, 8), z)
        assert torch.equal(FluxGenerator.unpack(FluxGenerator.pack(z), h, w), z)

    def test_layout(self):
        """packed[b, i (w/2) + j, 4c + 2 di + dj] = z[b, c, 2i + di, 2j + dj]."""
        h, w = 6, 10
        z = rand_latents(1, h, w)
        p = FluxGenerator.pack(z)
        for i, j, c, di, dj in [(0, 0, 0, 0, 0), (1, 3, 5, 1, 0), (2, 4, 15, 1, 1), (2, 1, 7, 0, 1)]:
            assert p[0, i * (w // 2) + j, 4 * c + 2 * di + dj] == z[0, c, 2 * i + di, 2 * j + dj]

    def test_odd_size_rejected(self):
        with pytest.raises(ValueError, match="even"):
            FluxGenerator.pack(rand_latents(1, 7, 8))


class TestCondition:
    def test_shapes(self, gen, cond2):
        d = cond2.data
        assert len(cond2) == 2 and cond2.prompts == PROMPTS and d["views"] == ["main", "pano"]
        assert d["prompt_embeds"].shape == (2, gen.max_sequence_length, 32)
        assert d["pooled_prompt_embeds"].shape == (2, 32)
        assert d["text_ids"].shape == (2, gen.max_sequence_length, 3)
        assert torch.equal(d["guidance"], torch.full((2,), 3.5))

    def test_prompts_differ(self, cond2):
        d = cond2.data
        assert not torch.allclose(d["prompt_embeds"][0], d["prompt_embeds"][1])
        assert not torch.allclose(d["pooled_prompt_embeds"][0], d["pooled_prompt_embeds"][1])

    def test_deterministic_and_view_independent(self, gen, cond2):
        again = gen.condition(PROMPTS, ["pano", "main"])
        assert torch.equal(again.data["prompt_embeds"], cond2.data["prompt_embeds"])
        assert torch.equal(again.data["pooled_prompt_embeds"], cond2.data["pooled_prompt_embeds"])

    def test_views(self, gen):
        assert gen.condition(["a glass sphere"], None).data["views"] == ["main"]
        with pytest.raises(ValueError, match="views"):
            gen.condition(["a", "b"], ["main"])
        with pytest.raises(ValueError, match="unknown views"):
            gen.condition(["a"], ["side"])

    def test_guidance_override(self, gen):
        assert torch.equal(gen.condition(["a"], ["main"], guidance=5.0).data["guidance"], torch.tensor([5.0]))


class TestVelocity:
    def test_finite_shape_deterministic(self, gen, cond2):
        z = rand_latents(2, 8, 16)
        v = gen.velocity(z, 0.7, cond2)
        assert v.shape == z.shape and v.dtype == z.dtype and torch.isfinite(v).all()
        assert torch.equal(v, gen.velocity(z, 0.7, cond2))

    def test_batch_equals_singles(self, gen, cond2):
        z = rand_latents(2, 8, 8)
        sig = torch.tensor([0.9, 0.4])
        v = gen.velocity(z, sig, cond2)
        for b in range(2):
            single = gen.condition([PROMPTS[b]], ["main"])
            vb = gen.velocity(z[b : b + 1], float(sig[b]), single)
            torch.testing.assert_close(v[b : b + 1], vb, rtol=0, atol=reordering_tolerance(VELOCITY_REDUCTION, vb))

    def test_one_prompt_expands(self, gen):
        z = rand_latents(3, 8, 8)
        c1 = gen.condition([PROMPTS[0]], ["main"])
        c3 = gen.condition([PROMPTS[0]] * 3, ["main"] * 3)
        v3 = gen.velocity(z, 0.5, c3)
        torch.testing.assert_close(
            gen.velocity(z, 0.5, c1), v3, rtol=0, atol=reordering_tolerance(VELOCITY_REDUCTION, v3)
        )
        with pytest.raises(ValueError, match="prompts for a batch"):
            gen.velocity(z, 0.5, gen.condition(PROMPTS, ["main", "pano"]))

    def test_depends_on_inputs(self, gen, cond2):
        z = rand_latents(1, 8, 8)
        c = gen.condition([PROMPTS[0]], ["main"])
        v = gen.velocity(z, 0.5, c)
        assert not torch.allclose(v, gen.velocity(z, 0.2, c))
        assert not torch.allclose(v, gen.velocity(z, 0.5, gen.condition([PROMPTS[1]], ["main"])))
        assert not torch.allclose(v, gen.velocity(z, 0.5, gen.condition([PROMPTS[0]], ["main"], guidance=1.0)))

    def test_bad_inputs(self, gen, cond2):
        with pytest.raises(ValueError):
            gen.velocity(torch.zeros(2, 4, 8, 8), 0.5, cond2)
        with pytest.raises(ValueError, match="sigma"):
            gen.velocity(rand_latents(2, 8, 8), torch.tensor([0.1, 0.2, 0.3]), cond2)


class TestSampling:
    def test_sigmas_match_flux_pipeline(self, gen):
        from diffusers.pipelines.flux.pipeline_flux import calculate_shift, retrieve_timesteps

        s = gen.sigmas(20, 720, 1280)
        assert s.shape == (21,) and s.dtype == torch.float64 and s[-1] == 0 and float(s[0]) == pytest.approx(1.0)
        assert (s[1:] < s[:-1]).all()
        sched = type(gen.pipe.scheduler).from_config(gen.pipe.scheduler.config)
        mu = calculate_shift(45 * 80, 256, 4096, 0.5, 1.15)
        timesteps, _ = retrieve_timesteps(sched, 20, "cpu", sigmas=np.linspace(1.0, 1 / 20, 20), mu=mu)
        torch.testing.assert_close(s[:-1].float(), timesteps.float() / 1000)
        # larger images shift the schedule towards noise
        assert (gen.sigmas(20, 1024, 2048)[1:-1] > s[1:-1]).all()

    @pytest.mark.parametrize("steps,hw", [(20, (720, 1280)), (4, (64, 96)), (28, (1024, 1024))])
    def test_sigmas_equal_the_closed_form(self, gen, steps, hw):
        """Evaluated in float64, the scheduler's shift is FLUX's closed form bit for bit."""
        from snell_bench.sampler import flux_sigmas

        h, w = hw
        assert torch.equal(gen.sigmas(steps, h, w), flux_sigmas(steps, (h // 16) * (w // 16)))

    def test_sigmas_follow_the_scheduler_config(self):
        from diffusers import FlowMatchEulerDiscreteScheduler
        from diffusers.pipelines.flux.pipeline_flux import calculate_shift

        g = TinyFluxGenerator(seed=0)
        cfg = g.pipe.scheduler.config
        ref = g.sigmas(8, 512, 512)
        g.pipe.scheduler = FlowMatchEulerDiscreteScheduler.from_config(cfg, max_shift=2.0)
        assert (g.sigmas(8, 512, 512)[1:-1] > ref[1:-1]).all()  # a larger shift: more steps at high noise
        # an option the float64 path does not model goes through set_timesteps (float32 values)
        g.pipe.scheduler = FlowMatchEulerDiscreteScheduler.from_config(cfg, shift_terminal=0.1)
        s = g.sigmas(8, 512, 512)
        sched = FlowMatchEulerDiscreteScheduler.from_config(cfg, shift_terminal=0.1)
        sched.set_timesteps(sigmas=np.linspace(1.0, 1 / 8, 8), mu=calculate_shift(32 * 32))
        assert s.dtype == torch.float64 and torch.equal(s, sched.sigmas.double())
        assert float(s[-2]) == pytest.approx(0.1) and (s[1:] < s[:-1]).all()
        g.pipe.scheduler = FlowMatchEulerDiscreteScheduler.from_config(cfg, invert_sigmas=True)
        with pytest.raises(ValueError, match="1 to 0"):
            g.sigmas(8, 512, 512)

    def test_sigmas_kinds_and_errors(self, gen):
        from snell_bench.sampler import linear_sigmas

        assert torch.equal(gen.sigmas(4, 64, 64, kind="linear"), linear_sigmas(4))
        with pytest.raises(ValueError, match="schedule"):
            gen.sigmas(4, 64, 64, kind="cosine")
        with pytest.raises(ValueError, match="positive integer"):
            gen.sigmas(0, 64, 64)
        with pytest.raises(ValueError, match="multiple of 16"):
            gen.sigmas(4, 64, 72)

    def test_euler_loop(self, gen):
        """Plain Euler sampling, x0_hat = z - sigma v, as the synchronized sampler does per view."""
        cond = gen.condition([PROMPTS[0]], ["main"])
        rng = torch.Generator().manual_seed(0)
        z = torch.randn(1, *gen.geometry.latent_shape(64, 64), generator=rng)
        sigmas = gen.sigmas(4, 64, 64)
        for s, s_next in zip(sigmas[:-1].tolist(), sigmas[1:].tolist()):
            x0_hat = z - s * gen.velocity(z, s, cond)
            z = x0_hat if s_next == 0 else (s_next / s) * z + (1 - s_next / s) * x0_hat
        x = gen.decode(z)
        assert x.shape == (1, 3, 64, 64) and torch.isfinite(x).all()
        assert 0 <= x.min() and x.max() <= 1


# ---------------------------------------------------------------------------------------- real weights


@pytest.fixture(scope="module")
def flux_dev():
    path = os.environ.get("SNELL_BENCH_FLUX_PATH", "black-forest-labs/FLUX.1-dev")
    try:
        return FluxGenerator.from_pretrained(path, device="cuda")
    except WeightsNotFoundError as err:
        pytest.skip(str(err))


@pytest.mark.weights
@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
class TestFluxDev:
    def test_vae_round_trip(self, flux_dev):
        """A smooth image survives encode -> decode (checks the shift/scale normalisation)."""
        yy, xx = torch.meshgrid(torch.linspace(0, 1, 256), torch.linspace(0, 1, 256), indexing="ij")
        x = torch.stack([xx, yy, 0.5 + 0.4 * torch.sin(6 * xx) * torch.cos(4 * yy)])[None]
        z = flux_dev.encode(x)
        assert z.shape == (1, 16, 32, 32)
        psnr = -10 * torch.log10(((flux_dev.decode(z) - x) ** 2).mean())
        assert psnr > 28

    def test_velocity_denoises(self, flux_dev):
        """At sigma = 0.5, x0_hat = z - sigma v is closer to the clean latent than z is
        (checks the timestep and velocity sign conventions)."""
        yy, xx = torch.meshgrid(torch.linspace(0, 1, 512), torch.linspace(0, 1, 512), indexing="ij")
        x = torch.stack([xx, yy, 0.5 * torch.ones_like(xx)])[None]
        x0 = flux_dev.encode(x)
        eps = torch.randn(x0.shape, generator=torch.Generator().manual_seed(0))
        cond = flux_dev.condition(["a smooth colour gradient"], ["main"])
        z = 0.5 * x0 + 0.5 * eps
        v = flux_dev.velocity(z, 0.5, cond)
        assert torch.isfinite(v).all() and v.shape == x0.shape
        x0_hat = z - 0.5 * v
        assert ((x0_hat - x0) ** 2).mean() < 0.5 * ((z - x0) ** 2).mean()

    def test_panorama_size(self, flux_dev):
        cond = flux_dev.condition(["a panorama"], ["pano"])
        z = torch.randn(1, *flux_dev.geometry.latent_shape(1024, 2048), generator=torch.Generator().manual_seed(0))
        v = flux_dev.velocity(z, 1.0, cond)
        assert v.shape == z.shape and torch.isfinite(v).all()
        x = flux_dev.decode(z - v)
        assert x.shape == (1, 3, 1024, 2048)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_tiny_flux_on_cuda_bf16(gen, cond2):
    g = TinyFluxGenerator(seed=0, device="cuda", dtype=torch.bfloat16)
    z = rand_latents(2, 8, 16)
    v = g.velocity(z, 0.7, g.condition(PROMPTS, ["main", "pano"]))
    assert v.device.type == "cpu" and v.dtype == torch.float32
    torch.testing.assert_close(v, gen.velocity(z, 0.7, cond2), atol=0.1, rtol=0.1)
