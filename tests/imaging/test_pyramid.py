"""Pyramids and pyramid warps against exact identities, shifted images and independent
area-averaging (supersampled) references."""

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from kornia.geometry.transform import pyrdown
from tolerances import reordering_tolerance

from snell_bench.imaging.pyramid import (
    collapse,
    gaussian_pyramid,
    laplacian_from_gaussian,
    laplacian_pyramid,
    lod_warp,
    pyramid_warp,
)
from snell_bench.imaging.remap import remap


def grid(H, W, dtype=torch.float32):
    """Identity map (H, W, 2) of pixel-centre coordinates (x, y)."""
    y, x = torch.meshgrid(torch.arange(H, dtype=dtype), torch.arange(W, dtype=dtype), indexing="ij")
    return torch.stack([x, y], -1)


def smooth_noise(B, C, H, W, seed=0, k=5):
    g = torch.Generator().manual_seed(seed)
    return F.avg_pool2d(torch.rand(B, C, H + k - 1, W + k - 1, generator=g), k, 1)


def sinusoid(N, f=0.35):
    """A 2-D pattern near the Nyquist frequency (f cycles per pixel along x and y)."""
    y, x = torch.meshgrid(torch.arange(float(N)), torch.arange(float(N)), indexing="ij")
    return (0.5 + 0.25 * torch.cos(2 * math.pi * f * x) + 0.25 * torch.cos(2 * math.pi * f * y + 1.0))[None, None]


def area_matrix(n_out, n_in, scale):
    """(n_out, n_in) weights of the box filter: destination pixel u covers source [u s, (u + 1) s)."""
    A = torch.zeros(n_out, n_in, dtype=torch.float64)
    for u in range(n_out):
        a, b = u * scale, (u + 1) * scale
        i = torch.arange(n_in, dtype=torch.float64)
        A[u] = ((torch.minimum(i + 1, torch.tensor(b)) - torch.maximum(i, torch.tensor(a))).clamp_min(0)) / scale
    return A


def minify_map(n_out, scale):
    """Backward map of a uniform minification: destination pixel u <- source centre of [u s, (u+1) s)."""
    return grid(n_out, n_out) * scale + (scale - 1) / 2


def mse(a, b):
    return float(((a - b) ** 2).mean())


class TestGaussianPyramid:
    def test_sizes_without_padding(self):
        pyr = gaussian_pyramid(torch.rand(1, 3, 90, 160), 5)
        assert [tuple(p.shape[-2:]) for p in pyr] == [(90, 160), (45, 80), (22, 40), (11, 20), (5, 10)]

    def test_levels_are_pyrdown(self):
        img = torch.rand(2, 3, 37, 53)
        pyr = gaussian_pyramid(img, 3)
        assert torch.equal(pyr[0], img)
        torch.testing.assert_close(pyr[2], pyrdown(pyrdown(img)))

    def test_constant_stays_constant(self):
        for wrap_x in (False, True):
            pyr = gaussian_pyramid(torch.full((1, 1, 45, 80), 0.3), 4, wrap_x=wrap_x)
            # weights summing to 1: three pyrdowns of a 25-tap blur and a 4-tap bilinear resample each
            atol = reordering_tolerance(3 * 29, 0.3)
            assert all(torch.allclose(p, torch.tensor(0.3), atol=atol, rtol=0) for p in pyr)

    def test_too_many_levels(self):
        with pytest.raises(ValueError):
            gaussian_pyramid(torch.rand(1, 1, 8, 32), 5)


class TestLaplacianPyramid:
    @pytest.mark.parametrize("size", [(37, 53), (90, 160), (45, 80), (64, 96)])
    @pytest.mark.parametrize("wrap_x", [False, True])
    def test_collapse_reproduces_the_image(self, size, wrap_x):
        img = torch.rand(2, 3, *size)
        pyr = laplacian_pyramid(img, 4, wrap_x=wrap_x)
        assert len(pyr) == 4
        assert (collapse(pyr, wrap_x=wrap_x) - img).abs().max() < 1e-5

    def test_bands_of_a_smooth_ramp_are_small(self):
        y, x = torch.meshgrid(torch.arange(96.0), torch.arange(128.0), indexing="ij")
        pyr = laplacian_pyramid(((x + y) / 224)[None, None].double(), 3)
        for band in pyr[:-1]:  # reflect borders bend the ends of a ramp; the inside stays linear
            assert band[..., 8:-8, 8:-8].abs().max() < 1e-7

    def test_wrap_x_is_circular(self):
        img = torch.rand(1, 2, 32, 64)
        pyr, pyr_rolled = laplacian_pyramid(img, 4, wrap_x=True), laplacian_pyramid(img.roll(24, -1), 4, wrap_x=True)
        # the same operations per pixel, at other positions in the kernels' loops: equal up to the
        # summation order of the 4 levels' chains of 5 x 5 blurs and bilinear resamplings (< 60 terms each)
        atol = reordering_tolerance(60 * 4, img)
        for k, (a, b) in enumerate(zip(pyr, pyr_rolled)):
            torch.testing.assert_close(a.roll(24 >> k, -1), b, atol=atol, rtol=0)

    def test_dtype_and_batch(self):
        img = torch.rand(3, 1, 20, 24, dtype=torch.float64)
        pyr = laplacian_pyramid(img, 3)
        assert all(p.dtype == torch.float64 and p.shape[:2] == (3, 1) for p in pyr)
        assert (collapse(pyr) - img).abs().max() < 1e-12
        torch.testing.assert_close(laplacian_pyramid(img[1:2], 3)[1], pyr[1][1:2])


class TestCollapse:
    def test_all_valid_masks_equal_plain_collapse(self):
        pyr = laplacian_pyramid(torch.rand(1, 3, 40, 56), 3)
        masks = [torch.ones(p.shape[-2:], dtype=torch.bool) for p in pyr]
        assert torch.equal(collapse(pyr, masks), collapse(pyr))

    def test_invalid_values_are_never_read(self):
        pyr = laplacian_pyramid(torch.rand(1, 3, 40, 56), 3)
        masks = [torch.ones(1, 1, *p.shape[-2:], dtype=torch.bool) for p in pyr]
        for m in masks:
            m[..., : m.shape[-2] // 2, :] = False
        clean = collapse([p * m for p, m in zip(pyr, masks)], masks)
        dirty = collapse([torch.where(m, p, torch.tensor(float("nan"))) for p, m in zip(pyr, masks)], masks)
        assert torch.isfinite(dirty).all()
        assert torch.equal(clean, dirty)
        assert (clean[..., :20, :] == 0).all()


class TestPyramidWarp:
    def test_identity(self):
        img = torch.rand(2, 3, 64, 96)
        out, valid = pyramid_warp(img, grid(64, 96))
        assert out.shape == img.shape and valid.shape == (2, 1, 64, 96) and valid.dtype == torch.bool
        assert valid.all()
        assert (out - img).abs().max() < 1e-4
        bands, masks = pyramid_warp(img, grid(64, 96), collapse=False)
        for band, ref, m in zip(bands, laplacian_pyramid(img, 5), masks):  # the source's own pyramid
            assert m.all() and (band - ref).abs().max() < 1e-4

    def test_one_level_is_remap_bit_for_bit(self):
        img = torch.rand(2, 3, 30, 40)
        c = grid(30, 40) * 1.3 + torch.tensor([-2.3, 1.7])  # partly outside the source
        c[5:9, 10:20] = float("nan")
        out, valid = pyramid_warp(img, c, levels=1)
        ref, ref_valid = remap(img, c)
        assert torch.equal(out, ref)
        assert torch.equal(valid[:, 0], ref_valid)
        out, valid = pyramid_warp(img, c, levels=1, wrap_x=True)
        ref, ref_valid = remap(img, c, wrap_x=True)
        assert torch.equal(out, ref) and torch.equal(valid[:, 0], ref_valid)

    @pytest.mark.parametrize("shift", [(3, -2), (16, 16), (-1, 0)])
    def test_integer_translation(self, shift):
        img = torch.rand(1, 3, 96, 128)
        dx, dy = shift
        out, valid = pyramid_warp(img, grid(96, 128) + torch.tensor([float(dx), float(dy)]))
        inside = torch.zeros(96, 128, dtype=torch.bool)
        inside[max(0, -dy) : 96 - max(0, dy), max(0, -dx) : 128 - max(0, dx)] = True
        assert torch.equal(valid[0, 0], inside)
        shifted = img.roll((-dy, -dx), (-2, -1))  # shifted[v, u] = img[v + dy, u + dx]
        assert (out - shifted)[..., inside].abs().max() < 1e-4
        bands, masks = pyramid_warp(img, grid(96, 128) + torch.tensor([float(dx), float(dy)]), collapse=False)
        assert (collapse(bands, masks) - out).abs().max() < 1e-5

    @pytest.mark.parametrize("source", ["sinusoid", "noise"])
    def test_antialiasing_integer_minification(self, source):
        g = torch.Generator().manual_seed(1)
        src = sinusoid(256) if source == "sinusoid" else torch.rand(1, 1, 256, 256, generator=g)
        c = minify_map(64, 4.0)
        ref = F.avg_pool2d(src, 4)  # the source averaged over each destination pixel's footprint
        plain, _ = remap(src, c)
        out, valid = pyramid_warp(src, c)
        assert valid.all()
        assert mse(out, ref) * 4 < mse(plain, ref)

    def test_antialiasing_fractional_minification(self):
        src = sinusoid(256).double()
        s, n = 6.4, 40
        A = area_matrix(n, 256, s)
        ref = A @ src[0, 0] @ A.T  # exact box filter of the pixel-constant source
        c = minify_map(n, s).double()
        plain, _ = remap(src, c)
        out, _ = pyramid_warp(src, c)
        assert mse(out[0, 0], ref) * 10 < mse(plain[0, 0], ref)
        bands, masks = pyramid_warp(src, c, collapse=False)
        torch.testing.assert_close(collapse(bands, masks), out)

    def test_without_scale_matching_minification_aliases(self):
        src, c = sinusoid(256), minify_map(64, 4.0)
        plain, _ = remap(src, c)
        out, _ = pyramid_warp(src, c, match_scale=False)
        assert torch.equal(out, plain)

    def test_magnification_does_not_blur(self):
        n, f = 64, 0.15

        def pattern(x, y):
            return 0.5 + 0.25 * torch.cos(2 * math.pi * f * x) * torch.cos(2 * math.pi * 0.1 * y + 0.3)

        src = pattern(*grid(n, n).unbind(-1))[None, None]
        c = (grid(4 * n, 4 * n) + 0.5) / 4 - 0.5
        truth = pattern(*c.unbind(-1))[16:-16, 16:-16]
        plain, _ = remap(src, c)
        out, _ = pyramid_warp(src, c)
        assert torch.equal(out, plain)  # finest level everywhere: exactly the bilinear warp
        assert mse(out[0, 0, 16:-16, 16:-16], truth) < 2e-4
        bands, masks = pyramid_warp(src, c, collapse=False)
        assert (collapse(bands, masks) - out).abs().max() < 1e-5

    def test_masks_at_every_level(self):
        img = torch.rand(1, 3, 128, 128)
        c = grid(128, 128)
        c[40:60, 30:70] = float("nan")
        out, valid = pyramid_warp(img, c)
        assert torch.isfinite(out).all()
        assert not valid[0, 0, 40:60, 30:70].any() and valid.sum() == 128 * 128 - 20 * 40
        assert (out[0, :, 40:60, 30:70] == 0).all()
        assert (out - img)[valid.expand_as(img)].abs().max() < 1e-4
        bands, masks = pyramid_warp(img, c, collapse=False)
        full = laplacian_pyramid(img, 5)
        far = torch.ones(128, 128, dtype=torch.bool)
        far[: 60 + 48, : 70 + 48] = False  # 48 px around the hole
        for k, (band, m) in enumerate(zip(bands, masks)):
            s = 2**k
            assert m.shape == (1, 1, math.ceil(128 / s), math.ceil(128 / s))
            assert torch.isfinite(band).all() and (band[~m.expand_as(band)] == 0).all()
            # a coarse pixel is valid if any of its fine pixels is
            assert not m[0, 0, math.ceil(40 / s) : 60 // s, math.ceil(30 / s) : 70 // s].any()
            assert m[0, 0, : 40 // s].all() and m[0, 0, math.ceil(60 / s) :].all()
            far_k = far[::s, ::s]
            assert (band - full[k])[..., far_k].abs().max() < 1e-4
        assert (collapse(bands, masks) - out).abs().max() < 1e-5

    def test_mask_argument_equals_nan_coordinates(self):
        img = torch.rand(2, 3, 48, 64)
        mask = torch.ones(48, 64, dtype=torch.bool)
        mask[10:20, 5:30] = False
        c = grid(48, 64)
        c_nan = c.clone()
        c_nan[~mask] = float("nan")
        mask_b = mask[None, None].expand(2, 1, -1, -1)
        out, valid = pyramid_warp(img, c, mask=mask)
        ref, ref_valid = pyramid_warp(img, c_nan)
        assert torch.equal(out, ref) and torch.equal(valid, ref_valid)
        assert torch.equal(pyramid_warp(img, c, mask=mask_b)[0], ref)
        bands, masks = pyramid_warp(img, c, mask=mask_b, collapse=False)
        ref_bands, ref_masks = pyramid_warp(img, c_nan, collapse=False)
        assert all(torch.equal(a, b) for a, b in zip(bands + masks, ref_bands + ref_masks))

    def test_seam_crossing_map(self):
        pano = smooth_noise(1, 3, 64, 128, seed=2)
        c = grid(64, 128) * torch.tensor([0.75, 1.0]) + torch.tensor([100.0, 0.0])  # x runs over the seam
        c_wrapped = c.clone()
        c_wrapped[..., 0] = torch.remainder(c[..., 0] + 0.5, 128) - 0.5  # jumps from 127.x to 0.x
        rolled = pano.roll(-96, -1)  # the same panorama, turned so that no seam is crossed
        c_rolled = c - torch.tensor([96.0, 0.0])
        bands, masks = pyramid_warp(pano, c, wrap_x=True, levels=4, collapse=False)
        bands_w, masks_w = pyramid_warp(pano, c_wrapped, wrap_x=True, levels=4, collapse=False)
        bands_r, _ = pyramid_warp(rolled, c_rolled, wrap_x=True, levels=4, collapse=False)
        for b, b_w, b_r, m in zip(bands, bands_w, bands_r, masks_w):
            assert m.all()
            assert (b - b_w).abs().max() < 1e-4
            assert (b_w - b_r).abs().max() < 1e-4
        out, _ = pyramid_warp(pano, c_wrapped, wrap_x=True, levels=4)
        plain, _ = pyramid_warp(pano, c_rolled, levels=4)
        assert (out - collapse(bands_r, masks_w)).abs().max() < 1e-4
        assert (out - plain).abs().max() > 0.01  # sampled elsewhere: the comparison means something

    def test_destination_panorama_is_circular(self):
        pano = torch.rand(1, 3, 32, 64)
        c = grid(32, 64) * torch.tensor([1.0, 0.7]) + torch.tensor([0.3, 0.2])
        a, ma = pyramid_warp(pano, c, wrap_x=True, dest_wrap_x=True, levels=4, collapse=False)
        b, _ = pyramid_warp(pano, c.roll(16, 1), wrap_x=True, dest_wrap_x=True, levels=4, collapse=False)
        for k, (ak, bk) in enumerate(zip(a, b)):  # as in TestLaplacianPyramid.test_wrap_x_is_circular
            assert (ak.roll(16 >> k, -1) - bk).abs().max() <= reordering_tolerance(60 * 4, pano)
        out, _ = pyramid_warp(pano, c, wrap_x=True, dest_wrap_x=True, levels=4)
        assert (collapse(a, ma, wrap_x=True) - out).abs().max() < 1e-5

    def test_too_many_levels(self):
        with pytest.raises(ValueError):
            pyramid_warp(torch.rand(1, 1, 8, 64), grid(8, 64), levels=5)

    def test_batch_dtype_and_numpy(self):
        img = torch.rand(2, 3, 40, 48, dtype=torch.float64)
        c = torch.stack([grid(40, 48, torch.float64) * 0.9, grid(40, 48, torch.float64) * 2.7])
        out, valid = pyramid_warp(img, c, levels=3)
        assert out.dtype == torch.float64 and out.shape == (2, 3, 40, 48)
        bands, masks = pyramid_warp(img, c, levels=3, collapse=False)
        assert [tuple(b.shape) for b in bands] == [(2, 3, 40, 48), (2, 3, 20, 24), (2, 3, 10, 12)]
        assert all(b.dtype == torch.float64 for b in bands)
        for i in range(2):
            ref, ref_valid = pyramid_warp(img[i : i + 1], c[i], levels=3)
            torch.testing.assert_close(out[i : i + 1], ref)
            assert torch.equal(valid[i : i + 1], ref_valid)
            ref_bands, _ = pyramid_warp(img[i : i + 1], c[i], levels=3, collapse=False)
            for b, rb in zip(bands, ref_bands):
                torch.testing.assert_close(b[i : i + 1], rb)
        torch.testing.assert_close(collapse(bands, masks), out)
        out_np, _ = pyramid_warp(img[:1], c[0].numpy(), levels=3)
        torch.testing.assert_close(out_np, out[:1])


class TestLodWarp:
    def test_is_the_collapsed_pyramid_warp(self):
        img = torch.rand(1, 3, 64, 64)
        c = grid(64, 64) * torch.tensor([2.3, 0.6]) + torch.tensor([0.0, 5.0])
        c[:4] = float("nan")
        out, valid = lod_warp(img, c)
        ref, ref_valid = pyramid_warp(img, c)
        assert torch.equal(out, ref) and torch.equal(valid, ref_valid)

    def test_non_compressing_map_is_remap(self):
        img = torch.rand(2, 3, 40, 56)
        c = grid(40, 56) * 0.8 + torch.tensor([3.3, -1.2])
        c[3:6, 7:9] = float("nan")
        out, valid = lod_warp(img, c)
        ref, ref_valid = remap(img, c)
        assert torch.equal(out, ref) and torch.equal(valid[:, 0], ref_valid)

    @pytest.mark.parametrize("scale,n", [(4.0, 64), (6.4, 40)])
    def test_antialiasing(self, scale, n):
        src = sinusoid(256).double()
        A = area_matrix(n, 256, scale)
        ref = A @ src[0, 0] @ A.T
        c = minify_map(n, scale).double()
        plain, _ = remap(src, c)
        out, valid = lod_warp(src, c)
        assert valid.all()
        assert mse(out[0, 0], ref) * 4 < mse(plain[0, 0], ref)

    def test_masks_and_seam(self):
        pano = smooth_noise(1, 3, 64, 128, seed=3)
        c = grid(64, 128) * torch.tensor([2.5, 1.0]) + torch.tensor([60.0, 0.0])
        c[:, :10] = float("nan")
        out, valid = lod_warp(pano, c, wrap_x=True)
        assert torch.isfinite(out).all() and not valid[..., :10].any() and valid[..., 10:].all()
        c_wrapped = c.clone()
        c_wrapped[..., 0] = torch.remainder(c[..., 0] + 0.5, 128) - 0.5
        out_w, _ = lod_warp(pano, c_wrapped, wrap_x=True)
        assert (out - out_w).abs().max() < 1e-4
        out_r, _ = lod_warp(pano.roll(-64, -1), c_wrapped - torch.tensor([64.0, 0.0]), wrap_x=True)
        assert (out - out_r).abs().max() < 1e-4


def test_warped_bands_line_up_with_an_images_own_pyramid_at_odd_sizes():
    """The sampler blends warped bands with an estimate's own Laplacian pyramid level by level, so
    their sizes must agree at every level, also where a level has an odd size (360 -> 45 -> 22)."""
    from snell_bench.imaging.pyramid import laplacian_pyramid, pyramid_warp

    img = torch.rand(1, 3, 360, 200)
    own = laplacian_pyramid(img, 5)
    x, y = np.meshgrid(np.arange(200.0), np.arange(360.0))
    bands, masks = pyramid_warp(img, np.stack([x * 0.9 + 5, y], -1), levels=5, collapse=False)
    assert [b.shape[-2:] for b in bands] == [o.shape[-2:] for o in own]
    assert [m.shape[-2:] for m in masks] == [o.shape[-2:] for o in own]


class TestPyramidWarpROI:
    """``roi=True`` (a window around the valid pixels) gives the full computation's result."""

    @staticmethod
    def disk_map(H, W, cx, cy, r, scale=1.3, shift=(40.0, 20.0), nan_outside=True):
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        c = np.stack([xx * scale + shift[0] + 5 * np.sin(yy / 9), yy * 0.9 + shift[1]], -1)
        if nan_outside:
            c[(xx - cx) ** 2 + (yy - cy) ** 2 > r**2] = np.nan
        return c

    @staticmethod
    def assert_same(a, b, collapse, levels):
        # the window runs the same operations per pixel on a crop, at other positions in the kernels'
        # loops: equal up to the summation order of each level's chain (a 5 x 5 blur and a bilinear
        # resampling down and up, the bilinear sampling, the band sums: under 60 terms per level)
        if collapse:
            torch.testing.assert_close(a[0], b[0], atol=reordering_tolerance(60 * levels, a[0]), rtol=0)
            assert torch.equal(a[1], b[1])
        else:
            assert len(a[0]) == len(b[0])
            for x, y in zip(a[0], b[0]):
                assert x.shape == y.shape
                torch.testing.assert_close(x, y, atol=reordering_tolerance(60 * levels, *a[0]), rtol=0)
            for x, y in zip(a[1], b[1]):
                assert torch.equal(x, y)

    @pytest.mark.parametrize("levels", [1, 3, 5])
    @pytest.mark.parametrize("collapse", [True, False])
    @pytest.mark.parametrize(
        "H, W, cx, cy, r",
        [
            (180, 320, 150, 90, 40),  # interior
            (180, 320, 10, 8, 30),  # touching the top-left corner
            (181, 323, 300, 170, 35),  # touching the bottom-right corner at odd sizes
            (90, 160, 80, 45, 60),  # almost everything valid: no window
        ],
    )
    def test_window_equals_full(self, levels, collapse, H, W, cx, cy, r):
        src = smooth_noise(1, 3, 256, 512, seed=1)
        c = self.disk_map(H, W, cx, cy, r)
        for wrap, dwrap in ((False, False), (True, False), (True, True)):
            kw = dict(levels=levels, collapse=collapse, wrap_x=wrap, dest_wrap_x=dwrap)
            self.assert_same(pyramid_warp(src, c, **kw), pyramid_warp(src, c, roi=True, **kw), collapse, levels)

    def test_panorama_destination_across_the_seam(self):
        src = smooth_noise(1, 3, 96, 160, seed=2)
        H, W = 64, 128
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        c = np.stack([xx * 0.7 + 10, yy * 0.9 + 5], -1)
        c[~((yy > 20) & (yy < 40) & ((xx < 12) | (xx > 110)))] = np.nan  # valid on both sides of x = 0
        kw = dict(levels=4, collapse=False, dest_wrap_x=True)
        self.assert_same(pyramid_warp(src, c, **kw), pyramid_warp(src, c, roi=True, **kw), False, 4)

    def test_all_invalid_and_shared_source_pyramid(self):
        src = smooth_noise(1, 3, 128, 256, seed=3)
        c = np.full((60, 100, 2), np.nan, np.float32)
        w, ok = pyramid_warp(src, c, levels=3, roi=True)
        assert not ok.any() and torch.count_nonzero(w) == 0
        c = self.disk_map(120, 200, 100, 60, 30)
        g = gaussian_pyramid(src, 5, wrap_x=True)
        for do_collapse in (True, False):
            a = pyramid_warp(src, c, levels=5, wrap_x=True, collapse=do_collapse)
            b = pyramid_warp(src, c, levels=5, wrap_x=True, collapse=do_collapse, roi=True, src_pyramid=g)
            self.assert_same(a, b, do_collapse, 5)

    def test_laplacian_from_gaussian(self):
        img = smooth_noise(1, 3, 90, 161, seed=4)
        for wrap in (False, True):
            a = laplacian_pyramid(img, 4, wrap_x=wrap)
            b = laplacian_from_gaussian(gaussian_pyramid(img, 4, wrap_x=wrap), wrap_x=wrap)
            for x, y in zip(a, b):
                assert torch.equal(x, y)


@pytest.mark.parametrize("shape", [(1, 3, 37, 64), (2, 1, 16, 15), (1, 3, 90, 160)])
def test_pyrdown_and_pyrup_are_kornias(shape):
    """The pyramid's own pyrdown / pyrup (kernel kept on the image's device) give kornia's numbers."""
    from kornia.geometry.transform import pyrdown as kornia_down
    from kornia.geometry.transform import pyrup as kornia_up

    from snell_bench.imaging.pyramid import pyrdown, pyrup

    x = torch.rand(shape, generator=torch.Generator().manual_seed(0))
    assert torch.equal(pyrdown(x), kornia_down(x)) and torch.equal(pyrup(x), kornia_up(x))


class TestMeta:
    """On ``meta`` (shapes, no data) every warp takes its general path and returns the shapes and
    dtypes of the real computation: with a window around the valid pixels or without, collapsed or
    as bands, across a panorama's seam, scale-matched or level by level."""

    @staticmethod
    def leaves(out) -> list[torch.Tensor]:
        return [t for v in out for t in TestMeta.leaves(v)] if isinstance(out, (list, tuple)) else [out]

    def assert_same_layout(self, on_meta, real):
        a, b = self.leaves(on_meta), self.leaves(real)
        assert [(t.shape, t.dtype) for t in a] == [(t.shape, t.dtype) for t in b]
        assert all(t.is_meta for t in a)

    @pytest.mark.parametrize(
        "kw",
        [
            dict(levels=5, roi=True),  # a window on the CPU
            dict(levels=5, roi=True, collapse=False, wrap_x=True, dest_wrap_x=True),
            dict(levels=3, collapse=False, match_scale=False),
            dict(levels=1, roi=True),
        ],
    )
    def test_shapes_of_the_real_path(self, kw):
        src = smooth_noise(1, 3, 64, 128, seed=5)
        c = torch.from_numpy(TestPyramidWarpROI.disk_map(72, 120, 60, 36, 14, scale=0.4, shift=(8.0, 4.0)))
        real = pyramid_warp(src, c, **kw)
        g = gaussian_pyramid(meta_like(src), kw["levels"], wrap_x=kw.get("wrap_x", False))
        self.assert_same_layout(pyramid_warp(meta_like(src), meta_like(c), src_pyramid=g, **kw), real)

    def test_masked_collapse(self):
        img = smooth_noise(1, 3, 40, 64, seed=6)
        masks = [torch.rand(40 >> k, 64 >> k, generator=torch.Generator().manual_seed(k)) > 0.3 for k in range(3)]
        real = collapse(laplacian_pyramid(img, 3), masks)
        self.assert_same_layout(collapse(laplacian_pyramid(meta_like(img), 3), [meta_like(m) for m in masks]), real)


def meta_like(x: torch.Tensor) -> torch.Tensor:
    """A tensor of ``x``'s shape and dtype on ``meta``."""
    return torch.empty_like(x, device="meta")
