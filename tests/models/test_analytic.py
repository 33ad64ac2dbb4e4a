"""The analytic generator: exact latent transform, exact velocity of a Gaussian data distribution."""

import numpy as np
import pytest
import torch
from conftest import integrate_flow
from tolerances import reordering_tolerance

from snell_bench.models.analytic import AnalyticGenerator, glass_blob_prior
from snell_bench.models.base import Generator
from snell_bench.sampler import flux_sigmas, linear_sigmas


def prior(h=16, w=24, seed=0):
    return torch.rand(1, 3, h, w, generator=torch.Generator().manual_seed(seed))


def test_protocol_and_geometry():
    g = AnalyticGenerator(prior(), prior(8, 16, 1), downscale=4)
    assert isinstance(g, Generator)
    assert g.geometry.latent_shape(16, 24) == (48, 4, 6)
    with pytest.raises(ValueError, match="multiple of 4"):
        g.geometry.latent_shape(18, 24)


def test_encode_decode_round_trip_is_exact():
    g = AnalyticGenerator(prior(), downscale=8, seed=3)
    img = prior(32, 48, 5)
    lat = g.encode(img)
    assert lat.shape == (1, 192, 4, 6)
    # exact up to float32 rounding: two products with a 192 x 192 orthogonal matrix in sequence (their
    # lengths add), of magnitude at most that of the latents
    torch.testing.assert_close(g.decode(lat), img, atol=reordering_tolerance(2 * 192, lat, img), rtol=0)
    # an orthogonal transform: distances are kept (up to the 2x scale of 2x - 1)
    other = prior(32, 48, 6)
    assert float((g.encode(other) - lat).norm()) == pytest.approx(2 * float((other - img).norm()), rel=1e-5)


def test_encode_has_no_posterior_to_sample():
    """``sampler.encode=sample`` with the analytic backend: its encoder is an exact linear map with
    no posterior, so a generator passed in is neither read nor advanced: the mean either way."""
    g = AnalyticGenerator(prior(), downscale=8, seed=3)
    img = prior(32, 48, 5)
    rng = torch.Generator().manual_seed(9)
    state = rng.get_state()
    assert torch.equal(g.encode(img, generator=rng), g.encode(img))
    assert torch.equal(rng.get_state(), state)


def test_posterior_mean_matches_bayes():
    """Scalar check of E[x0 | z] for x0 ~ N(mu, s^2), z = (1 - sigma) x0 + sigma eps."""
    g = AnalyticGenerator(prior(8, 8), downscale=8, prior_std=0.4)
    mu = g._priors["main"]
    cond = g.condition(["p"], ["main"])
    z = torch.randn(mu.shape, generator=torch.Generator().manual_seed(0))
    sigma, s2 = 0.35, 0.16
    # Bayes: precision-weighted combination of the prior and the observation z / (1 - sigma)
    obs_var = sigma**2 / (1 - sigma) ** 2
    post = (mu / s2 + (z / (1 - sigma)) / obs_var) / (1 / s2 + 1 / obs_var)
    torch.testing.assert_close(g.posterior_mean(z, sigma, cond), post, atol=1e-5, rtol=1e-5)
    v = g.velocity(z, sigma, cond)
    torch.testing.assert_close(z - sigma * v, post, atol=1e-5, rtol=1e-5)


def test_ode_transports_noise_to_the_data_distribution():
    """The exact velocity's ODE turns N(0, 1) into N(mu, s^2) per coordinate."""
    g = AnalyticGenerator(prior(8, 8), downscale=8, prior_std=0.25)
    mu = g._priors["main"]
    cond = g.condition(["p"], ["main"])
    n = 4000
    z = torch.randn((n,) + mu.shape[1:], generator=torch.Generator().manual_seed(1))
    z = integrate_flow(g, z, cond)
    torch.testing.assert_close(z.mean(0), mu[0], atol=0.03, rtol=0)
    assert float(z.std(0).mean()) == pytest.approx(0.25, rel=0.05)


def test_strength_sets_resistance():
    """A strong prior (small s) pulls the estimate to mu, a weak one follows the latent."""
    img = prior(8, 8)
    z = torch.zeros(1, 192, 1, 1)
    for s, expect_close_to_mu in [(0.01, True), (10.0, False)]:
        g = AnalyticGenerator(img, downscale=8, prior_std=s)
        mu = g._priors["main"]
        est = g.posterior_mean(z, 0.5, g.condition(["p"], ["main"]))
        assert (float((est - mu).abs().mean()) < 0.05) == expect_close_to_mu


def test_views_and_errors():
    g = AnalyticGenerator(prior(8, 8), prior(8, 16, 1), downscale=8)
    cond = g.condition(["a", "b"], ["main", "main"])
    z = torch.randn(2, 192, 1, 1)
    assert g.velocity(z, 0.5, cond).shape == z.shape
    with pytest.raises(ValueError, match="no prior for view"):
        g.condition(["a"], ["side"])
    with pytest.raises(ValueError, match="sigma = 0"):
        g.velocity(z, 0.0, cond)
    with pytest.raises(ValueError, match="does not match"):
        g.velocity(torch.randn(1, 192, 1, 2), 0.5, g.condition(["a"], ["main"]))
    with pytest.raises(ValueError, match="prior_std"):
        AnalyticGenerator(prior(8, 8), prior_std=0.0)


def test_glass_blob_is_wrong_only_inside_the_object():
    img = prior(32, 32)
    mask = np.zeros((32, 32), bool)
    mask[8:20, 10:22] = True
    out = glass_blob_prior(img, mask)
    assert torch.equal(out[..., ~torch.from_numpy(mask)], img[..., ~torch.from_numpy(mask)])
    assert float((out - img)[..., torch.from_numpy(mask)].abs().mean()) > 0.05
    assert torch.equal(glass_blob_prior(img, np.zeros((32, 32), bool)), img)  # empty mask


def test_sigmas_are_the_float64_closed_forms():
    g = AnalyticGenerator(prior(96, 160), downscale=8)
    s = g.sigmas(20, 96, 160)
    assert s.dtype == torch.float64 and s.shape == (21,) and float(s[0]) == pytest.approx(1.0) and s[-1] == 0.0
    assert torch.equal(s, flux_sigmas(20, (12 // 2) * (20 // 2)))  # tokens of the 12 x 20 latent grid
    assert torch.equal(g.sigmas(4, 96, 160, kind="linear"), linear_sigmas(4))
    assert (g.sigmas(20, 192, 320)[1:-1] > s[1:-1]).all()  # larger images: shifted towards noise
    with pytest.raises(ValueError, match="schedule"):
        g.sigmas(4, 96, 160, kind="cosine")
    with pytest.raises(ValueError, match="positive integer"):
        g.sigmas(0, 96, 160)
    with pytest.raises(ValueError, match="multiple of 8"):
        g.sigmas(4, 90, 160)


@pytest.mark.parametrize("sigma", [1.0, 1.1666666666666667, 2.3, 4.0])
def test_blur_is_a_replicate_padded_separable_gaussian(sigma):
    """Against an explicit pad + two 1-D convolutions with the same kernel."""
    import math

    import torch.nn.functional as F

    from snell_bench.models.analytic import gaussian_blur

    img = prior(24, 40, 2)
    k = int(2 * math.ceil(2.5 * sigma) + 1)
    g = torch.exp(-((torch.arange(k) - k // 2).float() ** 2) / (2 * sigma**2))
    g = g / g.sum()
    pad = k // 2
    ref = F.conv2d(F.pad(img, (pad, pad, 0, 0), mode="replicate"), g.view(1, 1, 1, k).repeat(3, 1, 1, 1), groups=3)
    ref = F.conv2d(F.pad(ref, (0, 0, pad, pad), mode="replicate"), g.view(1, 1, k, 1).repeat(3, 1, 1, 1), groups=3)
    # the same two k-tap passes, through kornia's convolution: equal up to the order of the 2k terms
    torch.testing.assert_close(gaussian_blur(img, sigma), ref, rtol=0, atol=reordering_tolerance(2 * k, ref))
    # weights summing to 1 (to rounding) keep a constant, to the rounding of the two k-tap passes
    assert float((gaussian_blur(torch.full_like(img, 0.3), sigma) - 0.3).abs().max()) <= reordering_tolerance(
        2 * k, 0.3
    )


def test_image_and_mask_layouts_give_the_same_prior():
    img = prior(32, 32)
    mask = np.zeros((32, 32), bool)
    mask[8:20, 10:22] = True
    hwc = img[0].permute(1, 2, 0).numpy().astype(np.float64)
    ref = glass_blob_prior(img, mask)
    assert torch.equal(glass_blob_prior(hwc, mask.tolist()), ref)
    assert torch.equal(glass_blob_prior(img, torch.from_numpy(mask)), ref)
    a = AnalyticGenerator(img, glass_mask=mask, downscale=8)
    b = AnalyticGenerator(hwc, glass_mask=mask.astype(np.float32), downscale=8)
    assert torch.equal(a._priors["main"], b._priors["main"]) and torch.equal(a._std["main"], b._std["main"])
