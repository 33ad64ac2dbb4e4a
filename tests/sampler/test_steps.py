"""Schedules and pure steps against closed forms and diffusers' own scheduler."""

import math

import pytest
import torch

from snell_bench.sampler import euler_estimate, flux_sigmas, linear_sigmas, renoise, stochastic_step, sync_step


class TestSchedules:
    def test_linear(self):
        s = linear_sigmas(4)
        torch.testing.assert_close(s, torch.tensor([1.0, 0.75, 0.5, 0.25, 0.0], dtype=torch.float64))

    @pytest.mark.parametrize("steps,seq", [(20, 3600), (4, 64), (28, 4096)])
    def test_flux_matches_diffusers(self, steps, seq):
        import numpy as np
        from diffusers import FlowMatchEulerDiscreteScheduler
        from diffusers.pipelines.flux.pipeline_flux import calculate_shift

        sch = FlowMatchEulerDiscreteScheduler(
            use_dynamic_shifting=True, base_shift=0.5, max_shift=1.15, base_image_seq_len=256, max_image_seq_len=4096
        )
        sch.set_timesteps(sigmas=np.linspace(1.0, 1 / steps, steps), mu=calculate_shift(seq))
        torch.testing.assert_close(flux_sigmas(steps, seq), sch.sigmas.double(), atol=1e-6, rtol=0)

    def test_shapes_and_monotone(self):
        s = flux_sigmas(20, 45 * 80)
        assert len(s) == 21 and s[0] == 1.0 and s[-1] == 0.0 and torch.all(s[1:] < s[:-1])
        with pytest.raises(ValueError, match="positive integer"):
            linear_sigmas(0)
        with pytest.raises(ValueError, match="positive integer"):
            flux_sigmas(2.5, 64)

    def test_unknown_schedule_is_a_settings_error(self):
        from snell_bench.sampler import SamplerSettings

        with pytest.raises(ValueError, match="sampler.schedule"):
            SamplerSettings(schedule="cosine")


class TestSteps:
    def test_exact_for_a_straight_path(self):
        # with the true x0 the Euler step lands exactly on the path at sigma'
        g = torch.Generator().manual_seed(0)
        x0, eps = torch.randn(1000, generator=g), torch.randn(1000, generator=g)
        z = 0.3 * x0 + 0.7 * eps
        v = eps - x0
        torch.testing.assert_close(euler_estimate(z, v, 0.7), x0)
        torch.testing.assert_close(sync_step(z, x0, 0.7, 0.4), 0.6 * x0 + 0.4 * eps)

    def test_last_step_returns_estimate(self):
        z, x0 = torch.randn(10), torch.randn(10)
        out = sync_step(z, x0, 0.05, 0.0)
        assert torch.equal(out, x0)
        g = torch.Generator().manual_seed(0)
        assert torch.equal(stochastic_step(z, x0, 0.05, 0.0, g), x0)

    def test_stochastic_eta_zero_is_deterministic_step(self):
        g = torch.Generator().manual_seed(0)
        z, x0 = torch.randn(100), torch.randn(100)
        torch.testing.assert_close(stochastic_step(z, x0, 0.6, 0.3, g, eta=0.0), sync_step(z, x0, 0.6, 0.3))

    def test_stochastic_step_marginal(self):
        # from the exact x0 and eps, a full renoise gives (1 - s') x0 + s' n with fresh n
        g = torch.Generator().manual_seed(1)
        x0 = torch.full((200_000,), 0.5, dtype=torch.float64)
        z = 0.4 * x0 + 0.6 * torch.randn(200_000, generator=g, dtype=torch.float64)
        out = stochastic_step(z, x0, 0.6, 0.25, g, eta=1.0)
        assert float(out.mean()) == pytest.approx(0.75 * 0.5, abs=3e-3)
        assert float(out.std()) == pytest.approx(0.25, rel=1e-2)


class TestRenoise:
    @pytest.mark.parametrize("sigma,s", [(0.3, 0.45), (0.05, 0.8), (0.5, 0.5), (0.0, 0.2)])
    def test_reproduces_forward_marginal(self, sigma, s):
        """Mean and variance of z_s over many draws against the closed form (1 - s) x0, s^2."""
        g = torch.Generator().manual_seed(2)
        n = 400_000
        x0 = torch.linspace(-1, 1, n, dtype=torch.float64)
        z = (1 - sigma) * x0 + sigma * torch.randn(n, generator=g, dtype=torch.float64)
        zs = renoise(z, sigma, s, g)
        resid = zs - (1 - s) * x0
        assert float(resid.mean()) == pytest.approx(0.0, abs=4 * s / math.sqrt(n) + 1e-12)
        assert float(resid.var()) == pytest.approx(s * s, rel=1e-2, abs=1e-12)
        # and it keeps the correlation with x0 exactly: regression slope of zs on x0 is 1 - s
        slope = float(((zs - zs.mean()) * (x0 - x0.mean())).sum() / ((x0 - x0.mean()) ** 2).sum())
        assert slope == pytest.approx(1 - s, abs=5e-3)

    def test_bad_levels(self):
        g = torch.Generator().manual_seed(0)
        with pytest.raises(ValueError, match="renoise"):
            renoise(torch.zeros(3), 0.5, 0.4, g)  # to a cleaner level
        with pytest.raises(ValueError, match="renoise"):
            renoise(torch.zeros(3), 1.0, 1.0, g)
