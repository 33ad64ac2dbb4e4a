"""push_pull_fill: known pixels kept, holes filled from their surroundings only."""

import torch

from snell_bench.imaging.fill import push_pull_fill


def test_known_pixels_are_kept_bit_for_bit_and_constants_fill_exactly():
    g = torch.Generator().manual_seed(0)
    img = torch.rand(1, 3, 37, 50, generator=g)
    known = torch.rand(37, 50, generator=g) > 0.6
    out = push_pull_fill(img, known)
    assert torch.equal(out[..., known], img[..., known])
    const = torch.full((1, 3, 37, 50), 0.3)
    filled = push_pull_fill(torch.where(known, const, torch.zeros(())), known)
    torch.testing.assert_close(filled, const)


def test_holes_take_values_between_their_surroundings():
    x = torch.linspace(0, 1, 64).expand(1, 1, 16, 64).clone()
    known = torch.ones(16, 64, dtype=torch.bool)
    known[:, 20:40] = False
    out = push_pull_fill(torch.where(known, x, torch.full_like(x, 5.0)), known)
    hole = out[0, 0][:, 20:40]
    assert 0.0 <= hole.min() and hole.max() <= 1.0  # within the known values (no 5.0 leaks in)
    assert (hole - x[0, 0][:, 20:40]).abs().mean() < 0.05  # close to the ramp it continues
    assert (hole[:, 1:] >= hole[:, :-1] - 1e-6).all()  # and monotone like the ramp around it


def test_nothing_known_gives_zero_and_wrap_x_uses_the_other_edge():
    assert torch.equal(
        push_pull_fill(torch.ones(1, 1, 4, 8), torch.zeros(4, 8, dtype=torch.bool)), torch.zeros(1, 1, 4, 8)
    )
    img = torch.zeros(1, 1, 8, 16)
    known = torch.zeros(8, 16, dtype=torch.bool)
    known[:, :2] = True
    img[..., :2] = 1.0
    out = push_pull_fill(img, known, wrap_x=True)
    assert torch.isfinite(out).all() and torch.allclose(out, torch.ones_like(out))
