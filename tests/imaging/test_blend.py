"""Detail-preserving average, per-level blending and the Fresnel combination against hand-computed
values and an independent per-pixel numpy reference."""

import numpy as np
import pytest
import torch

from snell_bench.imaging.blend import blend_images, blend_pyramids, detail_preserving_average, fresnel_combine
from snell_bench.imaging.pyramid import collapse, laplacian_pyramid, pyramid_warp


def dpa_reference(xs, ms, lam):
    """Per-pixel numpy detail-preserving average, NaN where no input is valid."""
    xs, ms = np.asarray(xs, np.float64), np.asarray(ms, bool)
    out = np.full(xs.shape[1:], np.nan)
    for idx in np.ndindex(*xs.shape[1:]):
        v = xs[(slice(None), *idx)][ms[(slice(None), *idx)]]
        if v.size == 0:
            continue
        avg = v.mean()
        vavg = (np.abs(v) * v).sum() / np.abs(v).sum() if np.abs(v).sum() > 0 else avg
        out[idx] = avg + lam * (vavg - avg)
    return out


def px(*values):
    """Inputs of one pixel: tensors (1, 1, 1, 1)."""
    return [torch.tensor(float(v)).reshape(1, 1, 1, 1) for v in values]


class TestDetailPreservingAverage:
    def test_lam_zero_is_the_masked_mean(self):
        a = torch.tensor([[1.0, 2.0], [3.0, 4.0]])[None, None]
        b = torch.tensor([[5.0, -6.0], [7.0, 8.0]])[None, None]
        c = torch.tensor([[0.0, 10.0], [-2.0, 1.0]])[None, None]
        ma = torch.tensor([[True, True], [False, True]])
        mb = torch.tensor([[True, False], [True, True]])
        mc = torch.tensor([[False, True], [True, True]])
        out, ok = detail_preserving_average([a, b, c], [ma, mb, mc], lam=0.0)
        expected = torch.tensor([[(1 + 5) / 2, (2 + 10) / 2], [(7 - 2) / 2, (4 + 8 + 1) / 3]])
        torch.testing.assert_close(out[0, 0], expected)
        assert ok.shape == (1, 1, 2, 2) and ok.all()

    def test_one_pixel_with_signed_values(self):
        out, _ = detail_preserving_average(px(2.0, -1.0, 0.5), lam=0.5)
        # avg = 1.5 / 3, vavg = (4 - 1 + 0.25) / (2 + 1 + 0.5)
        assert float(out) == pytest.approx(0.5 + 0.5 * (3.25 / 3.5 - 0.5))
        out, _ = detail_preserving_average(px(2.0, -1.0, 0.5), [None, None, torch.zeros(1, 1, dtype=torch.bool)])
        assert float(out) == pytest.approx(0.5 + 0.5 * (3.0 / 3.0 - 0.5))
        out, _ = detail_preserving_average(px(2.0, -1.0, 0.5), lam=1.0)
        assert float(out) == pytest.approx(3.25 / 3.5)

    def test_no_valid_input_keeps_the_fallback(self):
        x0 = torch.tensor([[1.0, float("nan")]])[None, None]
        x1 = torch.tensor([[float("inf"), float("-inf")]])[None, None]
        m0 = torch.tensor([[True, False]])
        m1 = torch.tensor([[False, False]])
        out, ok = detail_preserving_average([x0, x1], [m0, m1])
        assert torch.isfinite(out).all()
        assert ok[0, 0].tolist() == [[True, False]]
        assert out[0, 0, 0, 0] == 1.0 and out[0, 0, 0, 1] == 0.0  # first input, non-finite as 0
        fb = torch.full_like(x0, 0.25)
        out, _ = detail_preserving_average([x0, x1], [m0, m1], fallback=fb)
        assert out[0, 0, 0, 1] == 0.25 and out[0, 0, 0, 0] == 1.0

    def test_zero_magnitudes_use_the_average(self):
        out, ok = detail_preserving_average(px(0.0, 0.0, 7.0), [None, None, torch.zeros(1, 1, dtype=torch.bool)])
        assert ok.all() and float(out) == 0.0

    def test_against_reference_with_different_masks(self):
        g = torch.Generator().manual_seed(0)
        xs = [torch.randn(2, 3, 5, 6, generator=g, dtype=torch.float64) for _ in range(3)]
        top_rows = torch.zeros(2, 1, 5, 6, dtype=torch.bool)
        top_rows[..., :2, :] = True
        ms = [
            torch.rand(5, 6, generator=g) > 0.3,  # (H, W), broadcast over batch and channels
            torch.rand(2, 1, 5, 6, generator=g) > 0.5,
            top_rows,
        ]
        full = [np.broadcast_to(m.numpy(), (2, 3, 5, 6)) for m in ms]
        for lam in (0.0, 0.5, 0.8):
            out, ok = detail_preserving_average(xs, ms, lam=lam)
            ref = dpa_reference([x.numpy() for x in xs], full, lam)
            has = ~np.isnan(ref)
            np.testing.assert_allclose(out.numpy()[has], ref[has], rtol=1e-12, atol=1e-12)
            np.testing.assert_array_equal(ok.expand(2, 3, 5, 6).numpy(), has)
            np.testing.assert_array_equal(out.numpy()[~has], xs[0].numpy()[~has])

    def test_dtype_batch_and_gradcheck(self):
        xs = [torch.rand(2, 1, 3, 3, dtype=torch.float64) + 0.1 for _ in range(3)]
        ms = [torch.rand(2, 1, 3, 3) > 0.4 for _ in range(3)]
        out, ok = detail_preserving_average(xs, ms)
        assert out.dtype == torch.float64 and out.shape == (2, 1, 3, 3) and ok.shape == (2, 1, 3, 3)
        for b in range(2):
            ref, _ = detail_preserving_average([x[b : b + 1] for x in xs], [m[b : b + 1] for m in ms])
            torch.testing.assert_close(out[b : b + 1], ref)
        inputs = [x.clone().requires_grad_() for x in xs]
        assert torch.autograd.gradcheck(lambda *x: detail_preserving_average(list(x), ms)[0], inputs)

    def test_empty_inputs(self):
        with pytest.raises(ValueError):
            detail_preserving_average([], [])


class TestBlendPyramids:
    def test_identical_inputs_return_the_input(self):
        img = torch.rand(1, 3, 45, 80)
        pyr = laplacian_pyramid(img, 4)
        out, ok = blend_pyramids([pyr, pyr, pyr], lam=0.5)
        assert ok.all() and ok.shape == (1, 1, 45, 80)
        assert (out - img).abs().max() < 1e-5

    def test_is_per_level_dpa_then_collapse(self):
        g = torch.Generator().manual_seed(4)
        own = torch.rand(1, 3, 64, 64, generator=g)
        other = torch.rand(1, 3, 64, 64, generator=g)
        y, x = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
        c = torch.stack([x * 0.8 + 5, y], -1)
        c[8:56, 8:56] = float("nan")
        own_pyr = laplacian_pyramid(own, 4)
        warped, masks = pyramid_warp(other, c, levels=4, collapse=False)
        out, ok = blend_pyramids([own_pyr, warped], [None, masks], lam=0.5)
        assert torch.equal(ok, torch.ones_like(ok))
        levels = [detail_preserving_average([a, b], [None, m])[0] for a, b, m in zip(own_pyr, warped, masks)]
        torch.testing.assert_close(out, collapse(levels))
        assert torch.isfinite(out).all()
        # far inside the hole every level that reaches a pixel is the own estimate's
        assert (out - own)[..., 28:36, 28:36].abs().max() < 1e-5
        assert (out - own)[..., :8].abs().max() > 0.01

    def test_fallback_levels(self):
        a = laplacian_pyramid(torch.rand(1, 1, 32, 32), 3)
        fb = laplacian_pyramid(torch.full((1, 1, 32, 32), 0.5), 3)
        none = [torch.zeros(p.shape[-2:], dtype=torch.bool) for p in a]
        out, ok = blend_pyramids([a], [none], fallback_levels=fb)
        assert not ok.any()
        assert (out - 0.5).abs().max() < 1e-6


class TestBlendImages:
    """phi of whole images in FLUX's [-1, 1] image space (``sampler.dpa_domain=image``)."""

    def test_bright_and_dark_meet_in_the_middle(self):
        # 0.8, 0.2 -> 0.6, -0.6: avg 0, vavg (0.36 - 0.36) / 1.2 = 0 -> 0.5 after mapping back
        out, ok = blend_images(px(0.8, 0.2), lam=0.5)
        assert float(out) == pytest.approx(0.5, abs=1e-7) and bool(ok)
        # in [0, 1] directly: avg 0.5, vavg (0.64 + 0.04) / 1.0 = 0.68 -> 0.59
        assert float(detail_preserving_average(px(0.8, 0.2), lam=0.5)[0]) == pytest.approx(0.59, abs=1e-7)

    def test_against_reference_in_minus_one_one(self):
        g = torch.Generator().manual_seed(0)
        xs = [torch.rand(1, 2, 3, 4, generator=g) for _ in range(3)]
        ms = [torch.rand(1, 1, 3, 4, generator=g) > 0.3 for _ in range(3)]
        ms[0][..., 0, 0] = ms[1][..., 0, 0] = ms[2][..., 0, 0] = False
        out, ok = blend_images(xs, ms, lam=0.7)
        signed = [2 * x.numpy() - 1 for x in xs]
        masks = [np.broadcast_to(m.numpy(), xs[0].shape) for m in ms]
        ref = (dpa_reference(signed, masks, 0.7) + 1) / 2
        has = ~np.isnan(ref)
        np.testing.assert_allclose(out.numpy()[has], ref[has], atol=1e-6)
        # no valid input: the first image (the branch's own estimate)
        assert torch.equal(out[..., 0, 0], xs[0][..., 0, 0]) and not ok[..., 0, 0].any()

    def test_one_level_pyramid_with_signed_lowpass_is_the_image_blend(self):
        g = torch.Generator().manual_seed(1)
        xs = [torch.rand(1, 3, 8, 8, generator=g) for _ in range(2)]
        a, _ = blend_images(xs, lam=0.5)
        b, _ = blend_pyramids([[x] for x in xs], lam=0.5, signed_lowpass=True)
        torch.testing.assert_close(a, b, atol=0, rtol=0)

    def test_signed_lowpass_of_constant_images(self):
        # ``dpa_domain=bands``: constant images have zero bands; the low-pass level blends in [-1, 1]
        pyr = [laplacian_pyramid(torch.full((1, 1, 8, 8), v), 3) for v in (0.8, 0.2)]
        signed, _ = blend_pyramids(pyr, lam=0.5, signed_lowpass=True)
        unsigned, _ = blend_pyramids(pyr, lam=0.5)
        torch.testing.assert_close(signed, torch.full_like(signed, 0.5), atol=1e-6, rtol=0)
        torch.testing.assert_close(unsigned, torch.full_like(unsigned, 0.59), atol=1e-6, rtol=0)


class TestFresnelCombine:
    def test_limits(self):
        g = torch.Generator().manual_seed(0)
        refl, refr = torch.rand(2, 3, 4, 5, generator=g), torch.rand(2, 3, 4, 5, generator=g)
        assert torch.equal(fresnel_combine(refl, refr, torch.zeros(4, 5)), refr)
        assert (fresnel_combine(refl, refr, torch.ones(2, 1, 4, 5)) - refl).abs().max() < 1e-6

    def test_half_of_black_and_white_is_mixed_in_linear_light(self):
        black, white = torch.zeros(1, 3, 2, 2), torch.ones(1, 3, 2, 2)
        out = fresnel_combine(white, black, np.full((2, 2), 0.5, np.float32))
        torch.testing.assert_close(out, torch.full_like(out, 1.055 * 0.5 ** (1 / 2.4) - 0.055))
        assert float(out[0, 0, 0, 0]) == pytest.approx(0.7354, abs=1e-4)

    def test_mask_and_dtype(self):
        refl, refr = torch.ones(1, 3, 2, 3, dtype=torch.float64), torch.full((1, 3, 2, 3), 0.2, dtype=torch.float64)
        mask = torch.tensor([[True, False, True], [False, False, True]])
        out = fresnel_combine(refl, refr, torch.full((1, 1, 2, 3), 0.3, dtype=torch.float64), mask)
        assert out.dtype == torch.float64
        assert torch.equal(out[..., ~mask], refr[..., ~mask])
        assert (out[..., mask] > 0.2 + 0.1).all()


def test_meta_gives_the_real_shapes():
    """On ``meta`` (shapes, no data) the blends give the real computation's shapes and dtypes."""
    g = torch.Generator().manual_seed(0)
    imgs = [torch.rand(1, 3, 12, 20, generator=g) for _ in range(3)]
    masks = [torch.rand(12, 20, generator=g) > 0.5 for _ in range(3)]
    pyrs = [laplacian_pyramid(x, 3) for x in imgs]
    R = np.full((12, 20), 0.04, np.float32)

    def meta(x):
        return [meta(v) for v in x] if isinstance(x, list) else torch.empty_like(x, device="meta")

    def layout(out):
        return [(tuple(t.shape), t.dtype) for t in out]

    calls = [
        lambda f: blend_images(f(imgs), f(masks), lam=0.5),
        lambda f: blend_pyramids([f(p) for p in pyrs], None, lam=0.5, signed_lowpass=True),
        lambda f: (fresnel_combine(f(imgs[0]), f(imgs[1]), R, mask=f(masks[0])),),
    ]
    for call in calls:
        on_meta = call(meta)
        assert layout(on_meta) == layout(call(lambda x: x)) and all(t.is_meta for t in on_meta)
