"""The local stretch of piecewise-smooth maps (one branch per side of a jump) against closed-form
Jacobians, and the exactness of warps where a map is the identity: remap at pixel centres and the
pyramid warps outside an object's silhouette."""

import numpy as np
import pytest
import torch
from tolerances import EPS32

from snell_bench.imaging.coord_maps import local_stretch, matching_level
from snell_bench.imaging.pyramid import lod_warp, pyramid_warp
from snell_bench.imaging.remap import remap


def affine(J, offset, H, W):
    """Map ``(H, W, 2)`` float64 ``c(u, v) = J (u, v) + offset`` (destination x = u, y = v)."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    J = np.asarray(J, np.float64)
    return np.stack([J[0, 0] * u + J[0, 1] * v + offset[0], J[1, 0] * u + J[1, 1] * v + offset[1]], -1)


def stretch_of(J) -> float:
    """The larger column norm of a 2 x 2 Jacobian (closed form of the stretch)."""
    return float(max(np.hypot(*np.asarray(J)[:, 0]), np.hypot(*np.asarray(J)[:, 1])))


def disc_map(H, W, cx, cy, r, scale=0.6, shift=(25.0, 9.0)):
    """π^R-like map: the identity outside a disc; inside, a scaled-down view displaced by ``shift``
    (a lens shows a shrunken patch of the background elsewhere): a jump of ``|shift|`` pixels or
    more across the silhouette. Returns ``(map (H, W, 2) float32, disc (H, W) bool)``."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float32)
    disc = (u - cx) ** 2 + (v - cy) ** 2 <= r**2
    inside = np.stack([cx + shift[0] + scale * (u - cx), cy + shift[1] + scale * (v - cy)], -1)
    return np.where(disc[..., None], inside, np.stack([u, v], -1)).astype(np.float32), disc


class TestStretchAcrossAJump:
    # left of column 20 one branch, right of it another; the jump between them is 40 px or more
    JL, JR = [[1.5, 0.3], [-0.2, 1.2]], [[3.0, 0.0], [0.6, 2.5]]

    def two_branches(self, H=16, W=40):
        left, right = affine(self.JL, (2.0, 3.0), H, W), affine(self.JR, (60.0, -4.0), H, W)
        c = np.where((np.arange(W) < 20)[None, :, None], left, right)
        return torch.from_numpy(c)[None]

    def test_each_side_keeps_its_own_jacobian(self):
        c = self.two_branches()
        s = local_stretch(c, None, False)[0]
        # float64 differences of coordinates below 200: exact to 1e-12 (a few roundings of 200 * 2^-53)
        assert torch.allclose(s[:, :20], torch.tensor(stretch_of(self.JL), dtype=s.dtype), atol=1e-12, rtol=0)
        assert torch.allclose(s[:, 20:], torch.tensor(stretch_of(self.JR), dtype=s.dtype), atol=1e-12, rtol=0)

    def test_float32_and_the_pixels_beside_the_jump(self):
        c = self.two_branches().float()
        s = local_stretch(c, None, False)[0]
        # each difference of two float32 coordinates below 256 is off by at most 2 * 256 * EPS32 per
        # component, the norm of the central mean by at most twice that
        tol = 4 * 256 * EPS32
        torch.testing.assert_close(s[:, 19], torch.full_like(s[:, 19], stretch_of(self.JL)), atol=tol, rtol=0)
        torch.testing.assert_close(s[:, 20], torch.full_like(s[:, 20], stretch_of(self.JR)), atol=tol, rtol=0)

    def test_jump_across_a_panorama_destination_seam(self):
        # a circular destination: column 0 and W - 1 are neighbours, and across them the map jumps
        c = self.two_branches()
        s = local_stretch(c, None, True)[0]
        assert torch.allclose(s[:, 0], torch.tensor(stretch_of(self.JL), dtype=s.dtype), atol=1e-12, rtol=0)
        assert torch.allclose(s[:, -1], torch.tensor(stretch_of(self.JR), dtype=s.dtype), atol=1e-12, rtol=0)

    def test_no_same_branch_neighbour_gives_the_level_of_the_destination(self):
        # a lone pixel of another branch in the middle of an identity map
        c = torch.from_numpy(affine(np.eye(2), (0.0, 0.0), 5, 5))[None].clone()
        c[0, 2, 2] = torch.tensor([100.0, 50.0], dtype=c.dtype)
        s = local_stretch(c, None, False)[0]
        assert torch.isnan(s[2, 2])
        s[2, 2] = 1.0
        assert torch.equal(s, torch.ones_like(s))  # its neighbours use their other sides
        assert float(matching_level(c, 0, None, False)[0, 2, 2]) == 0.0
        assert float(matching_level(c, 2, None, False)[0, 2, 2]) == 2.0

    def test_a_smooth_map_is_one_branch(self):
        # the stretch may triple from pixel to pixel (a sphere's rim) without being split
        x = torch.tensor([0.0, 1.0, 3.0, 9.0, 27.0], dtype=torch.float64)
        c = torch.stack([x, torch.zeros(5, dtype=torch.float64)], -1)[None, None]
        s = local_stretch(c, None, False)[0, 0]
        assert s.tolist() == [1.0, 1.5, 4.0, 12.0, 18.0]  # central means, one-sided at the ends


class TestIdentityIsExact:
    def test_remap_at_pixel_centres(self):
        img = torch.rand(2, 3, 45, 80, generator=torch.Generator().manual_seed(0))
        v, u = torch.meshgrid(torch.arange(45.0), torch.arange(80.0), indexing="ij")
        out, ok = remap(img, torch.stack([u, v], -1))
        assert ok.all() and torch.equal(out, img)
        out, _ = remap(img, torch.stack([u - 80.0 * 2, v], -1), wrap_x=True)  # twice round the seam
        assert torch.equal(out, img)
        shifted, ok = remap(img, torch.stack([u + 3.0, v - 2.0], -1))
        assert torch.equal(shifted[..., 2:, :-3], img[..., :-2, 3:]) and not ok[:, :, -3:].any()

    @pytest.mark.parametrize("warp", ["lod", "pyramid"])
    def test_outside_a_disc_the_warp_is_the_source(self, warp):
        src = torch.rand(1, 3, 48, 64, generator=torch.Generator().manual_seed(1))
        c, disc = disc_map(48, 64, 30.0, 22.0, 6.0)
        assert 100 <= disc.sum() <= 120  # about the disc of the reported case (109 pixels)
        out, ok = lod_warp(src, c) if warp == "lod" else pyramid_warp(src, c, roi=True)
        outside = torch.from_numpy(~disc)
        assert ok.all()
        assert torch.equal(out[..., outside], src[..., outside])  # the source's values, bit for bit

    def test_inside_the_disc_the_stretch_is_the_lens(self):
        c, disc = disc_map(48, 64, 30.0, 22.0, 6.0)
        s = local_stretch(torch.from_numpy(c)[None].double(), None, False)[0].numpy()
        assert np.allclose(s[disc], 0.6, atol=1e-5) and np.allclose(s[~disc], 1.0, atol=1e-5)
