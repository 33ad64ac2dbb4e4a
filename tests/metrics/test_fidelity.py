"""Masked fidelity metrics against independent references (numpy, scikit-image, torchmetrics)."""

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
        gen, ref, mask = pair
        # the paper's LPIPS: the spatial map of the two RGB images as they are, in [-1, 1]
        to_in = lambda a: torch.from_numpy(a).permute(2, 0, 1)[None].float() * 2 - 1  # noqa: E731
        with torch.no_grad():
            lp_map = random_lpips.model(to_in(gen), to_in(ref))[0, 0].double().numpy()
        assert lp_map.shape == (H, W) and (lp_map[mask] > 0).all()
        expected = lp_map[mask].mean()
        assert random_lpips(gen, ref, mask) == pytest.approx(expected, rel=1e-5)
        np.testing.assert_allclose(random_lpips.spatial_map(gen, ref, mask).numpy(), lp_map, rtol=1e-5, atol=1e-7)

    def test_gray_matched_option(self, random_lpips, pair):
        from skimage.exposure import match_histograms

        gen, ref, mask = pair
        # snell_bench's option: gray images, the generated one matched inside the mask (skimage), [-1, 1]
        g, r = gray_ref(gen), gray_ref(ref)
        g_matched = g.copy()
        g_matched[mask] = match_histograms(g[mask], r[mask])
        to_in = lambda a: torch.from_numpy(a).float()[None, None].expand(1, 3, H, W) * 2 - 1  # noqa: E731
        with torch.no_grad():
            lp_map = random_lpips.model(to_in(g_matched), to_in(r))[0, 0].double().numpy()
        ours = random_lpips(gen, ref, mask, grayscale=True, histogram_match=True)
        assert ours == pytest.approx(lp_map[mask].mean(), rel=1e-5)
        assert ours != pytest.approx(random_lpips(gen, ref, mask), rel=1e-3)

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
# Protocol selection (the authors' protocol itself: test_authors_protocol.py)
# ------------------------------------------------------------------------------------------


class TestProtocolSelection:
    def test_paper_is_the_default(self, pair, random_lpips):
        gen, ref, mask = pair
        assert masked_psnr(gen, ref, mask, protocol="paper") == masked_psnr(gen, ref, mask)
        assert masked_mae(gen, ref, mask, protocol="paper") == masked_mae(gen, ref, mask)
        np.testing.assert_array_equal(
            match_histogram_masked(gray_ref(gen), gray_ref(ref), mask, protocol="paper"),
            match_histogram_masked(gray_ref(gen), gray_ref(ref), mask),
        )
        assert random_lpips(gen, ref, mask, protocol="paper") == random_lpips(gen, ref, mask)

    def test_the_protocols_differ(self, pair, random_lpips):
        gen, ref, mask = pair
        for fn in (masked_psnr, masked_mae, random_lpips):
            assert fn(gen, ref, mask, protocol="authors") != pytest.approx(fn(gen, ref, mask), rel=1e-3)

    def test_unknown_protocol_names_the_config_key(self, pair, random_lpips):
        gen, ref, mask = pair
        for call in (
            lambda: masked_psnr(gen, ref, mask, protocol="author"),
            lambda: masked_mae(gen, ref, mask, protocol="Paper"),
            lambda: match_histogram_masked(gray_ref(gen), gray_ref(ref), mask, protocol=None),
            lambda: MaskedMAE(protocol="official"),
            lambda: check_protocol("text"),
            lambda: random_lpips(gen, ref, mask, protocol="author"),
            lambda: score_all(gen, ref, mask, "a glass sphere", protocol="author"),
        ):
            with pytest.raises(ValueError, match=r"metrics\.protocol.*'paper', 'authors'"):
                call()

    def test_non_finite_pixels_under_both_protocols(self, pair, random_lpips):
        gen, ref, mask = pair
        bad = gen.copy()
        bad[mask.nonzero()[0][0], mask.nonzero()[1][0]] = np.nan
        for protocol in PROTOCOLS:
            for fn in (masked_psnr, masked_mae, random_lpips):
                with pytest.raises(MetricUnavailable) as exc:
                    fn(bad, ref, mask, protocol=protocol)
                assert exc.value.reason == NON_FINITE_REASON
