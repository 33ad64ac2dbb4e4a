"""Relighting by selection: candidate seeds, masked PSNR, the choice and its JSON record."""

import json
import math

import numpy as np
import pytest
import torch

from snell_bench.relight import IDENTICAL_NOTE, Relighter, RelightResult, candidate_seeds, masked_psnr, relight

H, W = 12, 16


def rand_image(seed=0):
    return torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(seed))


def disk_mask():
    ys, xs = np.mgrid[0:H, 0:W]
    return (ys - 6) ** 2 + (xs - 8) ** 2 <= 16


class FakeRelighter:
    """Adds a known offset per seed inside ``region`` (0 offset: the input itself)."""

    name = "fake"

    def __init__(self, offsets, region):
        self.offsets = offsets
        self.region = torch.from_numpy(region)
        self.calls = []

    def describe(self):
        return "adds a constant per seed"

    def relight(self, image, *, prompt, seed, scene=None, obj=None, warps=None):
        self.calls.append({"seed": seed, "prompt": prompt, "scene": scene, "obj": obj, "warps": warps})
        out = image.clone()
        out[:, :, self.region] = (out[:, :, self.region] + self.offsets[seed]).clamp(0, 1)
        return out


class TestSeeds:
    def test_distinct_deterministic_prefix(self):
        s = candidate_seeds(7, 20)
        assert len(s) == 20 and len(set(s)) == 20
        assert all(isinstance(x, int) and 0 <= x < 2**32 for x in s)
        assert s == candidate_seeds(7, 20)
        assert candidate_seeds(7, 3) == s[:3]

    def test_depends_on_the_cell_seed(self):
        assert set(candidate_seeds(0, 5)).isdisjoint(candidate_seeds(1, 5))

    def test_derivation(self):
        expected = [int(np.random.SeedSequence([3, k]).generate_state(1, np.uint32)[0]) for k in range(4)]
        assert candidate_seeds(3, 4) == expected

    @pytest.mark.parametrize("seed,n", [(-1, 3), (0, 0), (0, 1.5)])
    def test_invalid(self, seed, n):
        with pytest.raises(ValueError):
            candidate_seeds(seed, n)


class TestMaskedPSNR:
    def test_against_numpy(self):
        a, b = rand_image(0), rand_image(1)
        m = disk_mask()
        an, bn = a[0].numpy().astype(np.float64), b[0].numpy().astype(np.float64)
        mse = np.mean((an[:, m] - bn[:, m]) ** 2)
        assert masked_psnr(a, b, m) == pytest.approx(10 * np.log10(1 / mse), rel=1e-12)
        assert masked_psnr(a, b, torch.from_numpy(m)) == masked_psnr(a, b, m)
        assert masked_psnr(a.numpy(), b.numpy(), m) == masked_psnr(a, b, m)

    def test_only_the_mask_counts(self):
        a = rand_image(0)
        b = a.clone()
        m = disk_mask()
        b[:, :, ~torch.from_numpy(m)] = 0.0
        assert masked_psnr(a, b, m) == math.inf
        b[:, 1, torch.from_numpy(m)] += 0.1
        # one channel of three off by 0.1: MSE = 0.01 / 3
        assert masked_psnr(a, b, m) == pytest.approx(10 * np.log10(300), rel=1e-6)

    def test_empty_mask(self):
        with pytest.raises(ValueError, match="mask is empty"):
            masked_psnr(rand_image(0), rand_image(1), np.zeros((H, W), bool))

    def test_bad_inputs(self):
        a = rand_image(0)
        with pytest.raises(ValueError, match=r"\(1, 3, H, W\)"):
            masked_psnr(a, a[..., :-1], disk_mask())
        with pytest.raises(ValueError, match="bool"):
            masked_psnr(a, a, disk_mask().astype(np.uint8))
        b = a.clone()
        b[0, 0, 6, 8] = float("nan")
        with pytest.raises(ValueError, match="non-finite"):
            masked_psnr(a, b, disk_mask())


class TestRelight:
    def test_picks_the_max_and_records_all(self):
        image = rand_image(3) * 0.5
        m = disk_mask()
        seeds = candidate_seeds(0, 4)
        offsets = dict(zip(seeds, [0.2, 0.05, 0.1, 0.3]))
        fake = FakeRelighter(offsets, m)
        assert isinstance(fake, Relighter)
        res = relight(image, relighter=fake, prompt="p", seeds=seeds, object_mask=m, scene="S", obj="O", warps="X")
        assert isinstance(res, RelightResult)
        assert [c["seed"] for c in res.candidates] == seeds
        assert res.chosen == 1 and res.seed == seeds[1]
        expected = [masked_psnr(fake.relight(image, prompt="p", seed=s), image, m) for s in seeds]
        assert [c["psnr_db"] for c in res.candidates] == pytest.approx(expected)
        assert res.psnr_db == max(expected)
        assert torch.equal(res.image, fake.relight(image, prompt="p", seed=seeds[1]))
        call = fake.calls[0]
        assert (call["prompt"], call["scene"], call["obj"], call["warps"]) == ("p", "S", "O", "X")
        assert res.relighter == "fake" and res.description == "adds a constant per seed" and res.prompt == "p"
        assert res.images is None

    def test_tie_keeps_the_first_and_keep_images(self):
        image = rand_image(4) * 0.5
        m = disk_mask()
        seeds = [11, 12, 13]
        fake = FakeRelighter({11: 0.2, 12: 0.1, 13: 0.1}, m)
        res = relight(image, relighter=fake, prompt="p", seeds=seeds, object_mask=m, keep_images=True)
        assert res.chosen == 1
        assert len(res.images) == 3 and torch.equal(res.images[1], res.image)

    def test_the_input_is_not_modified(self):
        image = rand_image(5) * 0.5
        before = image.clone()

        class Inplace(FakeRelighter):
            def relight(self, image, **kw):
                image += 0.1
                return image

        relight(image, relighter=Inplace({}, disk_mask()), prompt="p", seeds=[1], object_mask=disk_mask())
        assert torch.equal(image, before)

    def test_infinite_psnr_in_json(self):
        image = rand_image(5) * 0.5
        m = disk_mask()
        fake = FakeRelighter({1: 0.1, 2: 0.0, 3: 0.0}, m)
        res = relight(image, relighter=fake, prompt="p", seeds=[1, 2, 3], object_mask=m)
        assert res.chosen == 1 and res.psnr_db == math.inf
        rec = res.to_json()
        text = json.dumps(rec, allow_nan=False)  # raises on inf / NaN
        back = json.loads(text)
        assert back["chosen"] == 1 and back["seed"] == 2 and back["psnr_db"] is None
        c0, c1, c2 = back["candidates"]
        assert isinstance(c0["psnr_db"], float) and "note" not in c0
        assert c1["psnr_db"] is None and c1["note"] == IDENTICAL_NOTE
        assert c2["psnr_db"] is None and c2["note"] == IDENTICAL_NOTE
        assert all(isinstance(c["seconds"], float) for c in back["candidates"])
        assert back["relighter"] == "fake" and back["prompt"] == "p"

    def test_numpy_floats_become_floats(self):
        res = RelightResult(
            image=rand_image(0), candidates=[{"seed": np.int64(3), "psnr_db": np.float32(12.5)}], chosen=0
        )
        rec = res.to_json()
        assert type(rec["candidates"][0]["psnr_db"]) is float and type(rec["seed"]) is int
        json.dumps(rec, allow_nan=False)

    def test_errors(self):
        image = rand_image(0)
        m = disk_mask()
        fake = FakeRelighter({1: 0.1}, m)
        with pytest.raises(ValueError, match="at least one seed"):
            relight(image, relighter=fake, prompt="p", seeds=[], object_mask=m)
        with pytest.raises(ValueError, match="object mask is empty"):
            relight(image, relighter=fake, prompt="p", seeds=[1], object_mask=np.zeros((H, W), bool))
        with pytest.raises(ValueError, match="object_mask"):
            relight(image, relighter=fake, prompt="p", seeds=[1], object_mask=m[:-1])

        class Cropping(FakeRelighter):
            def relight(self, image, **kw):
                return image[..., :-2]

        with pytest.raises(ValueError, match="returned"):
            relight(image, relighter=Cropping({}, m), prompt="p", seeds=[1], object_mask=m)
