"""Baselines through diffusers, on tiny random pipelines saved to a folder (CPU, offline).

FLUX.1 and FLUX Fill (:mod:`snell_bench.models.tiny_flux`), FLUX.2, Qwen-Image and SD3.5
(:mod:`snell_bench.models.tiny_external`) are saved with ``save_pretrained`` and loaded back through
:func:`~snell_bench.models.external.load_pipeline`, the path the real weights take.
"""

import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")

import contextlib
import inspect
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from tolerances import reordering_tolerance

from snell_bench.models import DeviceNotAvailableError, WeightsNotFoundError
from snell_bench.models.external import (
    CallSettings,
    call_settings,
    generate_external,
    inpaint_external,
    load_pipeline,
)
from snell_bench.models.tiny_external import (
    QWEN_IMAGE_PROMPT_TEMPLATE,
    TINY_KINDS,
    build_tiny_pipeline,
    byte_level_symbols,
)
from snell_bench.models.tiny_flux import build_tiny_flux_pipeline

H, W = 32, 48
PROMPT = "a glass sphere on a wooden table"
BASELINES = ("flux2", "qwen_image", "sd3")
#: The ``__call__`` defaults of diffusers 0.42: (steps, guidance, its keyword, negative prompt passed).
DEFAULTS = {
    "Flux2Pipeline": (50, 4.0, "guidance_scale", None),
    "QwenImagePipeline": (50, 4.0, "true_cfg_scale", " "),
    "StableDiffusion3Pipeline": (28, 7.0, "guidance_scale", None),
    "FluxPipeline": (28, 3.5, "guidance_scale", None),
    "FluxFillPipeline": (50, 30.0, "guidance_scale", None),
}
#: The tokenizer components each saved folder must record (model_index.json) and load back as.
TOKENIZERS = {
    "flux2": {"tokenizer": "PixtralProcessor"},
    "qwen_image": {"tokenizer": "Qwen2Tokenizer"},
    "sd3": {"tokenizer": "CLIPTokenizer", "tokenizer_2": "CLIPTokenizer", "tokenizer_3": "ByT5Tokenizer"},
}


@contextlib.contextmanager
def no_torch_dtype_warning():
    """A context in which diffusers' deprecation warning for ``torch_dtype=`` is an error."""
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*torch_dtype.*")
        yield


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """Tiny FLUX, FLUX Fill, FLUX.2, Qwen-Image and SD3 pipelines saved with ``save_pretrained``."""
    root = tmp_path_factory.mktemp("external")
    out = {}
    for name, fill in (("t2i", False), ("fill", True)):
        build_tiny_flux_pipeline(seed=0, fill=fill).save_pretrained(root / name)
        out[name] = str(root / name)
    for kind in BASELINES:
        build_tiny_pipeline(kind, seed=0).save_pretrained(root / kind)
        out[kind] = str(root / kind)
    yield out


@pytest.fixture(scope="module")
def scene():
    g = torch.Generator().manual_seed(0)
    i_minus = torch.rand(1, 3, H, W, generator=g)
    mask = np.zeros((H, W), bool)
    mask[8:24, 16:36] = True
    return i_minus, mask


def generate(folders, seed, name="t2i", **kwargs):
    kwargs.setdefault("steps", 2)
    return generate_external(folders[name], PROMPT, (H, W), seed=seed, device="cpu", **kwargs)


def inpaint(folders, scene, seed):
    i_minus, mask = scene
    return inpaint_external(folders["fill"], PROMPT, i_minus, mask, seed=seed, steps=2, device="cpu")


def reference(folder, pipeline_name, seed, **kwargs):
    """The pipeline's own ``__call__``, loaded from ``folder`` independently of the wrapper."""
    import diffusers

    pipe = getattr(diffusers, pipeline_name).from_pretrained(folder, local_files_only=True, dtype=torch.float32)
    out = pipe(generator=torch.Generator("cpu").manual_seed(seed), output_type="np", **kwargs).images
    return torch.from_numpy(np.ascontiguousarray(out[0])).permute(2, 0, 1)[None]


@pytest.fixture(scope="module")
def generated(folders):
    with no_torch_dtype_warning():  # diffusers' current dtype keyword
        return generate(folders, seed=1)


@pytest.fixture(scope="module")
def inpainted(folders, scene):
    with no_torch_dtype_warning():
        return inpaint(folders, scene, seed=1)


@pytest.fixture(scope="module", params=BASELINES)
def kind(request):
    """A baseline (module-scoped, so that pytest runs the tests of one baseline together and its
    loaded pipeline stays cached)."""
    return request.param


@pytest.fixture(scope="module")
def baseline(folders, kind):
    """``(image, settings)`` of the baseline at seed 1 with 2 steps."""
    with no_torch_dtype_warning():
        return generate(folders, 1, kind, return_settings=True)


def check_image(img):
    assert img.shape == (1, 3, H, W) and img.dtype == torch.float32 and img.device.type == "cpu"
    assert torch.isfinite(img).all() and img.min() >= 0 and img.max() <= 1


# ---------------------------------------------------------------------------- FLUX.1 and FLUX Fill
def test_fill_transformer_reads_latents_masked_latents_and_mask(folders):
    cfg = {k: json.loads((Path(folders[k]) / "transformer" / "config.json").read_text()) for k in ("t2i", "fill")}
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


def test_inpaint_with_a_built_pipeline_equals_the_saved_one(scene, inpainted):
    i_minus, mask = scene
    pipe = build_tiny_flux_pipeline(seed=0, fill=True)
    img, settings = inpaint_external(pipe, PROMPT, i_minus, mask, seed=1, steps=2, return_settings=True)
    # equal up to rounding: weights read from safetensors lie at other memory alignments than
    # freshly allocated ones, and the CPU matmul kernels then sum in another order. The longest
    # reduction is the joint attention over the 512 T5 tokens and the (H / 16) (W / 16) image tokens
    # (the transformer's input projection reads 384 channels, fewer).
    atol = reordering_tolerance(512 + (H // 16) * (W // 16), inpainted)
    torch.testing.assert_close(img, inpainted, rtol=0, atol=atol)
    assert settings == CallSettings("FluxFillPipeline", 2, 30.0, "guidance_scale")
    assert pipe.device.type == "cpu" and pipe.transformer.dtype == torch.float32  # used as it is


def test_inpaint_is_the_pipelines_own_call(folders, scene, inpainted):
    from PIL import Image

    i_minus, mask = scene
    img = Image.fromarray((i_minus[0].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8))
    m = Image.fromarray(mask.astype(np.uint8) * 255)
    ref = reference(
        folders["fill"], "FluxFillPipeline", 1, prompt=PROMPT, image=img, mask_image=m, height=H, width=W,
        num_inference_steps=2,
    )  # fmt: skip
    assert torch.equal(ref, inpainted)


def test_inpaint_mask_must_match_the_image(folders, scene):
    i_minus, _ = scene
    with pytest.raises(ValueError, match="mask"):
        inpaint_external(folders["fill"], PROMPT, i_minus, np.zeros((H, W + 16), bool), steps=1, device="cpu")


def test_a_size_the_pipeline_cannot_make_is_an_error(folders):
    with pytest.raises(ValueError, match="multiples of 16"):
        generate_external(folders["t2i"], PROMPT, (H + 8, W), steps=1, device="cpu")


# ---------------------------------------------------------------------------- FLUX.2, Qwen-Image, SD3.5
def test_saved_folder_records_the_classes(folders, kind):
    index = json.loads((Path(folders[kind]) / "model_index.json").read_text())
    assert index["_class_name"] == TINY_KINDS[kind]
    pipe = load_pipeline(folders[kind], device="cpu")
    assert type(pipe).__name__ == TINY_KINDS[kind]
    for component, cls in TOKENIZERS[kind].items():
        assert index[component] == ["transformers", cls]
        assert type(getattr(pipe, component)).__name__ == cls


def test_baseline_on_cpu(baseline, kind):
    img, settings = baseline
    check_image(img)
    steps, guidance, key, negative = DEFAULTS[TINY_KINDS[kind]]
    assert settings == CallSettings(TINY_KINDS[kind], 2, guidance, key, negative)


def test_baseline_is_deterministic_for_a_seed(folders, baseline, kind):
    assert torch.equal(generate(folders, 1, kind), baseline[0])


def test_baseline_depends_on_the_seed(folders, baseline, kind):
    assert not torch.equal(generate(folders, 2, kind), baseline[0])


def test_baseline_depends_on_the_prompt(folders, baseline, kind):
    other = generate_external(folders[kind], "a red cube", (H, W), seed=1, steps=2, device="cpu")
    assert not torch.equal(other, baseline[0])


def test_baseline_is_the_pipelines_own_call(folders, baseline, kind):
    """The wrapper adds nothing: the pipeline's defaults (Qwen-Image: with the negative prompt " "
    that switches its true CFG on) and the same generator seed give the same image."""
    extra = {"negative_prompt": " "} if kind == "qwen_image" else {}
    ref = reference(
        folders[kind], TINY_KINDS[kind], 1, prompt=PROMPT, height=H, width=W, num_inference_steps=2, **extra
    )
    assert torch.equal(ref, baseline[0])


def test_baseline_guidance_goes_to_the_pipelines_keyword(folders, baseline, kind):
    key = DEFAULTS[TINY_KINDS[kind]][2]
    img = generate(folders, 1, kind, guidance=2.0)
    assert not torch.equal(img, baseline[0])
    extra = {"negative_prompt": " "} if kind == "qwen_image" else {}
    ref = reference(
        folders[kind], TINY_KINDS[kind], 1, prompt=PROMPT, height=H, width=W, num_inference_steps=2, **{key: 2.0},
        **extra,
    )  # fmt: skip
    assert torch.equal(ref, img)


@pytest.mark.parametrize("name", sorted(DEFAULTS))
def test_default_settings_are_the_signatures(name):
    import diffusers

    cls = getattr(diffusers, name)
    steps, guidance, key, negative = DEFAULTS[name]
    assert call_settings(cls) == CallSettings(name, steps, guidance, key, negative)
    params = inspect.signature(cls.__call__).parameters
    assert params["num_inference_steps"].default == steps and params[key].default == guidance
    explicit = call_settings(cls, steps=3, guidance=1.0)
    assert explicit.call_kwargs() == {"num_inference_steps": 3, key: 1.0}  # no CFG: no negative prompt


def test_qwen_template_prefix_is_the_dropped_tokens(folders):
    pipe = load_pipeline(folders["qwen_image"], device="cpu")
    assert pipe.prompt_template_encode == QWEN_IMAGE_PROMPT_TEMPLATE
    prefix = QWEN_IMAGE_PROMPT_TEMPLATE.split("{}")[0]
    assert len(pipe.tokenizer(prefix).input_ids) == pipe.prompt_template_encode_start_idx == 34
    embeds, _ = pipe.encode_prompt("a", device="cpu")
    assert embeds.shape[1] == len(pipe.tokenizer(QWEN_IMAGE_PROMPT_TEMPLATE.format("a")).input_ids) - 34


def test_byte_level_symbols_are_gpt2s():
    from open_clip.tokenizer import bytes_to_unicode

    symbols = byte_level_symbols()
    assert symbols == [bytes_to_unicode()[b] for b in range(256)] and len(set(symbols)) == 256
    assert (symbols[ord(" ")], symbols[ord("\n")], symbols[ord("a")]) == ("Ġ", "Ċ", "a")


def test_tiny_builds_are_deterministic_and_leave_the_global_rng(folders):
    state = torch.random.get_rng_state()
    a, b, c = (build_tiny_pipeline("sd3", seed=s) for s in (0, 0, 1))
    assert torch.equal(torch.random.get_rng_state(), state)
    wa, wb, wc = (p.transformer.proj_out.weight for p in (a, b, c))
    assert torch.equal(wa, wb) and not torch.equal(wa, wc)
    assert not any(p.requires_grad for p in a.transformer.parameters()) and not a.text_encoder_3.training
    with pytest.raises(ValueError, match="flux2"):
        build_tiny_pipeline("sdxl")


# ---------------------------------------------------------------------------- loading
def test_dtype_is_applied(folders):
    pipe = load_pipeline(folders["t2i"], device="cpu", dtype="bf16")
    assert pipe.transformer.dtype == torch.bfloat16 and pipe.device.type == "cpu"
    assert load_pipeline(folders["t2i"], device="cpu").transformer.dtype == torch.float32


def test_each_call_loads_and_the_class_is_honoured(folders):
    """Loading keeps nothing: how long a pipeline lives is the model pool's choice."""
    a = load_pipeline(folders["fill"], pipeline="FluxFillPipeline", device="cpu")
    assert type(a).__name__ == "FluxFillPipeline"
    assert load_pipeline(folders["fill"], pipeline="FluxFillPipeline", device="cpu") is not a
    with pytest.raises(ValueError, match="not a diffusers pipeline"):
        load_pipeline(folders["fill"], pipeline="NoSuchPipeline", device="cpu")


def test_missing_weights_name_the_config_key(tmp_path, scene):
    i_minus, mask = scene
    for model_id in (str(tmp_path / "no_such_model"), "nobody-here/no-such-model", str(tmp_path)):
        with pytest.raises(WeightsNotFoundError, match="method.model_id"):
            generate_external(model_id, PROMPT, (H, W), steps=1, device="cpu")
        with pytest.raises(WeightsNotFoundError, match=r"method.model_id.*model\.fill"):
            inpaint_external(model_id, PROMPT, i_minus, mask, steps=1, device="cpu")


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
def test_no_cuda_and_no_device(folders, scene):
    i_minus, mask = scene
    with pytest.raises(DeviceNotAvailableError, match="device='cpu'"):
        generate_external(folders["t2i"], PROMPT, (H, W), steps=1)
    with pytest.raises(DeviceNotAvailableError, match="model.device=cpu"):
        inpaint_external(folders["fill"], PROMPT, i_minus, mask, steps=1)
    with pytest.raises(DeviceNotAvailableError):
        generate_external(folders["t2i"], PROMPT, (H, W), steps=1, device="cuda")
    with pytest.raises(DeviceNotAvailableError, match="model.device=cpu"):
        inpaint_external(build_tiny_flux_pipeline(seed=0, fill=True), PROMPT, i_minus, mask, device="cuda")
    # the device is resolved before any weight is looked for
    with pytest.raises(DeviceNotAvailableError, match="model.device=cpu"):
        load_pipeline("nobody-here/no-such-model")


def test_a_built_pipeline_is_moved_only_when_asked(scene):
    i_minus, mask = scene
    pipe = build_tiny_flux_pipeline(seed=0, fill=True)
    img = inpaint_external(pipe, PROMPT, i_minus, mask, steps=1, dtype="bf16")
    check_image(img)
    assert pipe.transformer.dtype == torch.bfloat16 and pipe.device.type == "cpu"


# ---------------------------------------------------------------------------- the recipes' baselines
#: What each recipe hands the baselines (DESIGN §6: eval/compare.py, eval/compare_inpaint.py):
#: (the object phrase in their prompts, FLUX t2i steps, Fill steps, Fill guidance, Qwen model, CFG).
RECIPE_BASELINES = {
    "paper": ("a big glass sphere", None, None, None, "Qwen/Qwen-Image", True),
    "authors": ("a solid transparent glass sphere", 28, 30, 30.0, "Qwen/Qwen-Image-2512", False),
}


def _method_cfg(recipe, method):
    from snell_bench.config import compose

    return compose([f"recipe={recipe}", f"method={method}", "output_dir=/tmp/x"])


@pytest.mark.parametrize("recipe", sorted(RECIPE_BASELINES))
def test_the_recipe_sets_the_baselines_methods(recipe):
    from snell_bench.pipeline.methods import baseline_prompt

    phrase, flux_steps, fill_steps, fill_guidance, qwen, cfg_on = RECIPE_BASELINES[recipe]
    t2i = _method_cfg(recipe, "t2i")
    assert t2i.method.steps == flux_steps and phrase in baseline_prompt(t2i)
    assert baseline_prompt(t2i) == str(t2i.scene.prompt).replace("{object}", "sphere").replace(
        "a big glass sphere", phrase
    )
    fill = _method_cfg(recipe, "inpaint")
    assert (baseline_prompt(fill), fill.method.steps, fill.method.guidance) == (phrase, fill_steps, fill_guidance)
    q = _method_cfg(recipe, "qwen_image")
    assert (q.method.model_id, q.method.cfg) == (qwen, cfg_on) and phrase in baseline_prompt(q)
    assert _method_cfg(recipe, "snellcaster").method.steps is None  # the method itself keeps sampler.steps


def _spy(monkeypatch, cls):
    """Record the keywords of every ``cls.__call__`` (signature kept: call_settings reads it)."""
    import functools

    calls = []
    original = cls.__call__

    @functools.wraps(original)
    def spy(self, *args, **kwargs):
        calls.append(kwargs)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(cls, "__call__", spy)
    return calls


@pytest.mark.parametrize("recipe", sorted(RECIPE_BASELINES))
def test_each_baseline_pipeline_receives_the_recipes_prompt_steps_and_guidance(folders, scene, recipe, monkeypatch):
    import diffusers

    from snell_bench.pipeline.methods import baseline_prompt

    _, _, fill_steps, fill_guidance, _, cfg_on = RECIPE_BASELINES[recipe]
    q = _method_cfg(recipe, "qwen_image")
    calls = _spy(monkeypatch, diffusers.QwenImagePipeline)
    generate_external(
        folders["qwen_image"], baseline_prompt(q), (H, W), seed=1, device="cpu", steps=q.method.steps, cfg=q.method.cfg
    )
    (kw,) = calls
    assert kw["prompt"] == baseline_prompt(q) and kw["num_inference_steps"] == 50 and kw["true_cfg_scale"] == 4.0
    assert ("negative_prompt" in kw) is cfg_on  # without one the pipeline skips its true CFG
    fill = _method_cfg(recipe, "inpaint")
    calls = _spy(monkeypatch, diffusers.FluxFillPipeline)
    i_minus, mask = scene
    inpaint_external(
        folders["fill"], baseline_prompt(fill), i_minus, mask, seed=1, device="cpu",
        steps=fill.method.steps, guidance=fill.method.guidance,
    )  # fmt: skip
    (kw,) = calls
    assert kw["prompt"] == baseline_prompt(fill)
    assert (kw["num_inference_steps"], kw["guidance_scale"]) == (fill_steps or 50, fill_guidance or 30.0)


def test_without_cfg_the_qwen_call_passes_no_negative_prompt():
    import diffusers

    on = call_settings(diffusers.QwenImagePipeline)
    off = call_settings(diffusers.QwenImagePipeline, cfg=False)
    assert on.call_kwargs() == {"num_inference_steps": 50, "true_cfg_scale": 4.0, "negative_prompt": " "}
    assert off.call_kwargs() == {"num_inference_steps": 50, "true_cfg_scale": 4.0}
    assert call_settings(diffusers.FluxPipeline, cfg=False) == call_settings(diffusers.FluxPipeline)
