"""sRGB transfer function against its defining constants."""

import numpy as np
import torch

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear


def test_known_values_and_round_trip():
    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(x)), x, atol=1e-12)
    assert abs(float(linear_to_srgb(np.float64(0.0031308))) - 0.04045) < 1e-5  # the knee
    assert abs(float(linear_to_srgb(np.float64(0.214041140))) - 0.5) < 1e-6
    assert float(srgb_to_linear(np.float64(1.0))) == 1.0 and float(srgb_to_linear(np.float64(0.0))) == 0.0


def test_torch_matches_numpy_and_clamps():
    x = np.linspace(-0.2, 1.2, 57)
    np.testing.assert_allclose(linear_to_srgb(torch.from_numpy(x)).numpy(), linear_to_srgb(x), atol=1e-12)
    np.testing.assert_allclose(srgb_to_linear(torch.from_numpy(x)).numpy(), srgb_to_linear(x), atol=1e-12)
    assert linear_to_srgb(x).min() == 0 and abs(linear_to_srgb(x).max() - 1) < 1e-12
