"""The sampler at the ends of the noise schedule, one and many steps, and bf16 model outputs."""

import math

import pytest
import torch
import torch.nn.functional as F

from snell_bench.models.analytic import AnalyticGenerator
from snell_bench.optics import compute_warps
from snell_bench.sampler import SamplerSettings, renoise, sample, stochastic_step, sync_step
from snell_bench.sampler.steps import euler_estimate
from snell_bench.scene.objects import GlassObject
from snell_bench.scene.placement import place_object
from snell_bench.scene.procedural import ProceduralScene

H, W, HP = 96, 160, 32


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a.double() - b.double()) ** 2).mean())
    return math.inf if mse == 0 else 10 * math.log10(1.0 / mse)


class TestStepEnds:
    def test_sync_step_to_zero_returns_the_estimate_exactly(self):
        g = torch.Generator().manual_seed(0)
        z = torch.randn(4, 8, generator=g) * 1e3
        x0 = torch.randn(4, 8, generator=g, dtype=torch.float64)
        for sigma in (1.0, 0.5, 1e-6, 1e-30):
            out = sync_step(z, x0, sigma, 0.0)
            assert torch.equal(out, x0) and out.dtype == x0.dtype
            assert out.data_ptr() != x0.data_ptr()  # a copy, not an alias
        assert torch.equal(sync_step(z, x0, 0.0, 0.0), x0)
        with pytest.raises(ValueError, match="sigma = 0"):
            sync_step(z, x0, 0.0, 0.5)

    def test_sync_step_is_finite_next_to_zero(self):
        z, x0 = torch.randn(1000), torch.randn(1000)
        for sigma, nxt in [(1.0, 1e-12), (1e-6, 1e-7), (1e-30, 1e-31), (1.0, 1.0)]:
            out = sync_step(z, x0, sigma, nxt)
            assert torch.isfinite(out).all()
            r = nxt / sigma
            torch.testing.assert_close(out, r * z + (1 - r) * x0)

    @pytest.mark.parametrize("eta", [0.0, 0.5, 1.0])
    def test_stochastic_step_ends(self, eta):
        g = torch.Generator().manual_seed(1)
        z, x0 = torch.randn(10_000, generator=g), torch.randn(10_000, generator=g)
        # to sigma' = 0: the estimate itself, whatever the starting level
        for sigma in (1.0, 1e-6, 0.0):
            assert torch.equal(stochastic_step(z, x0, sigma, 0.0, g, eta), x0)
        # from sigma = 1: the implied noise is z - 0 x0 = z
        out = stochastic_step(z, x0, 1.0, 0.5, g, eta)
        assert torch.isfinite(out).all()
        if eta == 0.0:
            torch.testing.assert_close(out, 0.5 * x0 + 0.5 * z)
        # next to zero: finite
        assert torch.isfinite(stochastic_step(z, x0, 1e-6, 1e-7, g, eta)).all()

    def test_stochastic_step_from_zero(self):
        g = torch.Generator().manual_seed(2)
        x0 = torch.full((200_000,), 0.25, dtype=torch.float64)
        z = x0.clone()
        # a full renoise does not use the implied noise: finite, with the exact marginal
        out = stochastic_step(z, x0, 0.0, 0.4, g, eta=1.0)
        assert torch.isfinite(out).all()
        assert float(out.mean()) == pytest.approx(0.6 * 0.25, abs=4e-3)
        assert float(out.std()) == pytest.approx(0.4, rel=1e-2)
        # and the same draw as from any other level
        a = stochastic_step(z, x0, 0.0, 0.4, torch.Generator().manual_seed(5), eta=1.0)
        b = stochastic_step(z, x0, 0.7, 0.4, torch.Generator().manual_seed(5), eta=1.0)
        assert torch.equal(a, b)
        with pytest.raises(ValueError, match="sigma = 0"):
            stochastic_step(z, x0, 0.0, 0.4, g, eta=0.5)

    def test_renoise_ends(self):
        g = torch.Generator().manual_seed(3)
        z = torch.randn(100_000, generator=g, dtype=torch.float64)
        # sigma = 0 -> s = 1: pure noise, independent of z
        n = renoise(z, 0.0, 1.0, torch.Generator().manual_seed(9))
        assert torch.equal(n, renoise(z * 0 + 7.0, 0.0, 1.0, torch.Generator().manual_seed(9)))
        assert float(n.mean()) == pytest.approx(0.0, abs=2e-2) and float(n.std()) == pytest.approx(1.0, rel=1e-2)
        # just below 1 -> 1: still pure noise
        assert torch.isfinite(renoise(z, 1.0 - 1e-9, 1.0, g)).all()
        # no travel: z itself
        for s in (0.0, 0.3):
            assert torch.equal(renoise(z, s, s, g), z)
        # sigma = 0 -> s: the forward marginal (1 - s) z + s n
        zs = renoise(z, 0.0, 0.2, g)
        assert float((zs - 0.8 * z).std()) == pytest.approx(0.2, rel=1e-2)


@pytest.fixture(scope="module")
def setup():
    scene = ProceduralScene("room", seed=0)
    r = scene.render(W, H)
    obj = place_object(GlassObject.sphere(subdivisions=4), r.depth, r.camera, up_hint=scene.up, relative_size=0.35)
    ws = compute_warps(r.depth, r.camera, obj, pano_height=HP)
    p = ws.pano
    pano = scene.render_panorama(center=p.center, height=p.height, up=-p.rotation[:, 1], forward=p.rotation[:, 2])
    i_minus = torch.from_numpy(r.image).permute(2, 0, 1)[None].float()
    gen = AnalyticGenerator.from_scene(r.image, ws.object_mask, pano)
    return ws, i_minus, gen


class TestVelocityEnds:
    def test_velocity_at_sigma_one_and_near_zero(self, setup):
        _, _, gen = setup
        g = torch.Generator().manual_seed(0)
        shape = (1,) + gen.geometry.latent_shape(H, W)
        eps = torch.randn(shape, generator=g)
        cond = gen.condition(["p"], ["main"])
        mu = gen._priors["main"]
        # sigma = 1: z is pure noise, the estimate is the prior mean and v = z - mu exactly
        v1 = gen.velocity(eps, 1.0, cond)
        assert torch.isfinite(v1).all()
        torch.testing.assert_close(v1, eps - mu)
        torch.testing.assert_close(euler_estimate(eps, v1, 1.0), mu)
        # sigma -> 0: z is (almost) a data sample x0; the estimate is x0, and v stays finite and O(1)
        x0 = mu + gen._std["main"] * torch.randn(shape, generator=g)
        for sigma, v_tol in ((1e-3, 1e-3), (1e-6, 0.5)):
            z = (1 - sigma) * x0 + sigma * eps
            v = gen.velocity(z, sigma, cond)
            assert torch.isfinite(v).all()
            assert float(v.abs().max()) < 10.0
            # against the closed form in float64: the Euler estimate (what the sampler uses) keeps
            # float32 precision; v itself loses digits as 1 / sigma (float32 cancellation in z - E[x0|z])
            post = gen.posterior_mean(z.double(), sigma, cond)
            torch.testing.assert_close(euler_estimate(z, v, sigma).double(), post, atol=1e-6, rtol=0)
            torch.testing.assert_close(v.double(), (z.double() - post) / sigma, atol=v_tol, rtol=0)
            assert float((post - x0).abs().max()) < 10 * sigma + 1e-5  # and E[x0 | z] -> x0
        # a batch of levels at both ends at once
        vb = gen.velocity(torch.cat([eps, x0]), torch.tensor([1.0, 1e-6]), gen.condition(["p", "p"], ["main", "main"]))
        assert torch.isfinite(vb).all()
        torch.testing.assert_close(vb[:1], v1)
        with pytest.raises(ValueError, match="sigma = 0"):
            gen.velocity(x0, 0.0, cond)


def check_image(img):
    assert img.shape == (1, 3, H, W) and img.dtype == torch.float32
    assert torch.isfinite(img).all()
    assert float(img.min()) >= 0.0 and float(img.max()) <= 1.0


class TestSampleEnds:
    def test_one_step(self, setup):
        ws, i_minus, gen = setup
        # pano_to_main=object (the default before the paper's recipe): outside the object the blend
        # reads the estimate and I⁻ only; with ``frame`` it also reads the (32 px high, so blurred)
        # panorama there
        s = SamplerSettings(steps=1, progress=False, pano_to_main="object")
        out = sample(gen, ws, i_minus, "p", "p360", s, seed=0)
        check_image(out.image)
        assert torch.isfinite(out.panorama).all()
        assert out.model_calls == {"main": 1, "pano": 1}
        # one step from sigma = 1: the estimate is the prior, synchronised; far from the glass that is I⁻
        # (the 5-level pyramid warp reaches about 2^5 px beyond the object)
        mask = torch.from_numpy(ws.object_mask)[None, None].float()
        far = (F.max_pool2d(mask, 65, 1, 32) == 0).expand_as(out.image)
        assert far.float().mean() > 0.25
        assert float((out.image - i_minus).abs()[far].max()) < 2e-3
        outside = (F.max_pool2d(mask, 33, 1, 16) == 0).expand_as(out.image)
        assert psnr(out.image[outside], i_minus[outside]) > 45.0

    @pytest.mark.parametrize("stochastic", [False, True])
    def test_fifty_steps(self, setup, stochastic):
        ws, i_minus, gen = setup
        s = SamplerSettings(steps=50, progress=False, time_travel=False, stochastic=stochastic)
        out = sample(gen, ws, i_minus, "p", "p360", s, seed=0)
        check_image(out.image)
        assert torch.isfinite(out.panorama).all()
        assert out.model_calls == {"main": 50, "pano": 50}
        # outside the glass the result is a sample of the room's prior around I⁻
        m = ~torch.from_numpy(ws.object_mask)
        assert psnr(out.image[..., m], i_minus[..., m]) > 20.0


class _BF16Velocity:
    """The analytic generator with its velocity rounded to bfloat16 (as a bf16 transformer returns)."""

    def __init__(self, gen: AnalyticGenerator, cast_back: bool) -> None:
        self._gen, self._cast_back = gen, cast_back
        self.name, self.geometry = gen.name, gen.geometry

    def __getattr__(self, name):
        return getattr(self._gen, name)

    def velocity(self, z, sigma, cond):
        v = self._gen.velocity(z, sigma, cond).to(torch.bfloat16)
        return v.to(z.dtype) if self._cast_back else v


class TestBF16Outputs:
    @pytest.fixture(scope="class")
    @staticmethod
    def fp32_runs(setup):
        ws, i_minus, gen = setup
        return {
            st: sample(
                gen, ws, i_minus, "p", "p360", SamplerSettings(steps=8, progress=False, stochastic=st), seed=0
            ).image
            for st in (False, True)
        }

    @pytest.mark.parametrize("cast_back", [True, False], ids=["cast_back", "bf16"])
    @pytest.mark.parametrize("stochastic", [False, True], ids=["det", "stoch"])
    def test_bf16_velocity_close_to_fp32(self, setup, fp32_runs, cast_back, stochastic):
        ws, i_minus, gen = setup
        s = SamplerSettings(steps=8, progress=False, stochastic=stochastic)
        out = sample(_BF16Velocity(gen, cast_back), ws, i_minus, "p", "p360", s, seed=0)
        check_image(out.image)
        assert torch.isfinite(out.panorama).all()
        assert psnr(out.image, fp32_runs[stochastic]) > 30.0
        assert not torch.equal(out.image, fp32_runs[stochastic])  # the rounding did reach the output

    def test_bf16_velocity_without_synchronisation(self, setup):
        ws, i_minus, gen = setup
        s = SamplerSettings(steps=8, progress=False, sync="none")
        ref = sample(gen, ws, i_minus, "p", "p360", s, seed=0).image
        out = sample(_BF16Velocity(gen, False), ws, i_minus, "p", "p360", s, seed=0).image
        check_image(out)
        assert psnr(out, ref) > 30.0
