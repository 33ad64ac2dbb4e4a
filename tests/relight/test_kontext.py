"""FLUX Kontext as a relighter, on the tiny random Kontext (CPU, offline), with a tiny LoRA."""

import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")

import pytest
import torch
from tolerances import reordering_tolerance

from snell_bench.models.errors import DeviceNotAvailableError, WeightsNotFoundError
from snell_bench.models.tiny_flux import build_tiny_flux_pipeline
from snell_bench.relight import Relighter
from snell_bench.relight.kontext import KontextRelighter, call_defaults, resolve_lora

H, W = 32, 48
PROMPT = "Create soft shadows and caustics under a big glass sphere"
#: The longest reduction of the tiny Kontext at H x W: the joint attention over the 512 T5 tokens and
#: the packed noisy and context latents, (H / 16) (W / 16) tokens each. Two paths that compute the
#: same float32 image in other summation orders agree to reordering_tolerance(KONTEXT_REDUCTION, image).
KONTEXT_REDUCTION = 512 + 2 * (H // 16) * (W // 16)


def image(h=H, w=W, seed=0):
    return torch.rand(1, 3, h, w, generator=torch.Generator().manual_seed(seed))


@pytest.fixture(scope="module")
def tiny():
    return KontextRelighter.tiny(seed=0, steps=2)


@pytest.fixture(scope="module")
def lora_dir(tmp_path_factory):
    """A LoRA with random non-zero weights on the tiny transformer's attention projections."""
    from diffusers import FluxKontextPipeline
    from peft import LoraConfig
    from peft.utils import get_peft_model_state_dict

    pipe = build_tiny_flux_pipeline(seed=0, kontext=True)
    config = LoraConfig(r=4, lora_alpha=8, target_modules=["to_q", "to_k", "to_v", "to_out.0"], init_lora_weights=False)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(1)
        pipe.transformer.add_adapter(config)
    folder = tmp_path_factory.mktemp("lora")
    FluxKontextPipeline.save_lora_weights(folder, transformer_lora_layers=get_peft_model_state_dict(pipe.transformer))
    return folder


@pytest.fixture(scope="module")
def base_output(tiny):
    return tiny.relight(image(), prompt=PROMPT, seed=5)


class TestTinyKontext:
    def test_protocol_and_records(self, tiny):
        assert isinstance(tiny, Relighter)
        assert tiny.name == "tiny_kontext"
        d = tiny.describe()
        assert "Kontext" in d and "2 steps" in d and "no LoRA" in d

    def test_output(self, base_output):
        out = base_output
        assert out.shape == (1, 3, H, W) and out.dtype == torch.float32 and out.device.type == "cpu"
        assert torch.isfinite(out).all() and out.min() >= 0 and out.max() <= 1

    def test_deterministic_and_seeded(self, tiny, base_output):
        assert torch.equal(tiny.relight(image(), prompt=PROMPT, seed=5), base_output)
        assert not torch.equal(tiny.relight(image(), prompt=PROMPT, seed=6), base_output)

    def test_depends_on_the_image(self, tiny, base_output):
        assert not torch.equal(tiny.relight(image(seed=1), prompt=PROMPT, seed=5), base_output)

    def test_equals_the_pipeline_called_directly(self, tiny, base_output):
        steps, guidance = call_defaults(tiny.pipe)
        direct = tiny.pipe(
            image=image(),
            prompt=PROMPT,
            height=H,
            width=W,
            max_area=H * W,
            _auto_resize=False,
            num_inference_steps=2,
            guidance_scale=guidance,
            generator=torch.Generator("cpu").manual_seed(5),
            output_type="pt",
        ).images
        torch.testing.assert_close(base_output, direct, rtol=0, atol=0)

    def test_defaults_from_the_call_signature(self, tiny):
        import inspect

        params = inspect.signature(type(tiny.pipe).__call__).parameters
        r = KontextRelighter(tiny.pipe)
        assert r.steps == params["num_inference_steps"].default
        assert r.guidance == params["guidance_scale"].default
        r = KontextRelighter(tiny.pipe, steps=3, guidance=2.5)
        assert (r.steps, r.guidance) == (3, 2.5)

    def test_size_not_a_multiple_of_16(self, tiny):
        out = tiny.relight(image(36, 40), prompt=PROMPT, seed=5)
        assert out.shape == (1, 3, 36, 40) and torch.isfinite(out).all()

    def test_from_a_saved_folder(self, tiny, base_output, tmp_path):
        tiny.pipe.save_pretrained(tmp_path / "kontext")
        r = KontextRelighter.from_pretrained(tmp_path / "kontext", device="cpu", steps=2)
        assert r.name == "flux_kontext" and "kontext" in r.describe()
        # the same float32 computation; weights read from safetensors lie at other memory alignments
        # than freshly allocated ones, and the CPU kernels may then sum in another order
        out = r.relight(image(), prompt=PROMPT, seed=5)
        torch.testing.assert_close(out, base_output, rtol=0, atol=reordering_tolerance(KONTEXT_REDUCTION, base_output))


class TestLoRA:
    def test_changes_the_output_and_scale_zero_is_off(self, lora_dir, base_output):
        with_lora = KontextRelighter.tiny(seed=0, steps=2, lora=lora_dir)
        out = with_lora.relight(image(), prompt=PROMPT, seed=5)
        assert out.shape == base_output.shape
        assert (out - base_output).abs().max() > 1e-3
        assert "LoRA" in with_lora.describe() and "scale 1" in with_lora.describe()
        off = KontextRelighter.tiny(seed=0, steps=2, lora=lora_dir, lora_scale=0.0)
        # scale 0 adds exact zeros to the base projections, in another pipeline instance: rounding only
        atol = reordering_tolerance(KONTEXT_REDUCTION, base_output)
        torch.testing.assert_close(off.relight(image(), prompt=PROMPT, seed=5), base_output, rtol=0, atol=atol)

    def test_a_file_path_and_reloading(self, lora_dir, base_output):
        files = list(lora_dir.glob("*.safetensors"))
        assert len(files) == 1
        pipe = build_tiny_flux_pipeline(seed=0, kontext=True)
        a = KontextRelighter(pipe, steps=2, lora=files[0])
        b = KontextRelighter(pipe, steps=2, lora=lora_dir)  # the same adapter name, loaded again
        out_a = a.relight(image(), prompt=PROMPT, seed=5)
        # the same adapter in freshly loaded tensors: equal up to the summation order
        atol = reordering_tolerance(KONTEXT_REDUCTION, out_a)
        torch.testing.assert_close(b.relight(image(), prompt=PROMPT, seed=5), out_a, rtol=0, atol=atol)
        assert (out_a - base_output).abs().max() > 1e-3

    @pytest.mark.parametrize("lora", ["/no/such/lora.safetensors", "nobody/no-such-lora"])
    def test_missing(self, lora, tiny):
        with pytest.raises(WeightsNotFoundError, match="relight.lora"):
            KontextRelighter(tiny.pipe, lora=lora)

    def test_folder_without_weights(self, tmp_path):
        with pytest.raises(WeightsNotFoundError, match="relight.lora"):
            resolve_lora(tmp_path)
        with pytest.raises(WeightsNotFoundError, match="relight.lora"):
            resolve_lora(tmp_path, weight_name="lora.safetensors")


class TestErrors:
    @pytest.mark.parametrize("model_id", ["/no/such/kontext", "nobody/no-such-kontext"])
    def test_missing_weights_name_the_key(self, model_id):
        with pytest.raises(WeightsNotFoundError, match="model.relighter.model_id"):
            KontextRelighter.from_pretrained(model_id, device="cpu")

    @pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA is available here")
    def test_no_cuda_names_the_key(self):
        with pytest.raises(DeviceNotAvailableError, match="model.device=cpu"):
            KontextRelighter.from_pretrained()

    def test_bad_image(self, tiny):
        with pytest.raises(ValueError, match=r"\(1, 3, H, W\)"):
            tiny.relight(image()[0], prompt=PROMPT, seed=0)
