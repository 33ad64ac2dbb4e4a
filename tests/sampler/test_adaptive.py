"""Per-scene decisions (reflection, panorama branch) and the region of interest of the sampler."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from tolerances import reordering_tolerance

from snell_bench.models.analytic import AnalyticGenerator
from snell_bench.optics import compute_warps
from snell_bench.sampler import SamplerSettings, sample
from snell_bench.sampler.adaptive import decide
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import place_object
from snell_bench.scene.procedural import ProceduralScene

H, W, HP = 96, 160, 64
FAST = SamplerSettings(steps=6, progress=False)


@pytest.fixture(scope="module")
def scene_setup():
    scene = ProceduralScene("room", seed=0)
    r = scene.render(W, H)
    out = {}
    for ior in (1.5, 1.02):
        obj = place_object(
            GlassObject.sphere(ior=ior, subdivisions=4), r.depth, r.camera, up_hint=scene.up, relative_size=0.35
        )
        out[ior] = compute_warps(r.depth, r.camera, obj, pano_height=HP)
    ws = out[1.5]
    p = ws.pano
    pano = scene.render_panorama(center=p.center, height=p.height, up=-p.rotation[:, 1], forward=p.rotation[:, 2])
    gen = AnalyticGenerator.from_scene(r.image, ws.object_mask, pano)
    i_minus = torch.from_numpy(r.image).permute(2, 0, 1)[None].float()
    return out, gen, i_minus


def test_reflection_kept_only_where_fresnel_matters(scene_setup):
    warps, _, _ = scene_setup
    ws = warps[1.5]
    m = ws.object_mask
    s, d, keep = decide(ws, FAST)
    assert keep is None and s.reflection and d["reflection"]["share_kept"] == 1.0
    thr = float(np.median(ws.fresnel[m]))
    s, d, keep = decide(ws, replace(FAST, reflection_min_fresnel=thr))
    assert s.reflection and keep is not None
    np.testing.assert_array_equal(keep, m & (ws.fresnel >= thr))
    assert d["reflection"]["share_kept"] == pytest.approx((ws.fresnel[m] >= thr).mean())
    weak = warps[1.02]  # a weak lens: Fresnel far below 1 % except at grazing rims
    fw = weak.fresnel[weak.object_mask]
    assert np.median(fw) < 1e-3
    s, d, keep = decide(weak, replace(FAST, reflection_min_fresnel=min(float(fw.max()) + 1e-6, 1.0)))
    assert d["reflection"]["pixels_kept"] == 0 and not s.reflection and keep is None
    assert d["reflection"]["max_fresnel"] == pytest.approx(float(fw.max()))
    json.dumps(d)  # JSON-ready


def test_panorama_skipped_only_above_the_observed_share(scene_setup):
    warps, _, _ = scene_setup
    for ws in warps.values():
        m = ws.object_mask
        observed = (ws.refraction_valid & ws.reflection_valid)[m].mean()
        for thr, skip in ((0.0, True), (observed, True), (min(observed + 1e-6, 1.0), observed >= 1.0), (None, False)):
            s, d, _ = decide(ws, replace(FAST, skip_panorama_above=thr))
            assert s.uses_panorama == (not skip)
            assert d["panorama"]["used"] == (not skip)
        # without reflection only the refracted rays count
        s, d, _ = decide(ws, replace(FAST, reflection=False, skip_panorama_above=0.0))
        assert d["panorama"]["observed_share"] == pytest.approx(ws.refraction_valid[m].mean())
    with pytest.raises(ValueError, match="skip_panorama_above"):
        SamplerSettings(skip_panorama_above=1.5)
    with pytest.raises(ValueError, match="reflection_min_fresnel"):
        SamplerSettings(reflection_min_fresnel=-0.1)


def test_skipping_the_panorama_halves_the_model_calls(scene_setup):
    warps, gen, i_minus = scene_setup
    ws = warps[1.5]
    full = sample(gen, ws, i_minus, "p", "p360", replace(FAST, time_travel=False), seed=0)
    skip = sample(gen, ws, i_minus, "p", "p360", replace(FAST, time_travel=False, skip_panorama_above=0.0), seed=0)
    assert full.model_calls == {"main": 6, "pano": 6} and skip.model_calls == {"main": 6, "pano": 0}
    assert skip.panorama is None and skip.decisions["panorama"]["used"] is False
    assert torch.isfinite(skip.image).all()


def test_region_of_interest_gives_the_same_images(scene_setup):
    warps, gen, i_minus = scene_setup
    ws = warps[1.5]
    a = sample(gen, ws, i_minus, "p", "p360", replace(FAST, roi=False), seed=3)
    b = sample(gen, ws, i_minus, "p", "p360", replace(FAST, roi=True), seed=3)
    assert a.model_calls == b.model_calls
    # The window runs the same operations per pixel, at other positions in the kernels' loops. Each
    # model call chains a decode and an encode (192 x 192 products) and a warp (under 60 terms per
    # pyramid level); the Euler steps mix the estimates convexly, so the rounding of all calls adds up
    # to sum(1 - sigma' / sigma) calls' worth over the steps run (4.03 here, time-travel repeats included).
    length = 5 * (2 * 192 + 60 * FAST.levels)
    torch.testing.assert_close(a.image, b.image, atol=reordering_tolerance(length, a.image), rtol=0)
    torch.testing.assert_close(a.panorama, b.panorama, atol=reordering_tolerance(length, a.panorama), rtol=0)
    assert b.decisions["roi"] is True and a.decisions["roi"] is False


def test_negligible_reflection_changes_little(scene_setup):
    """Dropping reflection below R = 0.05 changes the linear colour of a pixel by at most 0.05."""
    warps, gen, i_minus = scene_setup
    ws = warps[1.5]
    a = sample(gen, ws, i_minus, "p", "p360", FAST, seed=1)
    b = sample(gen, ws, i_minus, "p", "p360", replace(FAST, reflection_min_fresnel=0.05), seed=1)
    m = torch.from_numpy(ws.object_mask & (ws.fresnel < 0.05))
    assert m.any()
    # the synchronized sampler propagates the change through later steps; it stays small
    diff = (a.image - b.image).abs().amax(1)[0]
    assert float(diff[~torch.from_numpy(ws.object_mask)].max()) < 0.02
