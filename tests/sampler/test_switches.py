"""The sampler switches that separate the paper's text, the authors' code and snell_bench's own
options, each against a hand reference: time travel (``tt_mode``, ``tt_renoise``), the step
(``sde``), the VAE encoding (``encode``), the 8-bit round trip (``quantize``), where phi acts
(``dpa_domain``, ``lpw``) and which pixels receive the panorama (``pano_to_main``)."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from PIL import Image

from snell_bench.imaging.pyramid import pyramid_warp
from snell_bench.models.analytic import AnalyticGenerator
from snell_bench.sampler import SamplerSettings, sample
from snell_bench.sampler.eight_bit import to_8bit_floor, to_8bit_round
from snell_bench.sampler.steps import renoise_euler_maruyama, sde_step
from snell_bench.sampler.views import Views
from tests.sampler.room import room_sphere
from tests.tolerances import EPS64, reordering_tolerance

H, W, HP = 64, 96, 32


@pytest.fixture(scope="module")
def setup():
    scene, r, ws, i_minus = room_sphere(W, H, HP)
    p = ws.pano
    pano = scene.render_panorama(center=p.center, height=p.height, up=-p.rotation[:, 1], forward=p.rotation[:, 2])
    gen = AnalyticGenerator.from_scene(r.image, ws.object_mask, pano)
    return ws, i_minus, gen


class Recorder:
    """A generator that records every velocity call ``(z, sigma)``, decode ``(latent, image)`` and
    encode ``(image, latent, generator)`` of the generator it wraps."""

    def __init__(self, gen) -> None:
        self._gen = gen
        self.velocity_calls, self.decodes, self.encodes = [], [], []

    def __getattr__(self, name):
        return getattr(self._gen, name)

    def velocity(self, z, sigma, cond):
        self.velocity_calls.append((z.clone(), float(sigma)))
        return self._gen.velocity(z, sigma, cond)

    def decode(self, latents):
        out = self._gen.decode(latents)
        self.decodes.append((latents.clone(), out.clone()))
        return out

    def encode(self, images, generator=None):
        out = self._gen.encode(images, generator=generator)
        self.encodes.append((images.clone(), out.clone(), generator))
        return out


def run(setup, s, seed=0):
    ws, i_minus, gen = setup
    rec = Recorder(gen)
    out = sample(rec, ws, i_minus, "p", "p360", s, seed=seed)
    return rec, out


def sigmas_of(setup, s):
    ws, _, gen = setup
    return [float(v) for v in gen.sigmas(s.steps, *ws.camera.shape, kind=s.schedule)]


def exact_renoise(z, sigma, s, n):
    a = (1 - s) / (1 - sigma)
    return a * z + math.sqrt(s * s - a * a * sigma * sigma) * n


def em_renoise(z, sigma, s, n):
    return z + (s - sigma) * (n - z) / (1 - sigma) + abs(s - sigma) * n


def det_step(z, x0, sigma, nxt):
    return z + (nxt - sigma) * (z - x0) / sigma


# T = 5, window [0.2, 0.4): guided time travel at step 1 only; main view 3 repeats, panorama 1
TT = SamplerSettings(steps=5, tt_window=[0.2, 0.4], tt_repeats_main=3, progress=False)
SHAPE = (1, 3 * 8 * 8, H // 8, W // 8)  # the analytic latent space: 8 x 8 blocks
SHAPE_PANO = (1, 3 * 8 * 8, HP // 8, 2 * HP // 8)


class TestGuidedTimeTravel:
    @pytest.mark.parametrize("kind", ["exact", "euler_maruyama"])
    def test_latents_follow_the_hand_formula(self, setup, kind):
        s = replace(TT, tt_renoise=kind)
        rec, _ = run(setup, s)
        sig = sigmas_of(setup, s)
        main = [(z, sg) for z, sg in rec.velocity_calls if z.shape == SHAPE]
        # main-view calls: steps 0, 1, the re-prediction at sigma_1, steps 2, 3, 4
        assert [sg for _, sg in main] == pytest.approx([sig[0], sig[1], sig[1], sig[2], sig[3], sig[4]])
        # the run's draws in order: initial noise (main, panorama), then the two repeats' noise
        g = torch.Generator().manual_seed(0)
        torch.randn(SHAPE, generator=g), torch.randn(SHAPE_PANO, generator=g)
        n1, n2 = torch.randn(SHAPE, generator=g), torch.randn(SHAPE, generator=g)
        # the synchronised estimate at step 1: the third encode (step 0: main, pano; step 1: main)
        x0s = rec.encodes[2][1].double()
        assert rec.encodes[2][0].shape[-2:] == (H, W)
        renoise = exact_renoise if kind == "exact" else em_renoise
        z = main[1][0].double()
        for n in (n1, n2):  # renoise to sigma_0, step back to sigma_1 with the same x0s
            z = det_step(renoise(z, sig[1], sig[0], n.double()), x0s, sig[0], sig[1])
        got = main[2][0].double()
        tol = reordering_tolerance(32, got)  # float32: about 8 roundings per renoise and step, 4 of each
        torch.testing.assert_close(got, z, atol=tol, rtol=0)
        # after the re-prediction both branches are synchronised again and step to sigma_2
        x0s_new = rec.encodes[4][1].double()
        assert rec.encodes[4][0].shape[-2:] == (H, W) and rec.encodes[5][0].shape[-2:] == (HP, 2 * HP)
        torch.testing.assert_close(main[3][0].double(), det_step(got, x0s_new, sig[1], sig[2]), atol=tol, rtol=0)

    def test_panorama_is_resynchronised_with_the_post_travel_main_estimate(self, setup):
        ws, i_minus, _ = setup
        rec, _ = run(setup, TT)
        # decodes: step 0 (main, pano), step 1 (main, pano), the re-predicted main estimate
        pano_img, new_main_img = rec.decodes[3][1], rec.decodes[4][1]
        assert pano_img.shape[-2:] == (HP, 2 * HP) and new_main_img.shape[-2:] == (H, W)
        views = Views(ws, i_minus, TT)
        expected = views.blend_pano(pano_img, new_main_img)
        torch.testing.assert_close(rec.encodes[5][0], expected, atol=1e-6, rtol=0)
        stale = views.blend_pano(pano_img, rec.decodes[2][1])  # the pre-travel main estimate
        assert float((rec.encodes[5][0] - stale).abs().max()) > 1e-4  # 100x the tolerance above

    def test_no_call_at_the_noisier_level_and_repaint_differs(self, setup):
        s = TT
        sig = sigmas_of(setup, s)
        guided, g_out = run(setup, s)
        repaint, r_out = run(setup, replace(s, tt_mode="repaint"))
        assert g_out.model_calls == {"main": 5 + 1, "pano": 5}
        assert r_out.model_calls == {"main": 5 + 2, "pano": 5}
        main_sigmas = [sg for z, sg in repaint.velocity_calls if z.shape == SHAPE]
        assert main_sigmas == pytest.approx([sig[0], sig[1], sig[1], sig[1], sig[2], sig[3], sig[4]])
        assert not torch.equal(g_out.image, r_out.image)

    def test_travel_stops_before_the_first_level(self, setup):
        # window from step 0 with travel length 2: steps 0 and 1 cannot travel, step 2 can
        s = replace(TT, tt_window=[0.0, 0.6], tt_length=2)
        rec, out = run(setup, s)
        assert out.model_calls == {"main": 5 + 1, "pano": 5}

    def test_repeats_of_the_panorama(self, setup):
        rec, out = run(setup, replace(TT, tt_repeats_pano=2))
        assert out.model_calls == {"main": 6, "pano": 6}


class TestSteps:
    def test_euler_maruyama_renoise(self):
        z = torch.randn(1000, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
        got = renoise_euler_maruyama(z, 0.3, 0.5, torch.Generator().manual_seed(1))
        n = torch.randn(1000, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
        ref = z + 0.2 * (n - z) / 0.7 + 0.2 * n  # four roundings per element, in another order
        torch.testing.assert_close(got, ref, atol=reordering_tolerance(4, ref, eps=EPS64), rtol=0)
        with pytest.raises(ValueError, match="renoise needs"):
            renoise_euler_maruyama(z, 0.5, 0.3, torch.Generator())

    def test_sde_step(self):
        g = torch.Generator().manual_seed(0)
        z, x0 = torch.randn(1000, generator=g, dtype=torch.float64), torch.randn(1000, generator=g, dtype=torch.float64)
        got = sde_step(z, x0, 0.6, 0.4, torch.Generator().manual_seed(2))
        n = torch.randn(1000, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
        ref = z - 0.2 * (z - x0) / 0.6 + 0.2 * n
        torch.testing.assert_close(got, ref, atol=reordering_tolerance(4, ref, eps=EPS64), rtol=0)
        # to sigma' = 0: the estimate, no draw
        g2 = torch.Generator().manual_seed(3)
        state = g2.get_state()
        assert torch.equal(sde_step(z, x0, 0.6, 0.0, g2), x0) and torch.equal(g2.get_state(), state)

    def test_sde_in_the_sampler(self, setup):
        s = SamplerSettings(steps=3, time_travel=False, sde=True, progress=False)
        rec, _ = run(setup, s)
        sig = sigmas_of(setup, s)
        g = torch.Generator().manual_seed(0)
        torch.randn(SHAPE, generator=g), torch.randn(SHAPE_PANO, generator=g)
        n = torch.randn(SHAPE, generator=g).double()  # step 0: the main view draws first
        main = [z for z, _ in rec.velocity_calls if z.shape == SHAPE]
        z0, x0s = main[0].double(), rec.encodes[0][1].double()
        expected = z0 + (sig[1] - sig[0]) * (z0 - x0s) / sig[0] + abs(sig[1] - sig[0]) * n
        tol = reordering_tolerance(8, expected)  # one float32 step of a few roundings
        torch.testing.assert_close(main[1].double(), expected, atol=tol, rtol=0)
        # the deterministic step is another latent
        det = det_step(z0, x0s, sig[0], sig[1])
        assert float((main[1].double() - det).abs().max()) > 0.1

    def test_sde_and_stochastic_exclude_each_other(self):
        with pytest.raises(ValueError, match="sampler.sde=true and sampler.stochastic=true"):
            SamplerSettings(sde=True, stochastic=True)


class TestEncode:
    def test_the_sampler_passes_its_generator_for_sample_only(self, setup):
        s = SamplerSettings(steps=2, time_travel=False, progress=False)
        rec, _ = run(setup, s)
        assert rec.encodes and all(g is None for _, _, g in rec.encodes)
        rec, _ = run(setup, replace(s, encode="sample"))
        assert rec.encodes and all(isinstance(g, torch.Generator) for _, _, g in rec.encodes)
        assert len({id(g) for _, _, g in rec.encodes}) == 1  # the run's one generator

    def test_the_run_reports_whether_it_sampled(self, setup):
        s = SamplerSettings(steps=1, time_travel=False, progress=False)
        _, out = run(setup, replace(s, encode="sample"))
        assert out.decisions["encode"] == {"mode": "sample", "posterior_sampled": False}  # analytic

        class WithPosterior(Recorder):
            has_posterior = True

        ws, i_minus, gen = setup
        out = sample(WithPosterior(gen), ws, i_minus, "p", "p", replace(s, encode="sample"))
        assert out.decisions["encode"] == {"mode": "sample", "posterior_sampled": True}

    def test_analytic_has_no_posterior(self, setup):
        gen = setup[2]
        x = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(0))
        g = torch.Generator().manual_seed(5)
        state = g.get_state()
        assert torch.equal(gen.encode(x, generator=g), gen.encode(x)) and torch.equal(g.get_state(), state)


class TestQuantize:
    def test_the_pil_paths(self):
        x = torch.rand(1, 3, 8, 8, generator=torch.Generator().manual_seed(0)) * 1.2 - 0.1
        arr = x[0].permute(1, 2, 0).clamp(0, 1).numpy()
        # diffusers' postprocess: round; the authors' tensor_to_pil: uint8 truncation
        rounded = np.asarray(Image.fromarray((arr * 255).round().astype(np.uint8))).astype(np.float32) / 255
        floored = np.asarray(Image.fromarray((arr * 255).astype(np.uint8))).astype(np.float32) / 255
        assert np.array_equal(to_8bit_round(x)[0].permute(1, 2, 0).numpy(), rounded)
        assert np.array_equal(to_8bit_floor(x)[0].permute(1, 2, 0).numpy(), floored)

    @staticmethod
    def on_grid(img: torch.Tensor) -> bool:
        v = img.double() * 255
        return bool(((v - v.round()).abs() < 1e-4).all())

    def test_estimates_and_synchronised_images_are_8_bit(self, setup):
        s = SamplerSettings(steps=3, time_travel=False, dump_every=1, progress=False)
        rec, out = run(setup, replace(s, quantize=True))
        for d in out.dumps[:-1]:
            for key in ("main_x0", "main_sync", "pano_x0", "pano_sync"):
                assert self.on_grid(d[key]), key
        assert all(self.on_grid(img) for img, _, _ in rec.encodes)
        rec, out = run(setup, s)
        assert not self.on_grid(out.dumps[0]["main_x0"]) and not all(self.on_grid(i) for i, _, _ in rec.encodes)


def dpa(values, lam=0.5):
    """phi of scalars (hand form)."""
    avg = sum(values) / len(values)
    norm = sum(abs(v) for v in values)
    vavg = sum(abs(v) * v for v in values) / norm if norm else avg
    return avg + lam * (vavg - avg)


class TestBlendDomainAndWarp:
    @staticmethod
    def images(seed=0):
        g = torch.Generator().manual_seed(seed)
        return torch.rand(1, 3, H, W, generator=g), torch.rand(1, 3, H, W, generator=g)

    def views(self, setup, **kw):
        ws, i_minus, _ = setup
        s = SamplerSettings(panorama=False, reflection=False, progress=False, **kw)
        return Views(ws, i_minus, s), ws, i_minus

    def test_image_domain_is_phi_in_minus_one_one(self, setup):
        views, ws, _ = self.views(setup)
        x0, _ = self.images()
        out = views.blend_main(x0, None)
        # at every pixel where the warped I⁻ is valid: phi of two values in [-1, 1], mapped back
        a = 2 * x0.double() - 1
        b = 2 * views.imin_main.double() - 1
        avg, vavg = (a + b) / 2, (a.abs() * a + b.abs() * b) / (a.abs() + b.abs()).clamp_min(1e-300)
        ref = (avg + 0.5 * (vavg - avg) + 1) / 2
        ok = views.imin_main_m.expand_as(x0)
        assert ok.float().mean() > 0.5
        torch.testing.assert_close(out[ok].double(), ref[ok], atol=1e-6, rtol=0)
        assert float(dpa([0.6, -0.6])) == 0.0  # 0.8 and 0.2 -> 0.5

    def test_bands_domain_differs(self, setup):
        x0, _ = self.images()
        image = self.views(setup)[0].blend_main(x0, None)
        bands = self.views(setup, dpa_domain="bands")[0].blend_main(x0, None)
        assert float((image - bands).abs().max()) > 0.05

    def test_bands_low_pass_is_signed(self, setup):
        # constant images: every band-pass level is 0, the low-pass level is the value itself;
        # in [-1, 1], 0.8 and 0.2 blend to 0.5 (in [0, 1] they would blend to 0.59)
        from scipy.ndimage import binary_erosion

        ws, _, _ = setup
        s = SamplerSettings(panorama=False, reflection=False, dpa_domain="bands", levels=2, roi=False, progress=False)
        views = Views(ws, torch.full((1, 3, H, W), 0.2), s)
        out = views.blend_main(torch.full((1, 3, H, W), 0.8), None)
        # away (3 coarse pixels) from where the warped I⁻ is invalid
        far = binary_erosion(ws.refraction_valid, iterations=6, border_value=1)
        assert far.sum() > 0.5 * far.size
        m = torch.from_numpy(far)[None, None].expand(1, 3, -1, -1)
        torch.testing.assert_close(out[m], torch.full_like(out[m], 0.5), atol=1e-5, rtol=0)
        assert dpa([0.8, 0.2]) == pytest.approx(0.59)

    def test_lpw_changes_only_the_warp(self, setup):
        ws, i_minus, _ = setup
        x0, _ = self.images()
        on, _, _ = self.views(setup)
        off, _, _ = self.views(setup, lpw=False)
        single, ok = pyramid_warp(i_minus, torch.from_numpy(ws.refraction), levels=1)
        # without lpw: a single-level remap of I⁻; with it: the 5-level warp, another image
        torch.testing.assert_close(off.imin_main, single, atol=1e-6, rtol=0)
        assert torch.equal(off.imin_main_m, ok)
        assert float((on.imin_main - single).abs().max()) > 1e-3
        # the blend is the same phi (whole images in [-1, 1]) either way
        a, b = 2 * x0.double() - 1, 2 * off.imin_main.double() - 1
        avg, vavg = (a + b) / 2, (a.abs() * a + b.abs() * b) / (a.abs() + b.abs()).clamp_min(1e-300)
        ref = (avg + 0.5 * (vavg - avg) + 1) / 2
        m = ok.expand_as(x0)
        torch.testing.assert_close(off.blend_main(x0, None)[m].double(), ref[m], atol=1e-6, rtol=0)

    def test_lpw_with_bands_is_a_pyramid_of_the_single_level_remap(self, setup):
        # bands still need a pyramid; without lpw it samples level k for level k and collapses
        # (masked) to the single-level remap, with lpw to the scale-matched warp
        from snell_bench.imaging.pyramid import collapse

        ws, i_minus, _ = setup
        single, ok = pyramid_warp(i_minus, torch.from_numpy(ws.refraction), levels=1)
        m = ok.expand_as(single)
        for lpw in (False, True):
            views, _, _ = self.views(setup, dpa_domain="bands", lpw=lpw)
            assert len(views.imin_main) == 5
            warped = collapse(views.imin_main, views.imin_main_m)
            diff = float((warped - single)[m].abs().max())
            assert diff < 1e-5 if not lpw else diff > 1e-3, (lpw, diff)

    def test_lpw_pano_makes_the_warps_into_the_panorama_single_level(self, setup):
        # the authors' pyramid warps only into the main view: I⁻ (and the main estimate) reach the
        # panorama through a single-level remap; the warps into the main view keep the pyramid
        ws, i_minus, _ = setup
        s = dict(reflection=False, progress=False)
        on = Views(ws, i_minus, SamplerSettings(**s))
        off = Views(ws, i_minus, SamplerSettings(lpw_pano=False, **s))
        single, ok = pyramid_warp(i_minus, torch.from_numpy(ws.pano_to_persp), levels=1, dest_wrap_x=True)
        torch.testing.assert_close(off.imin_pano, single, atol=1e-6, rtol=0)
        assert torch.equal(off.imin_pano_m, ok)
        assert float((on.imin_pano - single)[ok.expand_as(single)].abs().max()) > 1e-3
        torch.testing.assert_close(off.imin_main, on.imin_main, atol=0, rtol=0)
        # the main estimate through π: the same single-level remap
        x0, _ = self.images()
        x0_pano = torch.rand(1, 3, HP, 2 * HP, generator=torch.Generator().manual_seed(3))
        a, b = off.blend_pano(x0_pano, x0), on.blend_pano(x0_pano, x0)
        assert float((a - b).abs().max()) > 1e-3

    def test_effective_levels(self):
        assert SamplerSettings().effective_levels == 5
        assert SamplerSettings(lpw=False).effective_levels == 1
        assert SamplerSettings(lpw=False, dpa_domain="bands").effective_levels == 5
        assert (SamplerSettings(lpw=False).warp_levels, SamplerSettings().blend_levels) == (1, 1)


class TestPanoToMain:
    def blend(self, setup, mode):
        ws, _, _ = setup
        s = SamplerSettings(reflection=False, pano_to_main=mode, roi=False, progress=False)
        views = Views(ws, torch.full((1, 3, H, W), 0.5), s)
        out = views.blend_main(torch.full((1, 3, H, W), 0.9), torch.full((1, 3, HP, 2 * HP), 0.1))
        return out, ws

    def test_frame_blends_the_panorama_into_non_object_pixels(self, setup):
        frame, ws = self.blend(setup, "frame")
        obj, _ = self.blend(setup, "object")
        outside = ~ws.object_mask & np.isfinite(ws.pano_refraction_frame[..., 0]) & ws.refraction_valid
        assert outside.sum() > 100
        m = torch.from_numpy(outside)[None, None].expand(1, 3, -1, -1)
        # in [-1, 1]: (0.8, -0.8, 0) -> 0 -> 0.5 with the panorama; (0.8, 0) -> 0.6 -> 0.8 without
        assert (dpa([0.8, -0.8, 0.0]) + 1) / 2 == pytest.approx(0.5)
        assert (dpa([0.8, 0.0]) + 1) / 2 == pytest.approx(0.8)
        torch.testing.assert_close(frame[m], torch.full_like(frame[m], 0.5), atol=1e-5, rtol=0)
        torch.testing.assert_close(obj[m], torch.full_like(obj[m], 0.8), atol=1e-5, rtol=0)
        # inside the object both read π⁻¹ of the object pixels: the same
        inside = torch.from_numpy(ws.object_mask)[None, None].expand(1, 3, -1, -1)
        torch.testing.assert_close(frame[inside], obj[inside], atol=1e-5, rtol=0)

    def test_frame_needs_the_field(self, setup):
        ws, i_minus, gen = setup
        import copy

        bare = copy.copy(ws)
        bare.pano_refraction_frame = None
        with pytest.raises(ValueError, match="pano_refraction_frame"):
            sample(gen, bare, i_minus, "p", "p", SamplerSettings(steps=2, progress=False))
        # without the panorama branch, or with object, it is not read
        sample(gen, bare, i_minus, "p", "p", SamplerSettings(steps=2, panorama=False, progress=False))
        sample(gen, bare, i_minus, "p", "p", SamplerSettings(steps=2, pano_to_main="object", progress=False))


class TestWindow:
    @pytest.mark.parametrize("floor,steps", [(False, [2]), (True, [1, 2])])
    def test_floor_rounds_both_bounds_down_as_the_authors(self, setup, floor, steps):
        # T = 6, window [0.25, 0.5]: 0.25 T = 1.5, 0.5 T = 3; exact: i in {2}, rounded down: {1, 2}
        s = SamplerSettings(steps=6, tt_window=[0.25, 0.5], tt_window_floor=floor, progress=False)
        rec, out = run(setup, s)
        sig = sigmas_of(setup, s)
        main = [sg for z, sg in rec.velocity_calls if z.shape == SHAPE]
        # every travelling step re-predicts once at its own level
        assert main == pytest.approx(sorted(sig[:6] + [sig[i] for i in steps], reverse=True))
        assert out.model_calls["main"] == 6 + len(steps)


class TestSettings:
    def test_paper_defaults(self):
        s = SamplerSettings()
        assert (s.tt_mode, s.tt_renoise, s.sde, s.encode, s.quantize, s.dpa_domain, s.pano_to_main) == (
            "guided",
            "exact",
            False,
            "mean",
            False,
            "image",
            "frame",
        )
        assert (s.sync_last_step, s.tt_repeats_main, s.tt_repeats_pano, s.levels, s.lam) == (True, 3, 1, 5, 0.5)

    @pytest.mark.parametrize("key", ["tt_mode", "tt_renoise", "encode", "dpa_domain", "pano_to_main"])
    def test_unknown_values(self, key):
        with pytest.raises(ValueError, match=f"sampler.{key}='nope' is unknown"):
            SamplerSettings(**{key: "nope"})
