"""The synchronized sampler at the paper's sizes with FLUX.1-dev's real architecture on ``meta``.

FLUX.1-dev (19 double and 38 single blocks, 3072 wide), T5-XXL, CLIP-L and the VAE are built from
their published configurations on the ``meta`` device (shapes, no data: every operation is free of
arithmetic), in bfloat16, and the loop runs end to end at 720 x 1280 with a 1024 x 2048 panorama and
T = 20, under both recipes, for every method of the ablation and of the time-travel experiment.
Checked against closed forms: the packed sequence of every velocity call (3600 and 8192 image
tokens, 512 T5 tokens), the model calls per branch (:func:`expected_model_calls`, derived from the
settings by hand below) and the shapes and dtype of the images.

On ``meta`` an operation costs its Python dispatch alone, so shapes repeat for free only when they
are not propagated again: the transformer (:meth:`FluxGenerator.velocity`), the imaging stages
(:func:`~snell_bench.utils.tensors.meta_shape_cache`) and the VAE (:meth:`FluxGenerator.decode`,
``encode``) run once per input shape, every later call answered with that output's shape, and here
the text encoders run once per prompt.

The warps are built in closed form at full size (right shapes and dtypes, valid coordinates inside
their sources, NaN where invalid) rather than traced: tracing 720 x 1280 and a 1024-row panorama
takes ~4 s on two cores, and on ``meta`` only their shapes reach the loop (the sampler's decisions
read the object mask and the Fresnel map on the host, which these have).
"""

from dataclasses import replace
from importlib.resources import files

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from snell_bench.config.compose import compose
from snell_bench.imaging.equirect import PanoramaCamera
from snell_bench.models.flux import FluxGenerator
from snell_bench.optics.warpset import WarpSet
from snell_bench.sampler import SamplerSettings, expected_model_calls, sample
from snell_bench.scene.camera import Camera

ABLATION = ["snellcaster", "no_pano", "no_tt", "no_dpa", "no_lpw", "no_reflection"]
TIME_TRAVEL = ["tt_r1", "tt_joint_r3", "tt_joint_r5", "tt_joint_r8", "tt_main_r3", "tt_main_r5", "tt_main_r8"]
RECIPES = ["paper", "authors"]
PROMPT, PANO_PROMPT = "a glass sphere on a table in a room", "a 360 degree panorama of a room"


def synthetic_warps(height: int, width: int, pano_height: int) -> WarpSet:
    """Warps of the given sizes in closed form: a disc-shaped object below the image centre seen
    mirrored through its centre (π^R) and reflecting the rows above it, the frame spanning the
    panorama's central quarter linearly (π⁻¹ and its inverse π), the mirror rays on the far side."""
    H, W, Hp, Wp = height, width, pano_height, 2 * pano_height
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    cx, cy, r = W / 2, 0.6 * H, 0.15 * H
    obj = (xs - cx) ** 2 + (ys - cy) ** 2 < r * r
    nan = np.float32(np.nan)

    def where(m, x, y):
        return np.stack([np.where(m, x, nan), np.where(m, y, nan)], -1).astype(np.float32)

    ones = np.ones((H, W), bool)
    u, v = 3 * Wp / 8 + xs * Wp / (4 * W), 3 * Hp / 8 + ys * Hp / (4 * H)  # the frame in the panorama
    mirrored_u, mirrored_v = 3 * Wp / 8 + (2 * cx - xs) * Wp / (4 * W), 3 * Hp / 8 + (2 * cy - ys) * Hp / (4 * H)
    frame = where(ones, u, v)
    frame[obj] = where(obj, mirrored_u, mirrored_v)[obj]
    pv, pu = np.mgrid[0:Hp, 0:Wp].astype(np.float32)
    px, py = (pu - 3 * Wp / 8) * 4 * W / Wp, (pv - 3 * Hp / 8) * 4 * H / Hp
    seen = (px >= 0) & (px <= W - 1) & (py >= 0) & (py <= H - 1)
    pano_to_persp = where(seen, px, py)
    on_object = np.zeros_like(seen)
    on_object[seen] = obj[py[seen].round().astype(int), px[seen].round().astype(int)]
    return WarpSet(
        camera=Camera.from_fov(W, H, 60.0),
        pano=PanoramaCamera(center=np.array([0.0, 0.0, 2.5]), rotation=np.eye(3), height=Hp),
        ior=1.5,
        object_mask=obj,
        refraction=where(ones, np.where(obj, 2 * cx - xs, xs), np.where(obj, 2 * cy - ys, ys)),
        refraction_valid=ones,
        refraction_kind=np.where(obj, 1, 0).astype(np.int8),
        bounces=np.where(obj, 2, 0).astype(np.uint8),
        fresnel=np.where(obj, 0.04, 0.0).astype(np.float32),
        reflection=where(obj, xs, np.clip(ys - 2 * r, 0, H - 1)),
        reflection_valid=obj,
        pano_refraction=where(obj, mirrored_u, mirrored_v),
        pano_refraction_valid=obj,
        pano_refraction_frame=frame,
        pano_refraction_frame_valid=ones,
        pano_reflection=where(obj, (u + Wp / 2) % Wp, Hp - 1 - v),
        pano_reflection_valid=obj,
        pano_to_persp=pano_to_persp,
        pano_to_persp_valid=seen,
        pano_to_persp_object=on_object,
    )


class Recording:
    """The generator as the sampler sees it, recording the latent and the text tokens of every
    velocity call. The text encoders run once per prompt (on ``meta`` their output depends on the
    prompt's token count alone)."""

    def __init__(self, gen: FluxGenerator):
        self.gen, self.name, self.geometry = gen, gen.name, gen.geometry
        self.device, self.dtype, self.has_posterior = gen.device, gen.dtype, gen.has_posterior
        self.velocity_inputs: list[tuple[tuple, tuple]] = []
        self._conditions: dict = {}

    def condition(self, prompts, views):
        key = (tuple(prompts), tuple(views))
        if key not in self._conditions:
            self._conditions[key] = self.gen.condition(prompts, views)
        return self._conditions[key]

    def velocity(self, z, sigma, cond):
        self.velocity_inputs.append((tuple(self.gen.pack(z).shape), tuple(cond.data["prompt_embeds"].shape)))
        return self.gen.velocity(z, sigma, cond)

    def decode(self, z):
        return self.gen.decode(z)

    def encode(self, x, generator=None):
        return self.gen.encode(x, generator=generator)

    def sigmas(self, *args, **kwargs):
        return self.gen.sigmas(*args, **kwargs)


@pytest.fixture(scope="module")
def flux_dev():
    """FLUX.1-dev's architecture on ``meta`` in bfloat16, and the shapes its transformer saw."""
    gen = FluxGenerator.from_pretrained(random_init=True, device="meta", dtype="bfloat16")
    seen = []

    def note(module, args, kwargs):
        seen.append({k: tuple(kwargs[k].shape) for k in ("hidden_states", "encoder_hidden_states", "img_ids")})

    handle = gen.pipe.transformer.register_forward_pre_hook(note, with_kwargs=True)
    yield Recording(gen), seen
    handle.remove()


@pytest.fixture(scope="module")
def paper():
    """The paper's preset under each recipe: the config, and each method's sampler settings."""
    out = {}
    for recipe in RECIPES:
        cfg = compose(["preset=paper", f"recipe={recipe}"])
        methods = {}
        for m in ABLATION + TIME_TRAVEL:  # as the pipeline merges them (apply_method)
            node = OmegaConf.load(files("snell_bench.conf") / "method" / f"{m}.yaml")
            methods[m] = OmegaConf.to_object(OmegaConf.merge(cfg.sampler, node.get("sampler") or {}))
        out[recipe] = cfg, methods
    return out


@pytest.fixture(scope="module")
def scene(paper):
    cfg, _ = paper["paper"]
    H, W, Hp = int(cfg.scene.height), int(cfg.scene.width), int(cfg.warps.pano_height)
    assert (H, W, Hp) == (720, 1280, 1024)  # the paper's sizes
    return synthetic_warps(H, W, Hp), torch.full((1, 3, H, W), 0.5)


def run(flux_dev, scene, settings: SamplerSettings):
    gen, _ = flux_dev
    ws, i_minus = scene
    gen.velocity_inputs.clear()
    res = sample(gen, ws, i_minus, PROMPT, PANO_PROMPT, replace(settings, progress=False), seed=0)
    return res, list(gen.velocity_inputs)


def check_run(res, velocity_inputs, settings: SamplerSettings) -> None:
    """(a) the packed sequences, (b) the model calls, (c) the images."""
    # (a) 2 x 2 patches of the 1/8 latents: (720/16)(1280/16) and (1024/16)(2048/16) tokens of 64
    # channels; T5's 512 tokens of 4096
    main, pano = ((1, 3600, 64), (1, 512, 4096)), ((1, 8192, 64), (1, 512, 4096))
    assert set(velocity_inputs) <= {main, pano}
    # (b)
    calls = {"main": velocity_inputs.count(main), "pano": velocity_inputs.count(pano)}
    assert res.model_calls == calls == expected_model_calls(settings)
    # (c)
    assert res.image.shape == (1, 3, 720, 1280) and res.image.dtype == torch.float32
    assert res.image.device.type == "meta"  # no data to bring back
    if settings.uses_panorama:
        assert res.panorama.shape == (1, 3, 1024, 2048) and res.panorama.dtype == torch.float32
    else:
        assert res.panorama is None


#: The model calls at T = 20 under both recipes, by hand: the window is steps 4 to 15 (12 steps,
#: [0.2 T, 0.8 T) as written and rounded down alike), guided time travel re-predicts a branch that
#: travelled once per window step however many repeats: 20 + 12 = 32, else 20.
BY_HAND = {
    "snellcaster": (32, 20),
    "no_pano": (32, 0),
    "no_tt": (20, 20),
    "no_dpa": (32, 20),
    "no_lpw": (32, 20),
    "no_reflection": (32, 20),
    "tt_r1": (20, 20),
    "tt_joint_r3": (32, 32),
    "tt_joint_r5": (32, 32),
    "tt_joint_r8": (32, 32),
    "tt_main_r3": (32, 20),
    "tt_main_r5": (32, 20),
    "tt_main_r8": (32, 20),
}


@pytest.mark.parametrize("recipe", RECIPES)
def test_closed_form_of_the_paper_methods(paper, recipe):
    _, methods = paper[recipe]
    assert {m: tuple(expected_model_calls(s).values()) for m, s in methods.items()} == BY_HAND


def test_closed_form_by_hand():
    """The other branches of the closed form: repaint, longer travels, rounding of the window."""
    S = SamplerSettings
    assert expected_model_calls(S(tt_mode="repaint")) == {"main": 44, "pano": 20}  # 20 + 2 x 12
    assert expected_model_calls(S(tt_mode="repaint", tt_repeats_pano=3)) == {"main": 44, "pano": 44}
    # blocks of 5 from step 4: 4-8, 9-13, 14-18 (15 steps, the last past the window's end)
    assert expected_model_calls(S(tt_mode="repaint", tt_length=5)) == {"main": 50, "pano": 20}
    # blocks of 4 from step 5 of 10, the second cut at the end: 5 steps
    assert expected_model_calls(S(steps=10, tt_mode="repaint", tt_length=4, tt_window=[0.5, 1.0]))["main"] == 20
    # guided, two levels back: steps 0 and 1 of the window [0, 5) have no level to travel to
    assert expected_model_calls(S(steps=10, tt_length=2, tt_window=[0.0, 0.5]))["main"] == 13
    # T = 6, window [1.5, 3): step 2 as written, steps 1 and 2 rounded down
    assert expected_model_calls(S(steps=6, tt_window=[0.25, 0.5]))["main"] == 7
    assert expected_model_calls(S(steps=6, tt_window=[0.25, 0.5], tt_window_floor=True))["main"] == 8
    assert expected_model_calls(S(sync="none")) == {"main": 20, "pano": 0}
    assert expected_model_calls(S(tt_repeats_main=1, tt_repeats_pano=1)) == {"main": 20, "pano": 20}


def test_the_transformer_sees_the_paper_sequences(flux_dev, scene, paper):
    """FLUX.1-dev's transformer runs on the 3600 and 8192 image tokens with 512 text tokens."""
    _, methods = paper["paper"]
    run(flux_dev, scene, methods["snellcaster"])
    _, seen = flux_dev
    assert {s["hidden_states"] for s in seen} == {(1, 3600, 64), (1, 8192, 64)}
    assert {s["encoder_hidden_states"] for s in seen} == {(1, 512, 4096)}
    assert {s["img_ids"] for s in seen} == {(3600, 3), (8192, 3)}


@pytest.mark.parametrize("method", ABLATION + TIME_TRAVEL)
@pytest.mark.parametrize("recipe", RECIPES)
def test_every_method_at_full_size(flux_dev, scene, paper, recipe, method):
    """The method's settings under the recipe through the whole loop."""
    _, methods = paper[recipe]
    res, inputs = run(flux_dev, scene, methods[method])
    check_run(res, inputs, methods[method])


@pytest.mark.parametrize(
    "switches",
    [
        dict(tt_mode="repaint"),
        dict(tt_mode="repaint", tt_repeats_pano=3, tt_length=5),
        dict(steps=10, tt_mode="repaint", tt_length=4, tt_window=[0.5, 1.0], tt_repeats_pano=2),
        dict(steps=10, tt_length=2, tt_window=[0.0, 0.5], tt_repeats_pano=3),
        dict(steps=6, tt_window=[0.25, 0.5], tt_window_floor=True),
        dict(sync="none"),
    ],
)
def test_other_time_travels_at_full_size(flux_dev, scene, paper, switches):
    """The loop against the closed form where the paper's methods do not go."""
    _, methods = paper["paper"]
    settings = replace(methods["snellcaster"], **switches)
    res, inputs = run(flux_dev, scene, settings)
    check_run(res, inputs, settings)
