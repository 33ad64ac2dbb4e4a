"""Masked fidelity metrics against independent references (numpy, scikit-image, torchmetrics)."""

import copy
import math
import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np
import pytest
import torch

from snell_bench.metrics import (
    EMPTY_MASK_REASON,
    NON_FINITE_REASON,
    PROTOCOLS,
    MaskedLPIPS,
    MaskedMAE,
    MaskedPSNR,
    MetricUnavailable,
    check_protocol,
    masked_mae,
    masked_psnr,
    match_histogram_masked,
    score_all,
    to_gray,
)

H, W = 24, 32


def gray_ref(img_hwc):
    """Grayscale written independently: BT.601 luma weights on the last axis."""
    return np.asarray(img_hwc, np.float64) @ np.array([0.299, 0.587, 0.114])


def to_bchw(img_hwc):
    return torch.from_numpy(np.ascontiguousarray(img_hwc)).permute(2, 0, 1)[None].float()


@pytest.fixture
def pair():
    rng = np.random.default_rng(7)
    ref = rng.random((H, W, 3))
    gen = np.clip(0.7 * ref + 0.3 * rng.random((H, W, 3)), 0, 1)
    mask = np.zeros((H, W), bool)
    mask[4:18, 6:25] = True
    mask[10:14, 10:14] = False
    return gen, ref, mask


FULL = np.ones((H, W), bool)


class TestToGray:
    def test_numpy_and_torch(self, pair):
        gen, _, _ = pair
        np.testing.assert_allclose(to_gray(gen), gray_ref(gen), atol=1e-12)
        t = to_gray(to_bchw(gen))
        assert t.shape == (1, 1, H, W) and t.dtype == torch.float32
        np.testing.assert_allclose(t[0, 0].numpy(), gray_ref(gen), atol=1e-6)

    def test_uint8(self, pair):
        gen, _, _ = pair
        g8 = (gen * 255).round().astype(np.uint8)
        np.testing.assert_allclose(to_gray(g8), gray_ref(g8 / 255.0), atol=1e-12)
        t8 = torch.from_numpy(g8).permute(2, 0, 1)[None]
        np.testing.assert_allclose(to_gray(t8)[0, 0].numpy(), gray_ref(g8 / 255.0), atol=1e-6)

    def test_equal_channels_are_unchanged(self):
        v = np.random.default_rng(0).random((5, 6))
        np.testing.assert_allclose(to_gray(np.repeat(v[..., None], 3, -1)), v, atol=1e-12)


class TestPSNRAndMAEReferences:
    def test_full_mask_no_matching_equals_skimage_and_torchmetrics(self, pair):
        from skimage.metrics import peak_signal_noise_ratio
        from torchmetrics.functional.image import peak_signal_noise_ratio as tm_psnr

        gen, ref, _ = pair
        ours = masked_psnr(gen, ref, FULL, histogram_match=False)
        sk = peak_signal_noise_ratio(gray_ref(ref), gray_ref(gen), data_range=1)
        tm = tm_psnr(
            torch.from_numpy(gray_ref(gen))[None, None], torch.from_numpy(gray_ref(ref))[None, None], data_range=1.0
        ).item()
        assert ours == pytest.approx(sk, abs=1e-10)
        assert ours == pytest.approx(tm, abs=1e-6)
        # torch (B, 3, H, W) inputs and a (B, 1, H, W) mask give the same number
        tmask = torch.ones(1, 1, H, W, dtype=torch.bool)
        assert masked_psnr(to_bchw(gen), to_bchw(ref), tmask, histogram_match=False) == pytest.approx(ours, abs=1e-5)

    def test_full_mask_mae_equals_numpy(self, pair):
        gen, ref, _ = pair
        expected = np.mean(np.abs(gray_ref(gen) - gray_ref(ref)))
        assert masked_mae(gen, ref, FULL, histogram_match=False) == pytest.approx(expected, abs=1e-12)

    def test_rgb_mode_equals_skimage_on_rgb(self, pair):
        from skimage.metrics import peak_signal_noise_ratio

        gen, ref, _ = pair
        ours = masked_psnr(gen, ref, FULL, histogram_match=False, grayscale=False)
        assert ours == pytest.approx(peak_signal_noise_ratio(ref, gen, data_range=1), abs=1e-10)

    def test_hand_computed_2x2(self):
        gen = np.array([[0.2, 0.4], [0.6, 0.8]])
        ref = np.array([[0.3, 0.4], [0.0, 1.0]])
        mask = np.array([[True, False], [False, True]])
        # masked differences 0.1 and 0.2: MSE = 0.025, MAE = 0.15
        assert masked_psnr(gen, ref, mask, histogram_match=False) == pytest.approx(10 * math.log10(40.0))
        assert masked_mae(gen, ref, mask, histogram_match=False) == pytest.approx(0.15)
        # RGB with equal channels: the gray image is the channel value
        rgb = lambda a: np.repeat(a[..., None], 3, -1)  # noqa: E731
        assert masked_psnr(rgb(gen), rgb(ref), mask, histogram_match=False) == pytest.approx(10 * math.log10(40.0))

    def test_hand_computed_histogram_matching(self):
        gen = np.array([[0.2, 0.5], [0.5, 0.8]])
        ref = np.array([[0.9, 0.0], [0.0, 0.1]])
        mask = np.array([[True, False], [False, True]])
        # inside the mask gen = (0.2, 0.8) -> ranks (0, 1) -> matched (0.1, 0.9); ref = (0.9, 0.1)
        matched = match_histogram_masked(gen, ref, mask)
        np.testing.assert_allclose(matched, [[0.1, 0.5], [0.5, 0.9]], atol=1e-12)
        assert masked_mae(gen, ref, mask) == pytest.approx(0.8)
        assert masked_psnr(gen, ref, mask) == pytest.approx(10 * math.log10(1 / 0.64))

    def test_identical_images_give_inf_and_zero(self, pair):
        _, ref, mask = pair
        assert masked_psnr(ref, ref, mask) == math.inf
        assert masked_mae(ref, ref, mask) == 0.0

    def test_uint8_is_read_as_fraction_of_255(self, pair):
        gen, ref, mask = pair
        g8, r8 = (gen * 255).round().astype(np.uint8), (ref * 255).round().astype(np.uint8)
        assert masked_psnr(g8, r8, mask) == pytest.approx(masked_psnr(g8 / 255.0, r8 / 255.0, mask), abs=1e-12)


class TestHistogramMatching:
    def test_full_mask_equals_skimage(self, pair):
        from skimage.exposure import match_histograms

        gen, ref, _ = pair
        g, r = gray_ref(gen), gray_ref(ref)
        np.testing.assert_allclose(match_histogram_masked(g, r, FULL), match_histograms(g, r), atol=1e-12)

    def test_full_mask_with_ties_equals_skimage(self, pair):
        from skimage.exposure import match_histograms

        gen, ref, _ = pair
        g, r = np.round(gray_ref(gen) * 8) / 8, np.round(gray_ref(ref) * 20) / 20  # many ties
        ours = match_histogram_masked(g, r, FULL)
        np.testing.assert_allclose(ours, match_histograms(g, r), atol=1e-12)
        assert masked_psnr(g, r, FULL) == pytest.approx(
            10 * math.log10(1 / np.mean((match_histograms(g, r) - r) ** 2)), abs=1e-9
        )

    def test_partial_mask_equals_skimage_on_masked_values(self, pair):
        from skimage.exposure import match_histograms

        gen, ref, mask = pair
        g, r = gray_ref(gen), gray_ref(ref)
        out = match_histogram_masked(g, r, mask)
        np.testing.assert_allclose(out[mask], match_histograms(g[mask], r[mask]), atol=1e-12)
        np.testing.assert_array_equal(out[~mask], g[~mask])

    def test_rank_method_gives_the_reference_values_exactly(self, pair):
        gen, ref, mask = pair
        g, r = gray_ref(gen), gray_ref(ref)
        out = match_histogram_masked(g, r, mask, method="rank")
        np.testing.assert_array_equal(np.sort(out[mask]), np.sort(r[mask]))
        # order is preserved: the ranks of the generated values are kept
        np.testing.assert_array_equal(np.argsort(out[mask], kind="stable"), np.argsort(g[mask], kind="stable"))

    def test_torch_in_torch_out(self, pair):
        gen, ref, mask = pair
        g = to_gray(to_bchw(gen))
        r = to_gray(to_bchw(ref))
        out = match_histogram_masked(g, r, torch.from_numpy(mask)[None, None])
        assert isinstance(out, torch.Tensor) and out.shape == g.shape and out.dtype == g.dtype
        np.testing.assert_allclose(
            out[0, 0].numpy(),
            match_histogram_masked(g[0, 0].double().numpy(), r[0, 0].double().numpy(), mask),
            atol=1e-6,
        )

    @pytest.mark.parametrize("method", ["cdf", "rank"])
    def test_invariant_to_monotone_brightness_change(self, pair, method):
        gen, ref, mask = pair
        base = masked_psnr(gen, ref, mask, method=method)
        assert masked_psnr(0.5 * gen + 0.1, ref, mask, method=method) == pytest.approx(base, abs=1e-9)
        assert masked_mae(0.5 * gen + 0.1, ref, mask, method=method) == pytest.approx(
            masked_mae(gen, ref, mask, method=method), abs=1e-12
        )
        # without matching the brightness change does matter
        assert masked_psnr(0.5 * gen + 0.1, ref, mask, histogram_match=False) != pytest.approx(
            masked_psnr(gen, ref, mask, histogram_match=False), abs=1e-3
        )


class TestMaskHandling:
    def test_empty_mask_is_unavailable(self, pair):
        gen, ref, _ = pair
        empty = np.zeros((H, W), bool)
        for fn in (masked_psnr, masked_mae):
            with pytest.raises(MetricUnavailable) as exc:
                fn(gen, ref, empty)
            assert exc.value.reason == EMPTY_MASK_REASON
        result = score_all(gen, ref, empty, "a glass sphere")
        assert result["metrics"]["psnr"] is None and result["metrics"]["mae"] is None
        assert result["missing"]["psnr"] == EMPTY_MASK_REASON
        assert result["missing"]["mae"] == EMPTY_MASK_REASON

    def test_pixels_outside_the_mask_do_not_matter(self, pair):
        gen, ref, mask = pair
        rng = np.random.default_rng(1)
        gen2, ref2 = gen.copy(), ref.copy()
        gen2[~mask] = rng.random(((~mask).sum(), 3))
        ref2[~mask] = rng.random(((~mask).sum(), 3))
        for hm in (True, False):
            assert masked_psnr(gen2, ref2, mask, histogram_match=hm) == masked_psnr(gen, ref, mask, histogram_match=hm)
            assert masked_mae(gen2, ref2, mask, histogram_match=hm) == masked_mae(gen, ref, mask, histogram_match=hm)

    def test_mask_shapes_and_errors(self, pair):
        gen, ref, mask = pair
        expected = masked_psnr(gen, ref, mask)
        for m in (mask[None], mask[None, None], mask[..., None], mask.astype(np.float32), torch.from_numpy(mask)):
            assert masked_psnr(gen, ref, m) == pytest.approx(expected, abs=1e-12)
        with pytest.raises(ValueError, match="mask shape"):
            masked_psnr(gen, ref, mask[:-1])
        with pytest.raises(ValueError, match="one image"):
            masked_psnr(torch.rand(2, 3, H, W), torch.rand(2, 3, H, W), mask)


class TestClassForms:
    def test_batch_mean_and_missing_count(self, pair):
        gen, ref, mask = pair
        rng = np.random.default_rng(3)
        gens = [gen, rng.random((H, W, 3)), gen]
        refs = [ref, ref, rng.random((H, W, 3))]
        masks = [mask, mask, np.zeros_like(mask)]
        g = torch.cat([to_bchw(x) for x in gens]).double()
        r = torch.cat([to_bchw(x) for x in refs]).double()
        m = torch.from_numpy(np.stack(masks))[:, None]
        for cls, fn in ((MaskedPSNR, masked_psnr), (MaskedMAE, masked_mae)):
            metric = cls()
            metric.update(g, r, m)
            assert metric.missing == 1 and len(metric.values) == 2
            expected = np.mean([fn(gens[i], refs[i], masks[i]) for i in range(2)])
            assert metric.compute() == pytest.approx(expected, abs=1e-6)
            metric.reset()
            with pytest.raises(MetricUnavailable):
                metric.compute()


# ------------------------------------------------------------------------------------------
# LPIPS
# ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def random_lpips():
    return MaskedLPIPS(allow_random_backbone=True)


class TestMaskedLPIPS:
    def test_identical_images_score_zero(self, random_lpips, pair):
        _, ref, mask = pair
        assert random_lpips.backbone_source == "random"
        assert not random_lpips.training
        assert random_lpips(ref, ref, mask) == pytest.approx(0.0, abs=1e-7)
        tmask = torch.from_numpy(mask)[None, None]
        assert random_lpips(to_bchw(ref), to_bchw(ref), tmask) == pytest.approx(0.0, abs=1e-7)

    def test_masked_mean_equals_hand_computed(self, random_lpips, pair):
        from skimage.exposure import match_histograms

        gen, ref, mask = pair
        # preprocessing written independently: gray, skimage matching of the masked values, [-1, 1]
        g, r = gray_ref(gen), gray_ref(ref)
        g_matched = g.copy()
        g_matched[mask] = match_histograms(g[mask], r[mask])
        to_in = lambda a: torch.from_numpy(a).float()[None, None].expand(1, 3, H, W) * 2 - 1  # noqa: E731
        with torch.no_grad():
            lp_map = random_lpips.model(to_in(g_matched), to_in(r))[0, 0].double().numpy()
        assert lp_map.shape == (H, W) and (lp_map[mask] > 0).all()
        expected = lp_map[mask].mean()
        assert random_lpips(gen, ref, mask) == pytest.approx(expected, rel=1e-5)
        np.testing.assert_allclose(random_lpips.spatial_map(gen, ref, mask).numpy(), lp_map, rtol=1e-5, atol=1e-7)

    def test_full_mask_equals_lpips_spatial_average(self, random_lpips):
        torch.manual_seed(0)
        g, r = torch.rand(1, 3, 32, 64), torch.rand(1, 3, 32, 64)
        ours = random_lpips(g, r, torch.ones(32, 64, dtype=torch.bool), grayscale=False, histogram_match=False)
        random_lpips.model.spatial = False
        try:
            with torch.no_grad():
                reference = random_lpips.model(g * 2 - 1, r * 2 - 1).item()
        finally:
            random_lpips.model.spatial = True
        assert ours == pytest.approx(reference, rel=1e-5)

    def test_empty_mask_is_unavailable(self, random_lpips, pair):
        gen, ref, _ = pair
        with pytest.raises(MetricUnavailable, match="empty mask"):
            random_lpips(gen, ref, np.zeros((H, W), bool))

    def test_missing_weights_name_the_config_key(self, tmp_path, monkeypatch):
        monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
        with pytest.raises(MetricUnavailable, match="metrics.lpips_weights"):
            MaskedLPIPS()
        with pytest.raises(MetricUnavailable, match="metrics.lpips_weights"):
            MaskedLPIPS(weights_path=tmp_path / "vgg16-397923af.pth")
        with pytest.raises(MetricUnavailable, match="metrics.lpips_weights"):
            MaskedLPIPS(weights_path=tmp_path / "missing.pth", allow_random_backbone=True)

    def test_torch_hub_cache_is_found(self, tmp_path, monkeypatch):
        monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path))
        (tmp_path / "checkpoints").mkdir()
        (tmp_path / "checkpoints" / "vgg16-397923af.pth").write_bytes(b"")
        found = MaskedLPIPS._resolve_weights(None, "vgg16-397923af.pth", "vgg16", False)
        assert found == tmp_path / "checkpoints" / "vgg16-397923af.pth"

    def test_backbone_loads_from_a_torchvision_state_dict(self, random_lpips, tmp_path):
        gen = torch.Generator().manual_seed(5)
        state = {}
        for key, p in random_lpips.model.net.state_dict().items():
            _, idx, pname = key.split(".")  # slice{k}.{features index}.{weight|bias}
            state[f"features.{idx}.{pname}"] = torch.randn(p.shape, generator=gen) * 0.05
        state["classifier.0.bias"] = torch.zeros(4)  # extra keys of a full vgg16 file are ignored
        path = tmp_path / "vgg16-397923af.pth"
        torch.save(state, path)
        loaded = MaskedLPIPS(weights_path=path)
        assert loaded.backbone_source == str(path)
        net = loaded.model.net.state_dict()
        for key in net:
            s, idx, pname = key.split(".")
            torch.testing.assert_close(net[key], state[f"features.{idx}.{pname}"], rtol=0, atol=0)
        # the calibrated linear layers come from the lpips package, not from the backbone file
        torch.testing.assert_close(loaded.model.lin0.model[1].weight, random_lpips.model.lin0.model[1].weight)

    def test_wrong_file_is_an_error(self, tmp_path):
        path = tmp_path / "bad.pth"
        torch.save({"something.else": torch.zeros(1)}, path)
        with pytest.raises(ValueError, match="not a torchvision vgg16 state_dict"):
            MaskedLPIPS(weights_path=path)


@pytest.mark.weights
def test_lpips_with_real_vgg_weights():
    """Needs ``SNELL_LPIPS_WEIGHTS`` (a vgg16-397923af.pth) or the file in the torch hub cache."""
    try:
        lp = MaskedLPIPS(os.environ.get("SNELL_LPIPS_WEIGHTS"))
    except MetricUnavailable as e:
        pytest.skip(e.reason)
    rng = np.random.default_rng(0)
    ref = np.repeat(np.linspace(0, 1, 64)[None, :, None], 64, 0).repeat(3, -1)
    noisy = np.clip(ref + 0.02 * rng.standard_normal(ref.shape), 0, 1)
    very_noisy = np.clip(ref + 0.3 * rng.standard_normal(ref.shape), 0, 1)
    mask = np.ones((64, 64), bool)
    assert lp(ref, ref, mask) == pytest.approx(0.0, abs=1e-6)
    assert 0 < lp(noisy, ref, mask) < lp(very_noisy, ref, mask) < 1.5


# ------------------------------------------------------------------------------------------
# The authors' protocol
# ------------------------------------------------------------------------------------------


def authors_matched(g, r):
    """The authors' matching written independently: skimage's CDF matching of the masked values, then
    an explicit linear rescale onto the generated values' own range."""
    from skimage.exposure import match_histograms

    m = match_histograms(g, r)
    return g.min() + (m - m.min()) * (g.max() - g.min()) / (m.max() - m.min())


class TestAuthorsProtocol:
    def test_hand_computed_2x2(self):
        gen = np.array([[0.3, 0.5], [0.4, 0.7]])
        ref = np.array([[0.0, 0.2], [0.6, 1.0]])
        full = np.ones((2, 2), bool)
        # ranks of gen (0.3, 0.5, 0.4, 0.7) -> (0, 2, 1, 3): matched onto ref's values (0, 0.6, 0.2, 1)
        paper = match_histogram_masked(gen, ref, full)
        np.testing.assert_allclose(paper, [[0.0, 0.6], [0.2, 1.0]], atol=1e-12)
        # differences (0, 0.4, -0.4, 0): MSE 0.08, MAE 0.2
        assert masked_psnr(gen, ref, full) == pytest.approx(10 * math.log10(12.5))  # 10.9691 dB
        assert masked_mae(gen, ref, full) == pytest.approx(0.2)
        # authors: the matched (0, 0.6, 0.2, 1) rescaled from [0, 1] onto gen's range [0.3, 0.7]
        authors = match_histogram_masked(gen, ref, full, protocol="authors")
        np.testing.assert_allclose(authors, [[0.3, 0.54], [0.38, 0.7]], atol=1e-12)
        # differences (0.3, 0.34, -0.22, -0.3): MSE 0.344 / 4 = 0.086, MAE 1.16 / 4 = 0.29
        assert masked_psnr(gen, ref, full, protocol="authors") == pytest.approx(10 * math.log10(1 / 0.086))  # 10.6550
        assert masked_mae(gen, ref, full, protocol="authors") == pytest.approx(0.29)

    def test_hand_computed_4x4_constant_images(self):
        mask = np.zeros((4, 4), bool)
        mask[1, 1:3] = mask[2, 1:3] = True
        # outside the mask: values that would change every number if they were read
        outside = np.random.default_rng(2).random((4, 4))
        gen = np.where(mask, 0.25, outside)  # constant inside the mask: zero range
        ref = outside.copy()
        ref[1, 1], ref[1, 2], ref[2, 1], ref[2, 2] = 0.05, 0.25, 0.45, 0.65
        # paper: every generated value maps to the reference's top quantile 0.65;
        # differences (0.6, 0.4, 0.2, 0): MSE 0.14, MAE 0.3
        np.testing.assert_allclose(match_histogram_masked(gen, ref, mask)[mask], 0.65, atol=1e-12)
        assert masked_psnr(gen, ref, mask) == pytest.approx(10 * math.log10(1 / 0.14))  # 8.5387 dB
        assert masked_mae(gen, ref, mask) == pytest.approx(0.3)
        # authors: the zero range cannot be stretched: the rescale leaves the generated constant 0.25;
        # differences (-0.2, 0, 0.2, 0.4): MSE 0.06, MAE 0.2 (= the unmatched pair)
        matched = match_histogram_masked(gen, ref, mask, protocol="authors")
        np.testing.assert_array_equal(matched[mask], 0.25)
        np.testing.assert_array_equal(matched[~mask], gen[~mask])
        assert masked_psnr(gen, ref, mask, protocol="authors") == pytest.approx(10 * math.log10(1 / 0.06))  # 12.2185
        assert masked_mae(gen, ref, mask, protocol="authors") == pytest.approx(0.2)
        # a constant reference 0.9 against gen (0.2, 0.4, 0.6, 0.8): paper matches everything to 0.9
        # (identical: inf); authors clips the constant 0.9 into gen's range [0.2, 0.8] -> 0.8:
        # differences 0.1 everywhere, MSE 0.01, PSNR 20 dB
        gen2 = outside.copy()
        gen2[1, 1], gen2[1, 2], gen2[2, 1], gen2[2, 2] = 0.2, 0.4, 0.6, 0.8
        ref2 = np.where(mask, 0.9, outside)
        assert masked_psnr(gen2, ref2, mask) == math.inf and masked_mae(gen2, ref2, mask) == 0.0
        np.testing.assert_allclose(match_histogram_masked(gen2, ref2, mask, protocol="authors")[mask], 0.8)
        assert masked_psnr(gen2, ref2, mask, protocol="authors") == pytest.approx(20.0)
        assert masked_mae(gen2, ref2, mask, protocol="authors") == pytest.approx(0.1)
        for g, r in ((gen, ref), (gen2, ref2), (gen, np.where(mask, 0.7, outside))):
            for fn in (masked_psnr, masked_mae):
                assert not math.isnan(fn(g, r, mask, protocol="authors"))

    def test_affine_change_is_forgiven_by_paper_not_by_authors(self, pair):
        _, ref, mask = pair
        gen = 0.5 * ref + 0.2  # an affine change of the reference, inside and outside the mask
        r = gray_ref(ref)[mask]
        # paper: matching carries gen's values back onto ref's exactly
        assert masked_psnr(gen, ref, mask) > 100 and masked_mae(gen, ref, mask) < 1e-9
        # authors: matched in shape, rescaled to gen's range: gen itself, i.e. the unmatched pair
        expected_mse = np.mean((0.2 - 0.5 * r) ** 2)
        ours = masked_psnr(gen, ref, mask, protocol="authors")
        assert ours == pytest.approx(10 * math.log10(1 / expected_mse), abs=1e-9)
        assert ours == pytest.approx(masked_psnr(gen, ref, mask, histogram_match=False), abs=1e-9)
        assert ours < 20
        assert masked_mae(gen, ref, mask, protocol="authors") == pytest.approx(np.mean(np.abs(0.2 - 0.5 * r)))

    def test_noisy_affine_equals_independent_numpy(self, pair):
        _, ref, mask = pair
        rng = np.random.default_rng(4)
        gen = 0.5 * ref + 0.2 + 0.03 * rng.standard_normal(ref.shape)
        g, r = gray_ref(gen)[mask], gray_ref(ref)[mask]
        out = authors_matched(g, r)
        mse = np.mean((out - r) ** 2)
        assert masked_psnr(gen, ref, mask, protocol="authors") == pytest.approx(10 * np.log10(1 / mse), abs=1e-9)
        assert masked_mae(gen, ref, mask, protocol="authors") == pytest.approx(np.mean(np.abs(out - r)), abs=1e-12)
        np.testing.assert_allclose(
            match_histogram_masked(gray_ref(gen), gray_ref(ref), mask, protocol="authors")[mask], out
        )
        # the two protocols differ on this pair: paper forgives the contrast change, authors do not
        assert masked_psnr(gen, ref, mask) > masked_psnr(gen, ref, mask, protocol="authors") + 5
        # float64 torch inputs and the class forms give the same numbers
        tg, tr = (torch.from_numpy(a).permute(2, 0, 1)[None] for a in (gen, ref))
        assert masked_psnr(tg, tr, mask, protocol="authors") == pytest.approx(10 * np.log10(1 / mse), abs=1e-9)
        metric = MaskedPSNR(protocol="authors")
        metric.update(tg, tr, torch.from_numpy(mask)[None, None])
        assert metric.compute() == pytest.approx(10 * np.log10(1 / mse), abs=1e-9)

    def test_rgb_mode_rescales_each_channel(self, pair):
        gen, ref, mask = pair
        gv, rv = np.asarray(gen)[mask], np.asarray(ref)[mask]
        out = np.stack([authors_matched(gv[:, c], rv[:, c]) for c in range(3)], axis=1)
        expected = 10 * np.log10(1 / np.mean((out - rv) ** 2))
        assert masked_psnr(gen, ref, mask, grayscale=False, protocol="authors") == pytest.approx(expected, abs=1e-9)

    def test_identical_empty_and_non_finite(self, pair):
        gen, ref, mask = pair
        assert masked_psnr(ref, ref, mask, protocol="authors") == math.inf
        assert masked_mae(ref, ref, mask, protocol="authors") == 0.0
        for fn in (masked_psnr, masked_mae):
            with pytest.raises(MetricUnavailable) as exc:
                fn(gen, ref, np.zeros_like(mask), protocol="authors")
            assert exc.value.reason == EMPTY_MASK_REASON
        bad = gen.copy()
        bad[mask.nonzero()[0][0], mask.nonzero()[1][0]] = np.nan
        for protocol in PROTOCOLS:
            for fn in (masked_psnr, masked_mae):
                with pytest.raises(MetricUnavailable) as exc:
                    fn(bad, ref, mask, protocol=protocol)
                assert exc.value.reason == NON_FINITE_REASON
        outside = gen.copy()
        outside[~mask] = np.nan  # never read
        assert masked_psnr(outside, ref, mask, protocol="authors") == masked_psnr(gen, ref, mask, protocol="authors")

    def test_paper_is_the_default(self, pair):
        gen, ref, mask = pair
        assert masked_psnr(gen, ref, mask, protocol="paper") == masked_psnr(gen, ref, mask)
        assert masked_mae(gen, ref, mask, protocol="paper") == masked_mae(gen, ref, mask)
        np.testing.assert_array_equal(
            match_histogram_masked(gray_ref(gen), gray_ref(ref), mask, protocol="paper"),
            match_histogram_masked(gray_ref(gen), gray_ref(ref), mask),
        )

    def test_unknown_protocol_names_the_config_key(self, pair):
        gen, ref, mask = pair
        for call in (
            lambda: masked_psnr(gen, ref, mask, protocol="author"),
            lambda: masked_mae(gen, ref, mask, protocol="Paper"),
            lambda: match_histogram_masked(gray_ref(gen), gray_ref(ref), mask, protocol=None),
            lambda: MaskedMAE(protocol="official"),
            lambda: check_protocol("text"),
        ):
            with pytest.raises(ValueError, match=r"metrics\.protocol.*'paper', 'authors'"):
                call()


@pytest.fixture(scope="module")
def plain_lpips(random_lpips):
    """``lpips.LPIPS`` as the authors call it (no spatial map), with the same weights."""
    model = copy.deepcopy(random_lpips.model)
    model.spatial = False
    return model


class TestMaskedLPIPSAuthors:
    @staticmethod
    def masked_input(img_hwc, mask):
        return to_bchw(np.asarray(img_hwc, np.float64) * mask[..., None])

    def test_equals_lpips_on_the_masked_rgb_pair(self, random_lpips, plain_lpips, pair):
        gen, ref, mask = pair
        with torch.no_grad():
            expected = plain_lpips(self.masked_input(gen, mask), self.masked_input(ref, mask), normalize=True).item()
        assert expected > 0
        assert random_lpips(gen, ref, mask, protocol="authors") == pytest.approx(expected, rel=1e-6)
        # RGB and unmatched: the paper's preprocessing options are not read
        assert random_lpips(gen, ref, mask, protocol="authors", grayscale=True, histogram_match=True) == pytest.approx(
            expected, rel=1e-6
        )
        # the spatial map is that of the masked pair; its whole-image mean is close to the value
        lp_map = random_lpips.spatial_map(gen, ref, mask, protocol="authors")
        assert lp_map.shape == (H, W)
        assert lp_map.double().mean().item() == pytest.approx(expected, rel=1e-3)
        assert random_lpips.model.spatial  # the module is left as it was

    def test_paper_is_unchanged_and_differs(self, random_lpips, pair):
        gen, ref, mask = pair
        paper = random_lpips(gen, ref, mask)
        assert random_lpips(gen, ref, mask, protocol="paper") == paper
        assert random_lpips(gen, ref, mask, protocol="authors") != pytest.approx(paper, rel=1e-2)

    def test_pixels_outside_the_mask_do_not_matter(self, random_lpips, pair):
        gen, ref, mask = pair
        rng = np.random.default_rng(9)
        gen2, ref2 = gen.copy(), ref.copy()
        gen2[~mask] = rng.random(((~mask).sum(), 3))
        ref2[~mask] = rng.random(((~mask).sum(), 3))
        assert random_lpips(gen2, ref2, mask, protocol="authors") == random_lpips(gen, ref, mask, protocol="authors")

    def test_degenerate_cases(self, random_lpips, pair):
        gen, ref, mask = pair
        assert random_lpips(ref, ref, mask, protocol="authors") == pytest.approx(0.0, abs=1e-7)
        with pytest.raises(MetricUnavailable) as exc:
            random_lpips(gen, ref, np.zeros((H, W), bool), protocol="authors")
        assert exc.value.reason == EMPTY_MASK_REASON
        bad = gen.copy()
        bad[0, 0] = np.nan
        for protocol in PROTOCOLS:
            with pytest.raises(MetricUnavailable) as exc:
                random_lpips(bad, ref, mask, protocol=protocol)
            assert exc.value.reason == NON_FINITE_REASON
        with pytest.raises(ValueError, match=r"metrics\.protocol"):
            random_lpips(gen, ref, mask, protocol="author")

    def test_score_all_passes_the_protocol(self, random_lpips, pair):
        gen, ref, mask = pair
        res = score_all(gen, ref, mask, "a glass sphere", lpips=random_lpips, protocol="authors")
        assert res["metrics"]["lpips"] == random_lpips(gen, ref, mask, protocol="authors")
        assert res["metrics"]["psnr"] == masked_psnr(gen, ref, mask, protocol="authors")
        assert res["metrics"]["mae"] == masked_mae(gen, ref, mask, protocol="authors")
        # missing weights: the metric is missing with its reason under both protocols
        why = MetricUnavailable("no LPIPS vgg16 backbone weights on this machine: set metrics.lpips_weights")
        for protocol in PROTOCOLS:
            res = score_all(gen, ref, mask, "a glass sphere", lpips=why, protocol=protocol)
            assert res["metrics"]["lpips"] is None and res["missing"]["lpips"] == why.reason
        with pytest.raises(ValueError, match=r"metrics\.protocol"):
            score_all(gen, ref, mask, "a glass sphere", protocol="author")
