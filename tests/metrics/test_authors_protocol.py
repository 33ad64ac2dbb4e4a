"""``metrics.protocol=authors``: the authors' evaluation (eval/masked_metrics.py) against values
computed by hand, and the paper protocol's LPIPS.

Every expected number below is derived in the comments from the authors' algorithm:

- images read as ``uint8 / 255``; a gray pixel ``(k, k, k)`` has gray ``k / 255`` (the weights sum
  to 1); the mask is ``uint8 / 255 >= 0.5``;
- each side's masked gray values ``v`` normalised ``u = (v - min) / (max - min + 1e-8)``; histc with
  256 bins on [0, 1] puts ``u`` in bin ``floor(256 u)`` (``u = 1``: bin 255); PDF ``= hist / N``, CDF its
  cumulative sum;
- a generated value reads the generated CDF at bin ``int(255 u)`` (255, not 256), its matched bin is
  the FIRST bin ``j`` minimising ``|cdf_ref[j] - cdf_gen|``, its value ``(j / 255) (max - min) + min``
  with the GENERATED values' min / max; the matched image is clamped to [0, 1];
- PSNR ``= 10 log10(1 / MSE)`` over the mask, ``inf`` where ``MSE <= 1e-8`` (``torch.isclose(MSE,
  0)``); MAE ``= mean |ref - matched|``.

The normaliser ``max - min + 1e-8`` (summed in float64, rounded to float32 by the division) equals
``max - min`` when ``min = 0`` and ``max >= 0.25``: ``max`` is then a float32 number and 1e-8 is below
half its float32 spacing (``>= 1.49e-8``). The test images keep ``min = 0`` and ``max >= 0.25``, so the
normalised maximum is exactly 1, except where a test says otherwise.
Values ``k / 255`` below are 8-bit levels; MSE and MAE are written in units of ``1 / 255``.
"""

import math
import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np
import pytest
import torch
from PIL import Image
from tolerances import EPS32, reordering_tolerance

from snell_bench.metrics import (
    EMPTY_MASK_REASON,
    NON_FINITE_REASON,
    MaskedLPIPS,
    MaskedPSNR,
    MetricUnavailable,
    authors_histogram_matching,
    authors_lpips,
    authors_lpips_box,
    authors_metrics,
    masked_lpips,
    masked_mae,
    masked_psnr,
    match_histogram_masked,
    metric_names,
    quantize_8bit,
    score_all,
    score_cell,
)
from snell_bench.utils.io import save_png


def gray_image(levels) -> np.ndarray:
    """An RGB float image whose pixel ``(y, x)`` is the gray ``(k, k, k) / 255`` of ``levels[y][x]``."""
    a = np.asarray(levels, np.float64) / 255.0
    return np.repeat(a[..., None], 3, axis=-1)


def psnr_db(sum_sq_levels: float, n: int) -> float:
    """``10 log10(1 / MSE)`` with ``MSE = sum_sq_levels / n / 255^2`` (differences in 8-bit levels)."""
    return 10.0 * math.log10(n * 255.0**2 / sum_sq_levels)


def psnr_tol(n: int) -> float:
    """float32 bound on a PSNR: every difference ``d`` of two values ``v <= 13 |d|`` (the tests'
    largest level over their smallest non-zero difference) carries at most 16 roundings of ``v``
    (gray: 3 products and 2 sums a side; the rescale: 1 product and 1 sum; the difference), its square
    ``2 * 16 * 13`` relative roundings; the mean of ``n`` squares ``n`` more; times ``10 / ln 10``."""
    return reordering_tolerance(32 * 13 + n, 10.0 / math.log(10.0))


def mae_tol(n: int) -> float:
    """float32 bound on a MAE of values in [0, 1]: 16 roundings a difference, ``n`` for the mean."""
    return reordering_tolerance(16 + n, 1.0)


def full(h, w):
    return np.ones((h, w), bool)


# ------------------------------------------------------------------------------------------
# PSNR / MAE
# ------------------------------------------------------------------------------------------


class TestAuthorsHandComputed:
    def test_2x2_and_paper_differs(self):
        # gen levels (0, 11, 33, 170), ref levels (0, 120, 60, 255), pixel by pixel, full mask.
        gen = gray_image([[0, 11], [33, 170]])
        ref = gray_image([[0, 120], [60, 255]])
        m = full(2, 2)
        # ref: min 0, max 1 -> u = k / 255; bins floor(256 k / 255) = k for k < 255: 0, 60, 120, 255.
        #   cdf_ref = 0.25 on [0, 59], 0.5 on [60, 119], 0.75 on [120, 254], 1 at 255.
        # gen: min 0, max 170 / 255 -> u = k / 170: 0, 0.0647, 0.1941, 1; 256 u = 0, 16.56, 49.69 -> bins
        #   0, 16, 49, 255; lookups int(255 u) = int(1.5 k) = 0, 16, 49, 255: CDFs 0.25, 0.5, 0.75, 1.
        # first argmin: 0.25 -> j 0, 0.5 -> j 60, 0.75 -> j 120, 1 -> j 255.
        # values (j / 255)(170 / 255): 0, 40, 80, 170 (levels); against ref (0, 120, 60, 255):
        #   differences 0, 80, 20, 85: sum of squares 0 + 6400 + 400 + 7225 = 14025; sum 185.
        ours = authors_metrics(gen, ref, m)
        assert ours.psnr == pytest.approx(psnr_db(14025, 4), abs=psnr_tol(4))  # 12.6824 dB
        assert ours.mae == pytest.approx(185 / 4 / 255, abs=mae_tol(4))  # 0.181373
        assert masked_psnr(gen, ref, m, protocol="authors") == ours.psnr
        assert masked_mae(gen, ref, m, protocol="authors") == ours.mae
        # paper: exact quantile matching of 4 distinct values onto 4: gen's ranks get ref's sorted values
        # (0, 60, 120, 255) against (0, 120, 60, 255): differences 0, 60, 60, 0: 7200; sum 120.
        assert masked_psnr(gen, ref, m) == pytest.approx(psnr_db(7200, 4), abs=1e-9)  # 15.5781 dB
        assert masked_mae(gen, ref, m) == pytest.approx(120 / 4 / 255, abs=1e-12)
        assert masked_psnr(gen, ref, m, protocol="paper") == masked_psnr(gen, ref, m)

    def test_lookup_reads_the_bin_below_identical_images_are_not_inf(self):
        # gen == ref, levels (0, 113, 170): min 0, max 170 / 255, u = k / 170 = 0, 0.6647, 1.
        # histc: 256 u = 170.16 -> bin 170; lookup int(255 u) = int(169.5) = 169, whose CDF 1/3 does not
        # count the pixel itself. cdf (both) = 1/3 on [0, 169], 2/3 on [170, 254], 1 at 255.
        # matched: 0 -> 1/3 -> j 0 -> 0; 113 -> 1/3 -> j 0 -> 0; 170 -> 1 -> j 255 -> 170.
        # differences 0, 113, 0: sum of squares 12769; sum 113.
        img = gray_image([[0, 113, 170]])
        m = full(1, 3)
        assert masked_psnr(img, img, m, protocol="authors") == pytest.approx(psnr_db(12769, 3), abs=psnr_tol(3))
        assert masked_mae(img, img, m, protocol="authors") == pytest.approx(113 / 3 / 255, abs=mae_tol(3))
        assert masked_psnr(img, img, m) == math.inf and masked_mae(img, img, m) == 0.0  # paper

    def test_tie_in_argmin_takes_the_first_bin(self):
        # gen (0, 11, 33, 170) as in the 2x2 test: CDF lookups 0.25, 0.5, 0.75, 1.
        # ref (0, 60, 60, 255): cdf_ref = 0.25 on [0, 59], 0.75 on [60, 254], 1 at 255.
        # 0.5 is 0.25 away from both 0.25 and 0.75 (exact in float32): the first such bin is 0 -> 0.
        # matched 0, 0, 40, 170 against 0, 60, 60, 255: differences 0, 60, 20, 85: 11225; sum 165.
        gen = gray_image([[0, 11], [33, 170]])
        ref = gray_image([[0, 60], [60, 255]])
        ours = authors_metrics(gen, ref, full(2, 2))
        assert ours.psnr == pytest.approx(psnr_db(11225, 4), abs=psnr_tol(4))  # 13.6495 dB
        assert ours.mae == pytest.approx(165 / 4 / 255, abs=mae_tol(4))

    def test_constant_generated_image_maps_to_itself(self):
        # gen constant 100: u = 0 / (0 + 1e-8) = 0 everywhere; its CDF is 1 from bin 0; the matched bin j
        # is where the ref CDF reaches 1, and the value j / 255 * 0 + min = 100: the unmatched pair.
        # against ref (0, 60, 120, 255): differences 100, 40, 20, 155: 36025; sum 315.
        gen = gray_image([[100, 100], [100, 100]])
        ref = gray_image([[0, 60], [120, 255]])
        ours = authors_metrics(gen, ref, full(2, 2))
        assert ours.psnr == pytest.approx(psnr_db(36025, 4), abs=psnr_tol(4))  # 8.5854 dB
        assert ours.mae == pytest.approx(315 / 4 / 255, abs=mae_tol(4))
        assert ours == authors_metrics(gen, ref, full(2, 2), histogram_match=False)

    def test_constant_reference_maps_everything_to_the_generated_minimum(self):
        # ref constant 200: its CDF is 1 in every bin, so every |1 - cdf_gen| ties across all bins and
        # the first bin 0 wins: every generated value becomes 0 * range + min = 0.
        # against 200 everywhere: sum of squares 4 * 200^2; sum 800.
        gen = gray_image([[0, 11], [33, 170]])
        ref = gray_image([[200, 200], [200, 200]])
        ours = authors_metrics(gen, ref, full(2, 2))
        assert ours.psnr == pytest.approx(psnr_db(4 * 200**2, 4), abs=psnr_tol(4))  # 2.1102 dB
        assert ours.mae == pytest.approx(200 / 255, abs=mae_tol(4))

    def test_small_range_maps_the_maximum_down(self):
        # gen == ref, levels (1, 3): max - min = 2 / 255 = 0.00784; in float32 1e-8 is more than half a
        # spacing there (4.7e-10), so the normaliser is above max - min and the maximum normalises to
        # u = 1 - 1.3e-6: histc bin 255, lookup int(254.9997) = 254, whose CDF is 0.5 -> j 0 -> the
        # minimum. matched (1, 1) against (1, 3): difference 2 on one pixel of 2: sum of squares 4; sum 2.
        img = gray_image([[1, 3]])
        ours = authors_metrics(img, img, full(1, 2))
        assert ours.psnr == pytest.approx(psnr_db(4, 2), abs=psnr_tol(2))  # 45.1 dB
        assert ours.mae == pytest.approx(1 / 255, abs=mae_tol(2))

    def test_isclose_gives_inf(self):
        # gen == ref, levels (65, 194): min > 0, but float32(max - min + 1e-8) = float32(max - min) here
        # (0.506, 1e-8 below half its spacing, and not at a rounding boundary): bins 0 and 255, their own;
        # the maximum comes back as float32(float32(max - min) * 1 + min), one float32 spacing (2^-24 in
        # [0.5, 1)) above 194 / 255. MSE = 2^-48 / 2 > 0 (10 log10(1 / MSE) would be 147.5 dB) but
        # torch.isclose(MSE, 0) (|MSE| <= 1e-8): PSNR inf. MAE = 2^-24 / 2 = 2^-25.
        lo, hi = np.float32(65) / np.float32(255), np.float32(194) / np.float32(255)
        w = torch.tensor([0.299, 0.587, 0.114])
        for k, v in ((65, lo), (194, hi)):  # for these levels the float32 gray of (k, k, k) is k / 255
            assert (torch.full((3,), float(k)) / 255 * w).sum().item() == v
        span = np.float64(hi) - np.float64(lo)
        assert np.float32(span + 1e-8) == np.float32(span)  # the normaliser: the maximum normalises to 1
        assert np.float32(span) + lo == np.nextafter(hi, np.float32(1))
        img = gray_image([[65, 194]])
        ours = authors_metrics(img, img, full(1, 2))
        assert ours.psnr == math.inf
        assert ours.mae == 2.0**-25
        # unmatched: 5x5 identical images but one blue level: gray difference 0.114 / 255 = 4.47e-4,
        # MSE = 2.0e-7 / 25 = 8.0e-9 <= 1e-8: inf; the paper's PSNR is 10 log10(25 / d^2) = 81.0 dB.
        a = gray_image(np.full((5, 5), 128))
        b = a.copy()
        b[2, 2, 2] = 129 / 255
        d = 0.114 / 255
        assert authors_metrics(b, a, full(5, 5), histogram_match=False).psnr == math.inf
        assert masked_psnr(b, a, full(5, 5), histogram_match=False) == pytest.approx(10 * math.log10(25 / d**2))

    def test_clamp_of_the_matched_image(self):
        # the matching on gray images (not from 8-bit RGB): gen (0.2, 0.5, 1.2), ref (0, 0.5, 1), full.
        # gen: min 0.2, max 1.2, u = 0, 0.3, 1: bins 0, 76 (76.8), 255; lookups 0, 76 (76.5), 255:
        #   CDFs 1/3, 2/3, 1. ref: u = 0, 0.5, 1: bins 0, 128, 255: cdf 1/3 on [0, 127], 2/3 on
        #   [128, 254], 1 at 255. matched bins 0, 128, 255: values 0.2, 128 / 255 + 0.2, 1.2 -> clamped
        #   to 1; the pixel outside the mask (1.5) is clamped too.
        gen = np.array([[0.2, 0.5, 1.2, 1.5]])
        ref = np.array([[0.0, 0.5, 1.0, 0.3]])
        mask = np.array([[True, True, True, False]])
        out = match_histogram_masked(gen, ref, mask, protocol="authors")
        np.testing.assert_allclose(out, [[0.2, 128 / 255 + 0.2, 1.0, 1.0]], atol=4 * EPS32)
        t = match_histogram_masked(torch.from_numpy(gen)[None, None], torch.from_numpy(ref), mask, protocol="authors")
        assert t.shape == (1, 1, 1, 4) and t.dtype == torch.float64
        np.testing.assert_array_equal(t.numpy()[0, 0], out)
        # on 8-bit RGB triplets the clamp never changes a value: a gray is at most 1 (white is exactly 1
        # in float32) and the rescale of the top bin, float32(max - min) + min, never exceeds 1.

    def test_matching_function_on_values(self):
        # the 2x2 test's values, straight: gen (0, 11, 33, 170) / 255 onto ref (0, 120, 60, 255) / 255.
        src = torch.tensor([0, 11, 33, 170], dtype=torch.float32) / 255.0
        tmpl = torch.tensor([0, 120, 60, 255], dtype=torch.float32) / 255.0
        out = authors_histogram_matching(src, tmpl)
        assert out.dtype == torch.float32
        np.testing.assert_allclose(out.numpy(), np.array([0, 40, 80, 170]) / 255, atol=4 * EPS32)


class TestAuthorsInputs:
    def test_float_images_are_quantised_like_save_png(self):
        # rint(255 x), half to even, then clip: 0.5 -> 0, 1.5 -> 2, 2.5 -> 2, 3.49 -> 3, -0.1 -> 0, 1.3 -> 255
        x = np.array([[0.5, 1.5, 2.5, 3.49]]) / 255
        np.testing.assert_array_equal(quantize_8bit(x), [[0, 2, 2, 3]])
        np.testing.assert_array_equal(quantize_8bit(np.array([-0.1, 1.3])), [0, 255])
        # a float image scores like its 8-bit levels written by hand
        gen = gray_image([[0, 11], [33, 170]]) + np.array([[[0.3], [-0.4]], [[0.45], [0.2]]]) / 255
        ref = gray_image([[0, 120], [60, 255]]) - 0.2 / 255
        gen8 = np.repeat(np.array([[0, 11], [33, 170]], np.uint8)[..., None], 3, -1)
        ref8 = np.repeat(np.array([[0, 120], [60, 255]], np.uint8)[..., None], 3, -1)
        assert authors_metrics(gen, ref, full(2, 2)) == authors_metrics(gen8, ref8, full(2, 2))
        assert authors_metrics(gen, ref, full(2, 2)).psnr == pytest.approx(psnr_db(14025, 4), abs=psnr_tol(4))
        # torch (1, 3, H, W) inputs are the same images
        tg = torch.from_numpy(gen).permute(2, 0, 1)[None].float()
        assert authors_metrics(tg, ref, full(2, 2)) == authors_metrics(gen8, ref8, full(2, 2))

    def test_in_memory_equals_the_png_files(self, tmp_path):
        rng = np.random.default_rng(3)
        gen, ref = rng.random((20, 24, 3)), rng.random((20, 24, 3)) ** 2
        mask = rng.random((20, 24)) < 0.4
        save_png(tmp_path / "g.png", gen)
        save_png(tmp_path / "r.png", ref)
        save_png(tmp_path / "m.png", mask.astype(np.float32))
        files = [np.asarray(Image.open(tmp_path / f"{n}.png")) for n in ("g", "r", "m")]
        assert authors_metrics(gen, ref, mask) == authors_metrics(files[0], files[1], files[2])

    def test_mask_is_thresholded_at_half_after_8_bits(self):
        # gen (0, 11, 33, 170), ref (0, 120, 60, 255) plus a fifth pixel (gen 255, ref 0) whose mask
        # value decides. Mask 0.5: rint(127.5) = 128 (half to even), 128 / 255 >= 0.5: scored by the
        # authors (the paper's rule for float masks, > 0.5, leaves it out). 0.498: 127 -> not scored.
        gen = gray_image([[0, 11, 33, 170, 255]])
        ref = gray_image([[0, 120, 60, 255, 0]])
        base = authors_metrics(gen[:, :4], ref[:, :4], full(1, 4))
        mask_off = np.array([[1.0, 1.0, 1.0, 1.0, 0.498]])
        assert authors_metrics(gen, ref, mask_off) == base
        assert authors_metrics(gen, ref, mask_off > 0.5) == base
        with_it = authors_metrics(gen, ref, np.array([[1.0, 1.0, 1.0, 1.0, 0.5]]))
        assert with_it != base
        assert authors_metrics(gen, ref, np.array([[255, 255, 255, 255, 128]], np.uint8)) == with_it
        assert authors_metrics(gen, ref, np.array([[255, 255, 255, 255, 127]], np.uint8)) == base

    def test_errors(self):
        gen, ref = gray_image([[0, 11]]), gray_image([[0, 120]])
        for mask in (np.zeros((1, 2), bool), np.array([[0.4, 0.49]])):
            with pytest.raises(MetricUnavailable) as exc:
                authors_metrics(gen, ref, mask)
            assert exc.value.reason == EMPTY_MASK_REASON
        bad = gen.copy()
        bad[0, 1, 0] = np.nan
        with pytest.raises(MetricUnavailable) as exc:
            masked_psnr(bad, ref, full(1, 2), protocol="authors")
        assert exc.value.reason == NON_FINITE_REASON
        with pytest.raises(ValueError, match="grayscale=True"):
            authors_metrics(gen, ref, full(1, 2), grayscale=False)
        with pytest.raises(ValueError, match="method"):
            masked_psnr(gen, ref, full(1, 2), method="rank", protocol="authors")
        with pytest.raises(ValueError, match="size"):
            authors_metrics(gen, gray_image([[0, 1, 2]]), full(1, 2))

    def test_rgb_psnr_unmatched(self):
        # their psnr_rgb: all three channels over the mask. gen (10, 20, 30), ref (10, 20, 70) on one
        # pixel, (0, 0, 0) vs (0, 0, 0) on another: squares 0, 0, 1600, 0, 0, 0 over 6 values.
        gen = np.array([[[10, 20, 30], [0, 0, 0]]]) / 255
        ref = np.array([[[10, 20, 70], [0, 0, 0]]]) / 255
        ours = authors_metrics(gen, ref, full(1, 2), grayscale=False, histogram_match=False)
        assert ours.psnr == pytest.approx(psnr_db(1600, 6), abs=psnr_tol(6))
        assert ours.mae == pytest.approx(40 / 6 / 255, abs=mae_tol(6))

    def test_class_form_routes_the_protocol(self):
        gen = gray_image([[0, 11], [33, 170]])
        ref = gray_image([[0, 120], [60, 255]])
        metric = MaskedPSNR(protocol="authors")
        metric.update(gen, ref, full(2, 2))
        assert metric.compute() == pytest.approx(psnr_db(14025, 4), abs=psnr_tol(4))


# ------------------------------------------------------------------------------------------
# LPIPS: masking, averaging and cropping with a stub network
# ------------------------------------------------------------------------------------------


class StubNet:
    """A network whose map is hand-computable: at each pixel the channel mean of ``(in0 - in1)^2``
    plus the same at its right neighbour (0 past the right border); ``spatial=False``: the map's
    mean. It records its inputs."""

    def __init__(self):
        self.calls = []

    def __call__(self, in0, in1, spatial):
        self.calls.append((in0.clone(), in1.clone(), spatial))
        q = ((in0 - in1) ** 2).mean(dim=1, keepdim=True)
        lp = q + torch.nn.functional.pad(q[..., 1:], (0, 1))
        return lp if spatial else lp.mean().reshape(1, 1, 1, 1)


class StubLPIPS(MaskedLPIPS):
    """:class:`MaskedLPIPS` with :class:`StubNet` in place of VGG."""

    def __init__(self):
        torch.nn.Module.__init__(self)
        self.stub = StubNet()

    def network(self, in0, in1, spatial):
        return self.stub(in0, in1, spatial)


def lpips_triplet():
    """4x5: gen 153 everywhere; ref 102 everywhere except 51 at (2, 2); mask (1, 1), (1, 3), (2, 2).

    Differences gen - ref: 51 (0.2) everywhere, 102 (0.4) at (2, 2); in [-1, 1]: 0.4 and 0.8, squared
    q = 0.16 and 0.64."""
    gen = gray_image(np.full((4, 5), 153))
    ref = gray_image(np.full((4, 5), 102))
    ref[2, 2] = 51 / 255
    mask = np.zeros((4, 5), bool)
    mask[1, 1] = mask[1, 3] = mask[2, 2] = True
    return gen, ref, mask


class TestLPIPSStub:
    def test_paper_full_rgb_map_averaged_over_the_mask(self):
        # unmasked inputs: the map at (1, 1) = q(1, 1) + q(1, 2) = 0.32; (1, 3) = 0.16 + 0.16 = 0.32;
        # (2, 2) = 0.64 + 0.16 = 0.80; mean 1.44 / 3 = 0.48.
        gen, ref, mask = lpips_triplet()
        net = StubNet()
        assert masked_lpips(net, gen, ref, mask) == pytest.approx(0.48, abs=1e-6)
        in0, in1, spatial = net.calls[0]
        assert spatial and in0.shape == (1, 3, 4, 5)
        torch.testing.assert_close(in0, torch.full((1, 3, 4, 5), 2 * 0.6 - 1))

    def test_authors_masked_map_averaged_over_the_mask(self):
        # inputs masked (-1 outside in both): q = 0 outside the mask. (1, 1) = 0.16 + 0; (1, 3) =
        # 0.16 + 0; (2, 2) = 0.64 + 0; mean 0.96 / 3 = 0.32 (not the whole-frame mean 0.96 / 20).
        gen, ref, mask = lpips_triplet()
        net = StubNet()
        assert authors_lpips(net, gen, ref, mask) == pytest.approx(0.32, abs=1e-6)
        in0, in1, spatial = net.calls[0]
        expected = torch.full((1, 3, 4, 5), -1.0)
        expected[..., torch.from_numpy(mask)] = 2 * 0.6 - 1
        assert spatial
        torch.testing.assert_close(in0, expected)

    def test_authors_box_crop_in_0_1_without_normalize(self):
        # box rows 1-2, cols 1-3 (2 x 3); the crop back in [0, 1]: gen 0.6 / ref 0.4 (0.2 at the crop's
        # (1, 1)) at mask pixels, 0 elsewhere; passed as is (no x 2 - 1). q' = 0.04, 0.04, 0.16 at crop
        # (0, 0), (0, 2), (1, 1). Map: row 0: 0.04 + 0, 0 + 0.04, 0.04 + 0 (border); row 1: 0 + 0.16,
        # 0.16 + 0, 0: sum 0.44, mean 0.44 / 6.
        gen, ref, mask = lpips_triplet()
        net = StubNet()
        assert authors_lpips_box(net, gen, ref, mask, "unit") == pytest.approx(0.44 / 6, abs=1e-6)
        in0, in1, spatial = net.calls[0]
        assert not spatial
        torch.testing.assert_close(in0[0, 0], torch.tensor([[0.6, 0.0, 0.6], [0.0, 0.6, 0.0]]))
        torch.testing.assert_close(in1[0, 0], torch.tensor([[0.4, 0.0, 0.4], [0.0, 0.2, 0.0]]))

    def test_authors_box_crop_in_minus_1_1_as_eval_py(self):
        # the same crop left in [-1, 1]: differences doubled, q' four times the unit crop's: 1.76 / 6
        gen, ref, mask = lpips_triplet()
        net = StubNet()
        assert authors_lpips_box(net, gen, ref, mask) == pytest.approx(1.76 / 6, abs=1e-6)
        in0, in1, _ = net.calls[0]
        torch.testing.assert_close(in0[0, 0], torch.tensor([[0.2, -1.0, 0.2], [-1.0, 0.2, -1.0]]))
        with pytest.raises(ValueError, match="metrics.lpips_box_range='half'.*signed.*unit"):
            authors_lpips_box(net, gen, ref, mask, "half")

    def test_score_all_routes_the_protocol(self):
        gen, ref, mask = lpips_triplet()
        lp = StubLPIPS()
        paper = score_all(gen, ref, mask, "a glass sphere", lpips=lp)
        authors = score_all(gen, ref, mask, "a glass sphere", lpips=lp, protocol="authors")
        assert tuple(paper["metrics"]) == metric_names("paper") and "lpips_box" not in paper["missing"]
        assert tuple(authors["metrics"]) == ("psnr", "mae", "lpips", "lpips_box", "clip", "image_reward")
        assert paper["metrics"]["lpips"] == pytest.approx(0.48, abs=1e-6)
        assert authors["metrics"]["lpips"] == pytest.approx(0.32, abs=1e-6)
        assert authors["metrics"]["lpips_box"] == pytest.approx(1.76 / 6, abs=1e-6)
        cell = score_cell(gen, ref, mask, "a glass sphere", {"lpips": lp}, protocol="authors")
        assert cell["metrics"]["lpips_box"] == authors["metrics"]["lpips_box"]
        unit = score_cell(gen, ref, mask, "a", {"lpips": lp}, protocol="authors", lpips_box_range="unit")
        assert unit["metrics"]["lpips_box"] == pytest.approx(0.44 / 6, abs=1e-6)

    def test_missing_weights_make_both_lpips_missing(self):
        gen, ref, mask = lpips_triplet()
        why = MetricUnavailable("no LPIPS vgg16 backbone weights on this machine: set metrics.lpips_weights")
        res = score_cell(gen, ref, mask, "a glass sphere", {"lpips": why}, protocol="authors")
        for name in ("lpips", "lpips_box"):
            assert res["metrics"][name] is None and res["missing"][name] == why.reason
        no_ref = score_cell(gen, None, None, "a glass sphere", {}, protocol="authors", reference_reason="none")
        assert no_ref["metrics"]["lpips_box"] is None and no_ref["missing"]["lpips_box"] == "none"
        paper = score_cell(gen, ref, mask, "a glass sphere", {"lpips": why})
        assert "lpips_box" not in paper["metrics"] and "lpips_box" not in paper["missing"]

    def test_options_of_the_other_protocol_are_errors(self):
        gen, ref, mask = lpips_triplet()
        lp = StubLPIPS()
        with pytest.raises(ValueError, match="metrics.protocol=authors"):
            lp(gen, ref, mask, box=True)
        with pytest.raises(ValueError, match="protocol='paper'"):
            lp(gen, ref, mask, protocol="authors", histogram_match=True)
        with pytest.raises(MetricUnavailable) as exc:
            lp(gen, ref, np.zeros_like(mask), protocol="authors", box=True)
        assert exc.value.reason == EMPTY_MASK_REASON


# ------------------------------------------------------------------------------------------
# LPIPS with the real network code (random backbone): the same computation written directly
# ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def random_lpips():
    return MaskedLPIPS(allow_random_backbone=True)


def test_real_network_variants(random_lpips):
    rng = np.random.default_rng(11)
    h, w = 40, 48
    ref = rng.integers(0, 256, (h, w, 3)) / 255
    gen = np.clip(ref + rng.integers(-30, 31, (h, w, 3)) / 255, 0, 1)
    mask = np.zeros((h, w), bool)
    mask[8:30, 10:40] = rng.random((22, 30)) < 0.7
    model = random_lpips.model
    t = lambda a: torch.from_numpy(a).permute(2, 0, 1)[None].float()  # noqa: E731
    m = torch.from_numpy(mask)
    with torch.no_grad():
        gin, rin = t(gen * mask[..., None]) * 2 - 1, t(ref * mask[..., None]) * 2 - 1
        lp_map = model(gin, rin)[0, 0]
        model.spatial = False
        ys, xs = np.nonzero(mask)
        box = np.s_[..., ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]
        box_value = model(gin[box], rin[box]).item()
        box_unit = model((gin[box] + 1) / 2, (rin[box] + 1) / 2).item()
        model.spatial = True
        full_map = model(t(gen) * 2 - 1, t(ref) * 2 - 1)[0, 0]
    # a mean of up to h w float32 values: reordering bound
    assert random_lpips(gen, ref, mask, protocol="authors") == pytest.approx(
        lp_map[m].mean().item(), abs=reordering_tolerance(h * w, lp_map)
    )
    assert random_lpips(gen, ref, mask, protocol="authors", box=True) == pytest.approx(
        box_value, abs=reordering_tolerance(h * w, box_value)
    )
    assert random_lpips(gen, ref, mask, protocol="authors", box=True, box_range="unit") == pytest.approx(
        box_unit, abs=reordering_tolerance(h * w, box_unit)
    )
    assert random_lpips(gen, ref, mask) == pytest.approx(
        full_map[m].double().mean().item(), abs=reordering_tolerance(h * w, full_map)
    )
    assert random_lpips.spatial_map(gen, ref, mask).shape == (h, w)
    assert model.spatial
    small = np.zeros((h, w), bool)
    small[5:10, 5:30] = True  # a 5-pixel-high box: below VGG's 16
    with pytest.raises(MetricUnavailable, match="16 pixels"):
        random_lpips(gen, ref, small, protocol="authors", box=True)


def test_the_box_ranges_against_lpips_normalize():
    """lpips documents its inputs as [-1, 1], or [0, 1] with ``normalize=True`` (which maps them
    with ``2 x - 1``): the ``signed`` box (eval/eval.py) is LPIPS of the [0, 1] crop with
    ``normalize=True``; the ``unit`` box (eval/masked_metrics.py) is the [0, 1] crop without it,
    another number."""
    import lpips

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        model = lpips.LPIPS(net="vgg", pnet_rand=True, verbose=False).eval()
    rng = np.random.default_rng(3)
    h, w = 36, 40
    ref = rng.integers(0, 256, (h, w, 3)) / 255
    gen = np.clip(ref + rng.integers(-40, 41, (h, w, 3)) / 255, 0, 1)
    mask = np.zeros((h, w), bool)
    mask[6:30, 4:36] = rng.random((24, 32)) < 0.8
    ys, xs = np.nonzero(mask)
    crop = np.s_[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a[crop] * mask[crop][..., None])).permute(2, 0, 1)[None]  # noqa: E731
    g01, r01 = t(gen).float(), t(ref).float()

    def net(in0, in1, spatial):
        assert not spatial
        return model(in0, in1)

    with torch.no_grad():
        normalized = model(g01, r01, normalize=True).item()
        as_given = model(g01, r01).item()
        signed = authors_lpips_box(net, gen, ref, mask, "signed")
        unit = authors_lpips_box(net, gen, ref, mask, "unit")
    # the same network on inputs equal up to one float32 rounding (2 x - 1 here and there): the
    # reordering bound of the network's longest reduction (3 x 3 x 512 VGG taps)
    assert signed == pytest.approx(normalized, abs=reordering_tolerance(9 * 512, normalized))
    assert unit == pytest.approx(as_given, abs=reordering_tolerance(9 * 512, as_given))
    assert abs(unit - normalized) > 100 * reordering_tolerance(9 * 512, normalized)
