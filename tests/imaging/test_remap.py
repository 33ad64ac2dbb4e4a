"""remap against direct indexing and hand-computed bilinear values."""

import numpy as np
import torch

from snell_bench.imaging.remap import remap


def test_identity_and_integer_shift():
    img = torch.rand(2, 3, 8, 10)
    x, y = np.meshgrid(np.arange(10.0), np.arange(8.0))
    out, ok = remap(img, np.stack([x, y], -1))
    assert ok.all()
    torch.testing.assert_close(out, img)
    out, ok = remap(img, np.stack([x + 2, y], -1))
    torch.testing.assert_close(out[..., :7], img[..., 2:9])
    assert not ok[:, :, 8:].any()  # sampled beyond the right edge


def test_bilinear_value_and_nan():
    img = torch.arange(12.0).reshape(1, 1, 3, 4)
    coords = np.array([[[1.5, 0.5], [np.nan, 1.0]]])
    out, ok = remap(img, coords)
    assert float(out[0, 0, 0, 0]) == (1 + 2 + 5 + 6) / 4
    assert ok.tolist() == [[[True, False]]] and float(out[0, 0, 0, 1]) == 0.0


def test_wrap_x_crosses_the_seam():
    img = torch.arange(4.0).reshape(1, 1, 1, 4)
    out, ok = remap(img, np.array([[[3.5, 0.0], [-0.25, 0.0], [4.0, 0.0]]]), wrap_x=True)
    assert ok.all()
    torch.testing.assert_close(out[0, 0, 0], torch.tensor([1.5, 0.75 * 0 + 0.25 * 3, 0.0]))
