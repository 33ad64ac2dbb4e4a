"""The synchronized sampler on a small procedural scene with the analytic backend (and tiny FLUX)."""

from dataclasses import replace

import numpy as np
import pytest
import torch
from conftest import sphere_at

from snell_bench.metrics.refraction import refraction_psnr
from snell_bench.models.analytic import AnalyticGenerator
from snell_bench.optics import compute_warps
from snell_bench.sampler import SamplerSettings, sample
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import place_object
from snell_bench.scene.procedural import ProceduralScene

H, W, HP = 96, 160, 64


def pano_of(scene, ws):
    p = ws.pano
    return scene.render_panorama(center=p.center, height=p.height, up=-p.rotation[:, 1], forward=p.rotation[:, 2])


@pytest.fixture(scope="module")
def setup():
    scene = ProceduralScene("room", seed=0)
    r = scene.render(W, H)
    obj = place_object(GlassObject.sphere(subdivisions=4), r.depth, r.camera, up_hint=scene.up, relative_size=0.35)
    ws = compute_warps(r.depth, r.camera, obj, pano_height=HP)
    i_minus = torch.from_numpy(r.image).permute(2, 0, 1)[None].float()
    gen = AnalyticGenerator.from_scene(r.image, ws.object_mask, pano_of(scene, ws))
    return scene, r, obj, ws, i_minus, gen


FAST = SamplerSettings(steps=10, progress=False)


def run(setup, settings=FAST, seed=0, ws=None, gen=None):
    _, _, _, ws0, i_minus, gen0 = setup
    return sample(gen or gen0, ws or ws0, i_minus, "p", "p360", settings, seed=seed)


@pytest.fixture(scope="module")
def full(setup):
    return run(setup)


def test_synchronisation_fixes_the_glass(setup, full):
    _, _, _, ws, i_minus, _ = setup
    assert ws.object_mask.sum() > 300
    none = run(setup, replace(FAST, sync="none"))
    psnr_sync = refraction_psnr(full.image, i_minus, ws)
    psnr_none = refraction_psnr(none.image, i_minus, ws)
    assert psnr_sync > psnr_none + 5.0, (psnr_sync, psnr_none)
    assert psnr_sync > 20.0
    assert none.panorama is None and none.model_calls == {"main": 10, "pano": 0}


@pytest.mark.parametrize(
    "change",
    [
        dict(reflection=False),
        dict(panorama=False),
        dict(dpa=False),
        dict(lpw=False),
        dict(time_travel=False),
        dict(stochastic=True),
        dict(schedule="linear"),
    ],
    ids=lambda d: next(iter(d)),
)
def test_every_switch_changes_the_output(setup, full, change):
    other = run(setup, replace(FAST, **change))
    assert torch.isfinite(other.image).all()
    assert not torch.equal(other.image, full.image)


def test_bitwise_deterministic(setup, full):
    again = run(setup)
    assert torch.equal(again.image, full.image) and torch.equal(again.panorama, full.panorama)
    stoch = replace(FAST, stochastic=True)
    assert torch.equal(run(setup, stoch, seed=3).image, run(setup, stoch, seed=3).image)
    assert not torch.equal(run(setup, seed=1).image, full.image)


def test_time_travel_spends_no_wasted_model_call(setup, full):
    # guided time travel (the default since the paper's recipe; before it, the repaint loop was the
    # default and spent 4 + 6 x 3 main calls): T = 10, window [2, 8): per window step one call at
    # sigma_i, none at the noisier level, one re-prediction at sigma_i for a branch that travelled
    assert full.model_calls == {"main": 10 + 6, "pano": 10}
    both = run(setup, replace(FAST, tt_repeats_pano=2))
    assert both.model_calls == {"main": 10 + 6, "pano": 10 + 6}
    # the repeats renoise and step back without a model call: 5 repeats cost what 2 cost
    five = run(setup, replace(FAST, tt_repeats_main=5))
    assert five.model_calls == {"main": 10 + 6, "pano": 10}
    # repaint: a block re-predicted at every level, R times
    repaint = run(setup, replace(FAST, tt_mode="repaint"))
    assert repaint.model_calls == {"main": 4 + 6 * 3, "pano": 10}
    longer = run(setup, replace(FAST, tt_mode="repaint", tt_length=2, tt_repeats_pano=2))
    # blocks of 2 steps starting at 2, 4, 6: 6 steps x 3 repeats (main), x 2 (pano)
    assert longer.model_calls == {"main": 4 + 6 * 3, "pano": 4 + 6 * 2}
    no_tt = run(setup, replace(FAST, time_travel=False))
    assert no_tt.model_calls == {"main": 10, "pano": 10}


def test_outputs_finite_and_in_range(full):
    for img in (full.image, full.panorama):
        assert torch.isfinite(img).all() and img.min() >= 0 and img.max() <= 1
    assert full.panorama.shape == (1, 3, HP, 2 * HP)


def test_unit_ior_and_empty_mask_are_finite(setup):
    scene, r, obj, ws, i_minus, _ = setup
    ws1 = compute_warps(r.depth, r.camera, obj.with_ior(1.0), pano_height=HP)
    gen1 = AnalyticGenerator.from_scene(r.image, ws1.object_mask, pano_of(scene, ws1))
    out = run(setup, ws=ws1, gen=gen1)
    assert torch.isfinite(out.image).all()
    # a sphere far smaller than a pixel, between pixel centres: empty mask
    f, cx, cy = r.camera.K[0, 0], r.camera.K[0, 2], r.camera.K[1, 2]
    c = np.array([(10.5 - cx) / f * 2.0, (10.5 - cy) / f * 2.0, 2.0])
    ws0 = compute_warps(r.depth, r.camera, sphere_at(c, 0.05 / f, subdivisions=2), pano_height=HP)
    assert not ws0.object_mask.any()
    gen0 = AnalyticGenerator.from_scene(r.image, ws0.object_mask, pano_of(scene, ws0))
    out0 = run(setup, ws=ws0, gen=gen0)
    assert torch.isfinite(out0.image).all() and torch.isfinite(out0.panorama).all()


def test_dumps_and_bad_settings(setup):
    out = run(setup, replace(FAST, dump_every=5, time_travel=False))
    assert [d["step"] for d in out.dumps] == [0, 5]
    assert out.dumps[0]["main_sync"].shape == (1, 3, H, W)
    with pytest.raises(ValueError, match="sampler.sync"):
        SamplerSettings(sync="sometimes")
    with pytest.raises(ValueError, match="tt_window"):
        SamplerSettings(tt_window=[0.8, 0.2])
    _, _, _, ws, i_minus, gen = setup
    with pytest.raises(ValueError, match="i_minus"):
        sample(gen, ws, i_minus[..., :-8], "p", "p", FAST)


def test_tiny_flux_two_branch_loop_with_time_travel():
    """The full FLUX code path (packing, VAE, text encoders, batched branches) on CPU."""
    from snell_bench.models.tiny_flux import TinyFluxGenerator

    scene = ProceduralScene("room", seed=1)
    r = scene.render(128, 64)
    obj = place_object(GlassObject.sphere(subdivisions=3), r.depth, r.camera, up_hint=scene.up, relative_size=0.35)
    ws = compute_warps(r.depth, r.camera, obj, pano_height=64)  # 64 x 128: the same latent size as the view
    i_minus = torch.from_numpy(r.image).permute(2, 0, 1)[None].float()
    gen = TinyFluxGenerator(seed=0)
    s = SamplerSettings(steps=5, progress=False, tt_window=[0.2, 0.8], tt_repeats_main=2)
    a = sample(gen, ws, i_minus, "a glass sphere on a table", "a panorama", s, seed=0)
    assert torch.isfinite(a.image).all() and torch.isfinite(a.panorama).all()
    assert a.image.shape == (1, 3, 64, 128) and a.panorama.shape == (1, 3, 64, 128)
    assert a.model_calls["main"] > a.model_calls["pano"] == 5
    b = sample(gen, ws, i_minus, "a glass sphere on a table", "a panorama", s, seed=0)
    assert torch.equal(a.image, b.image)


class _Schedule:
    """A generator that records its schedule requests and can hand back a given schedule."""

    def __init__(self, gen, sigmas=None) -> None:
        self._gen, self._sigmas, self.calls = gen, sigmas, []

    def __getattr__(self, name):
        return getattr(self._gen, name)

    def sigmas(self, num_steps, height, width, kind="flux"):
        self.calls.append((num_steps, height, width, kind))
        return self._gen.sigmas(num_steps, height, width, kind) if self._sigmas is None else self._sigmas


@pytest.mark.parametrize("kind", ["flux", "linear"])
def test_schedule_comes_from_the_generator(setup, kind):
    _, _, _, ws, i_minus, gen = setup
    s = replace(FAST, steps=3, schedule=kind, time_travel=False)
    spy = _Schedule(gen)
    out = sample(spy, ws, i_minus, "p", "p360", s, seed=0)
    assert spy.calls == [(3, H, W, kind)]
    assert torch.equal(out.image, run(setup, s).image)
    # another schedule from the generator changes the result
    other = _Schedule(gen, torch.tensor([1.0, 0.9, 0.3, 0.0], dtype=torch.float64))
    assert not torch.equal(sample(other, ws, i_minus, "p", "p360", s, seed=0).image, out.image)


def test_schedule_of_the_wrong_length_is_an_error(setup):
    _, _, _, ws, i_minus, gen = setup
    bad = _Schedule(gen, torch.linspace(1.0, 0.0, 3, dtype=torch.float64))
    with pytest.raises(ValueError, match="noise levels for 3 steps"):
        sample(bad, ws, i_minus, "p", "p360", replace(FAST, steps=3), seed=0)
