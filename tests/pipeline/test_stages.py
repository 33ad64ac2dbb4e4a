"""The pipeline's stages: each one against the functions it wires, and the methods' plumbing."""

import numpy as np
import pytest
import torch
from hydra.errors import ConfigCompositionException
from tolerances import reordering_tolerance

from snell_bench import pipeline
from snell_bench.config import compose

TINY = [
    "scene.width=128",
    "scene.height=64",
    "scene.supersample=1",
    "warps.pano_height=32",
    "warps.cache_dir=null",
    "sampler.steps=3",
    "sampler.progress=false",
    "reference.spp=1",
    "reference.true_spp=1",
    "output_dir=/tmp/x",
]


@pytest.fixture(scope="module")
def inputs():
    return pipeline.prepare_inputs(compose(TINY))


def test_prepare_inputs_equals_the_stages_called_by_hand(inputs):
    from snell_bench.optics.warps import compute_warps
    from snell_bench.scene.objects import GlassObject
    from snell_bench.scene.placement import place_object
    from snell_bench.scene.procedural import ProceduralScene

    scene = ProceduralScene("room", 0)
    r = scene.render(width=128, height=64, supersample=1)
    obj = place_object(
        GlassObject.sphere(ior="glass"),
        r.depth,
        r.camera,
        size=None,
        relative_size=0.25,
        yaw_deg=0.0,
        seed=0,
        up_hint=scene.up,
    )
    ws = compute_warps(r.depth, r.camera, obj, pano_height=32, max_bounces=8, cache_dir=None)
    np.testing.assert_array_equal(inputs.scene.image, r.image)
    np.testing.assert_array_equal(inputs.obj.vertices, obj.vertices)
    np.testing.assert_array_equal(inputs.warps.refraction, ws.refraction)
    np.testing.assert_array_equal(inputs.warps.fresnel, ws.fresnel)
    assert inputs.i_minus.shape == (1, 3, 64, 128) and inputs.i_minus.dtype == torch.float32
    assert set(inputs.timings) == {"scene", "warps", "reference", "true_render"}
    assert inputs.reference is not None and inputs.reference.image.shape == (64, 128, 3)
    assert inputs.true_render is not None


def test_build_object_instantiates_the_factory_with_the_material():
    from snell_bench.scene.objects import GlassObject

    cfg = compose(["object=cylinder", "object.ior=water", "output_dir=/tmp/x"])
    obj = pipeline.build_object(cfg.object)
    ref = GlassObject.cylinder(ior="water")
    np.testing.assert_array_equal(obj.vertices, ref.vertices)
    assert obj.ior == ref.ior == pytest.approx(1.333, abs=1e-3)
    spot = pipeline.build_object(compose(["object=spot", "output_dir=/tmp/x"]).object)
    assert spot.name and len(spot.mesh.faces) > 1000


def test_generators_get_their_model_keys(inputs):
    from snell_bench.models.analytic import AnalyticGenerator
    from snell_bench.models.tiny_flux import TinyFluxGenerator

    gen = pipeline.build_generator(
        compose(["model=tiny_flux", "model.guidance=2.0", "output_dir=/tmp/x"]).model, inputs
    )
    assert isinstance(gen, TinyFluxGenerator) and gen.guidance == 2.0
    ana = pipeline.build_generator(compose(["model.prior_std=0.07", "output_dir=/tmp/x"]).model, inputs)
    assert isinstance(ana, AnalyticGenerator) and ana.prior_std == 0.07


def test_run_method_applies_switches_and_shares_the_generator(inputs):
    base = compose(TINY)
    snell = pipeline.run_method(pipeline.apply_method(base), inputs)
    assert snell.warps is inputs.warps and "warps" not in snell.timings
    assert snell.image.shape == (1, 3, 64, 128) and 0 <= snell.image.min() and snell.image.max() <= 1
    assert snell.stats["model_calls"]["pano"] == 3
    again = pipeline.run_method(pipeline.apply_method(base), inputs)
    torch.testing.assert_close(again.image, snell.image, rtol=0, atol=0)  # deterministic for the seed
    assert len(inputs.pool.held("generator")) == 1 and again.timings["generator"] == snell.timings["generator"]
    # a method with its own warp settings gets its own warps
    adaptive = pipeline.run_method(pipeline.apply_method(compose([*TINY, "method=adaptive"])), inputs)
    assert adaptive.warps is not inputs.warps and "warps" in adaptive.timings
    assert adaptive.warps.options["infinity_tolerance_px"] == 1.0
    t2i = pipeline.run_method(pipeline.apply_method(compose([*TINY, "method=t2i"])), inputs)
    assert t2i.stats["model_calls"]["pano"] == 0


def test_methods_that_cannot_run_here_are_skipped(inputs):
    if torch.cuda.is_available():
        pytest.skip("a CUDA machine runs external methods")
    with pytest.raises(pipeline.Skip, match="model.device=cpu"):
        pipeline.run_method(pipeline.apply_method(compose([*TINY, "method=flux2_dev"])), inputs)


def test_an_external_baseline_runs_from_a_local_folder_on_the_cpu(tmp_path, inputs):
    """``method.model_id`` a diffusers folder (tiny random SD3 here), ``model.device=cpu``: the
    pipeline's image, seeded with the cell's seed, its settings recorded."""
    from snell_bench.models.tiny_external import build_tiny_pipeline

    build_tiny_pipeline("sd3", seed=0).save_pretrained(tmp_path / "sd3")
    over = [*TINY, "method=sd35_large", f"method.model_id={tmp_path / 'sd3'}", "model.device=cpu", "method.steps=2"]
    res = pipeline.run_method(pipeline.apply_method(compose(over)), inputs)
    again = pipeline.run_method(pipeline.apply_method(compose([*over, "seed=1"])), inputs)
    assert len(inputs.pool.held("pipeline")) == 1  # loaded once, kept by the inputs' pool
    assert res.image.shape == (1, 3, 64, 128) and 0 <= res.image.min() and res.image.max() <= 1
    used = res.stats["pipeline"]
    assert used["steps"] == 2 and used["guidance"] == 7.0  # the pipeline's own default guidance
    assert used["prompt"] == pipeline.full_prompt(compose(over))
    assert not torch.equal(res.image, again.image)


def test_scores_against_the_reference_and_the_true_render(inputs):
    from snell_bench.metrics import load_scorers, masked_psnr
    from snell_bench.utils.io import saved_pixels

    cfg = pipeline.apply_method(compose(TINY))
    res = pipeline.run_method(cfg, inputs, scorers=load_scorers(cfg.metrics))
    img = saved_pixels(res.image[0].permute(1, 2, 0).numpy())  # the 8-bit values image.png holds
    m = res.scores["metrics"]
    assert m["psnr"] == masked_psnr(img, inputs.reference.image, inputs.reference.mask)
    assert m["psnr_true"] == masked_psnr(img, inputs.true_render, inputs.warps.object_mask)
    assert m["lpips"] is None and "lpips_weights" in res.scores["missing"]["lpips"]
    assert "metrics" in res.timings
    # metrics.score_file=false: the sampler's float image, as cells recorded before the key existed
    floats = pipeline.apply_method(compose([*TINY, "metrics.score_file=false"]))
    res = pipeline.run_method(floats, inputs, scorers=load_scorers(floats.metrics))
    img = res.image[0].permute(1, 2, 0).numpy()
    assert res.scores["metrics"]["psnr"] == masked_psnr(img, inputs.reference.image, inputs.reference.mask)


def test_full_prompt_names_the_object():
    cfg = compose(["object=spot", "output_dir=/tmp/x"])
    p = pipeline.full_prompt(cfg)
    assert "{object}" not in p and "glass cow" in p


def test_a_missing_renderer_is_a_reason_not_a_failure(monkeypatch, inputs):
    import sys

    monkeypatch.setitem(sys.modules, "mitsuba", None)  # as if the render extra were not installed
    ref, reason = pipeline.render_reference(compose(TINY), inputs.scene, inputs.obj)
    assert ref is None and "render extra" in reason


def test_the_reference_gets_one_settings_object_of_the_config(monkeypatch, inputs):
    """Every key of the ``reference`` node that the settings have, ``spp`` replaced when given,
    ``warps.edge_threshold`` and the run's seed."""
    import dataclasses

    from snell_bench.pipeline import inputs as stages
    from snell_bench.render import ReferenceSettings

    seen = []
    monkeypatch.setattr(stages, "render", lambda *args: seen.append(args[4]) or inputs.reference)
    cfg = compose(TINY)
    pipeline.render_reference(cfg, inputs.scene, inputs.obj, spp=6)
    overrides = ["reference.sampler=independent", "reference.crop=false", "warps.edge_threshold=0.08", "seed=4"]
    pipeline.render_reference(compose([*TINY, *overrides]), inputs.scene, inputs.obj)
    r = cfg.reference
    keys = ("unobserved_spp", "crop", "crop_margin_px", "self_noise", "unobserved_threshold", "reflection")
    expected = ReferenceSettings(
        spp=6,
        sampler=str(r.sampler.value),
        edge_threshold=cfg.warps.edge_threshold,
        seed=cfg.seed,
        **{k: r[k] for k in keys},
    )
    changed = dataclasses.replace(expected, spp=1, sampler="independent", crop=False, edge_threshold=0.08, seed=4)
    assert seen == [expected, changed]
    assert type(seen[0].sampler) is str


def test_each_variation_has_its_own_seed(inputs):
    """The sampling seed is seed + variation (so a text-only baseline differs between variations);
    variation 0 keeps the run's seed."""
    from omegaconf import OmegaConf

    cfg = pipeline.apply_method(compose([*TINY, "model=tiny_flux", "scene.source=procedural", "method=t2i"]))
    assert pipeline.cell_seed(cfg) == 0
    a = pipeline.run_method(cfg, inputs).image
    cfg1 = pipeline.apply_method(
        compose([*TINY, "model=tiny_flux", "scene.source=procedural", "method=t2i", "scene.variation=1", "seed=0"])
    )
    assert pipeline.cell_seed(cfg1) == 1 and OmegaConf.to_yaml(cfg1.model) == OmegaConf.to_yaml(cfg.model)
    assert not torch.equal(a, pipeline.run_method(cfg1, inputs).image)


def test_flux_fill_without_its_device_or_weights_is_skipped(inputs):
    if torch.cuda.is_available():
        pytest.skip("a CUDA machine would try to load the weights")
    with pytest.raises(pipeline.Skip, match="cannot run here"):
        pipeline.run_method(pipeline.apply_method(compose([*TINY, "model=flux_dev", "method=inpaint"])), inputs)


def test_inpainting_runs_a_tiny_flux_fill_on_the_cpu(inputs):
    """``model=tiny_flux``: a tiny random ``FluxFillPipeline`` repaints the object's silhouette from
    the object phrase, with the authors' 30 steps and guidance 30."""
    cfg = pipeline.apply_method(
        compose([*TINY, "model=tiny_flux", "scene.source=procedural", "method=inpaint", "method.steps=2"])
    )
    res = pipeline.run_method(cfg, inputs)
    m = torch.from_numpy(inputs.warps.object_mask)
    assert res.stats["pipeline"]["steps"] == 2 and res.stats["pipeline"]["guidance"] == 30.0
    assert res.stats["pipeline"]["prompt"] == pipeline.object_phrase(cfg) == "a big glass sphere"
    assert float((res.image - inputs.i_minus).abs()[0].amax(0)[m].mean()) > 0.01


def test_inpainting_masks():
    from types import SimpleNamespace

    cfg = compose([*TINY, "method=inpaint", "method.mask=box", "method.mask_dilate_px=1"])
    m = np.zeros((8, 10), bool)
    m[2, 3] = m[4, 6] = True
    box = pipeline.inpaint_mask(cfg, SimpleNamespace(object_mask=m))
    assert box.sum() == (3 + 2) * (4 + 2) - 4  # the 3 x 4 box grown by a disc of radius 1 (no corners)
    with pytest.raises(ConfigCompositionException, match="method.mask=ellipse"):  # a choice: checked when composed
        compose([*TINY, "method=inpaint", "method.mask=ellipse"])


def test_warps_traced_without_a_region_of_interest_are_cached_apart(tmp_path, inputs):
    cfg = compose([*TINY, f"warps.cache_dir={tmp_path}"])
    roi = pipeline.trace_warps(inputs.scene, inputs.obj, cfg.warps)
    full = pipeline.trace_warps(
        inputs.scene, inputs.obj, compose([*TINY, f"warps.cache_dir={tmp_path}", "warps.roi=false"]).warps
    )
    assert roi.stats["roi"] is True and full.stats["roi"] is False
    assert full.stats["traced_primary_rays"] > roi.stats["traced_primary_rays"]
    np.testing.assert_array_equal(full.refraction, roi.refraction)
    assert len(list(tmp_path.glob("*.npz"))) == 2


@pytest.mark.parametrize("model", ["analytic", "tiny_flux"])
def test_relighting_keeps_the_best_of_n_candidates(inputs, model):
    """``method=snellcaster_relit``: N candidates of the model's relighter (the traced shadow, the
    tiny Kontext), seeded from the cell's seed; the one closest to the un-relit image inside the
    object is kept, every score recorded."""
    import json

    from snell_bench.relight import candidate_seeds, masked_psnr

    cfg = pipeline.apply_method(
        compose([*TINY, f"model={model}", "method=snellcaster_relit", "relight.candidates=3", "relight.steps=2"])
    )
    res = pipeline.run_method(cfg, inputs)
    rec = res.stats["relight"]
    json.dumps(rec, allow_nan=False)
    assert [c["seed"] for c in rec["candidates"]] == candidate_seeds(pipeline.cell_seed(cfg), 3)
    scores = [c["psnr_db"] if c["psnr_db"] is not None else float("inf") for c in rec["candidates"]]
    assert rec["chosen"] == int(np.argmax(scores))
    assert masked_psnr(res.image, res.unrelit, inputs.warps.object_mask) == pytest.approx(scores[rec["chosen"]])
    assert rec["prompt"] == "Create soft shadows and caustics under a big glass sphere"
    assert "relight" in res.timings and not torch.equal(res.image, res.unrelit)


def test_the_panorama_prior_is_not_the_truth_unless_asked(inputs):
    """``model.pano_prior``: ``other`` (default: another variation's panorama from the same pose),
    ``blur``, ``truth``, ``observed``; the analytic backend starts from what it is given."""
    from scipy.ndimage import gaussian_filter1d

    from snell_bench.scene.procedural import ProceduralScene
    from snell_bench.scene.sources import OTHER_VARIATION_OFFSET, panorama_prior, scene_panorama

    sc, ws = inputs.scene, inputs.warps
    truth = scene_panorama(sc, ws.pano)
    assert np.array_equal(panorama_prior(sc, ws, inputs.i_minus, "truth"), truth)
    other = panorama_prior(sc, ws, inputs.i_minus, "other")
    p = ws.pano
    again = ProceduralScene(sc.source.kind, seed=sc.source.seed + OTHER_VARIATION_OFFSET).render_panorama(
        center=p.center, height=p.height, up=-p.rotation[:, 1], forward=p.rotation[:, 2]
    )
    assert np.array_equal(other, again) and other.shape == truth.shape
    assert -10 * np.log10(((other - truth) ** 2).mean()) < 25  # wrong, not the truth
    blur = panorama_prior(sc, ws, inputs.i_minus, "blur")
    s = truth.shape[0] / 32
    ref = gaussian_filter1d(gaussian_filter1d(truth, s, axis=0, mode="nearest"), s, axis=1, mode="wrap")
    np.testing.assert_allclose(blur, ref, atol=1e-6)
    with pytest.raises(ValueError, match="model.pano_prior"):
        panorama_prior(sc, ws, inputs.i_minus, "oracle")
    for kind, expected in (("other", other), ("truth", truth)):
        gen = pipeline.build_generator(compose([*TINY, f"model.pano_prior={kind}"]).model, inputs)
        # the prior is held as latents: an encode and a decode (192 x 192 products) in float32
        atol = reordering_tolerance(2 * 192, gen._priors["pano"], expected)
        np.testing.assert_allclose(gen.prior_image("pano")[0].permute(1, 2, 0).numpy(), expected, atol=atol)
