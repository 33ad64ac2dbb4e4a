"""``sampler.latent_dtype=float16`` (the authors' float16 pipeline): the latents the tiny random FLUX
receives are float16 values at every call, through deterministic steps, Euler-Maruyama steps and
time travel alike."""

import pytest
import torch

from snell_bench.optics import compute_warps
from snell_bench.sampler import SamplerSettings, sample
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import place_object
from snell_bench.scene.procedural import ProceduralScene
from tests.sampler.test_switches import Recorder


@pytest.fixture(scope="module")
def scene():
    sc = ProceduralScene("room", seed=1)
    r = sc.render(64, 32)
    obj = place_object(GlassObject.sphere(subdivisions=2), r.depth, r.camera, up_hint=sc.up, relative_size=0.35)
    ws = compute_warps(r.depth, r.camera, obj, pano_height=32)
    return ws, torch.from_numpy(r.image).permute(2, 0, 1)[None].float()


def is_float16(z: torch.Tensor) -> bool:
    """Every value of ``z`` is a float16 number (rounding to float16 changes nothing)."""
    return z.dtype == torch.float32 and torch.equal(z.half().float(), z)


def run(scene, model_dtype, **kw):
    from snell_bench.models.tiny_flux import TinyFluxGenerator

    ws, i_minus = scene
    rec = Recorder(TinyFluxGenerator(seed=0, dtype=model_dtype))  # its modules are in eval mode
    s = SamplerSettings(steps=4, progress=False, tt_window=[0.25, 0.75], tt_repeats_main=2, **kw)
    sample(rec, ws, i_minus, "a glass sphere on a table", "a panorama", s, seed=0)
    return [z for z, _ in rec.velocity_calls]


@pytest.mark.parametrize("kw", [{}, {"sde": True, "tt_renoise": "euler_maruyama"}])
def test_latents_are_float16_between_steps(scene, kw):
    calls = run(scene, "float32", latent_dtype="float16", **kw)
    assert len(calls) > 4  # every step, and the time-travel re-prediction
    assert all(is_float16(z) for z in calls)
    # float32 latents are not: the check means something
    assert not all(is_float16(z) for z in run(scene, "float32", **kw)[1:])


def test_the_authors_float16_model(scene):
    """``model.dtype=float16`` with float16 latents, as the authors' pipeline."""
    calls = run(scene, "float16", latent_dtype="float16", sde=True)
    assert all(is_float16(z) for z in calls)
