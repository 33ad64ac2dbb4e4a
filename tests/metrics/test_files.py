"""The files an evaluation reads: the JPEG round trips of the authors' main.jpg, blender.jpg and
blender_mask.jpg against PIL's own encoder and decoder writing real files, the mask's threshold on
hand-made masks, and score_cell scoring those files."""

import numpy as np
import pytest
from PIL import Image, JpegImagePlugin

from snell_bench.metrics import score_cell
from snell_bench.metrics.files import (
    GENERATED_QUALITY,
    MASK_QUALITY,
    REFERENCE_QUALITY,
    evaluated_files,
    jpeg_mask_round_trip,
    jpeg_round_trip,
)
from snell_bench.metrics.functional import quantize_8bit


def pil_file_round_trip(pixels: np.ndarray, path, **save_kwargs) -> np.ndarray:
    """What the authors' code does: ``Image.save(path.jpg, ...)``, then ``Image.open(path)``."""
    Image.fromarray(pixels).save(path, **save_kwargs)
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB" if pixels.ndim == 3 else "L"))


@pytest.fixture
def image():
    rng = np.random.default_rng(0)
    base = rng.random((40, 56, 3))
    return np.clip(base + 0.3 * np.sin(np.arange(56) / 3.0)[None, :, None], 0, 1).astype(np.float32)


@pytest.mark.parametrize("quality", [GENERATED_QUALITY, REFERENCE_QUALITY])
def test_the_round_trip_is_pils_own_file(image, quality, tmp_path):
    # main.jpg: save(path) with no options (quality 75); blender.jpg: save(path, quality=95)
    kwargs = {} if quality == 75 else {"quality": 95}
    expected = pil_file_round_trip(quantize_8bit(image), tmp_path / "x.jpg", **kwargs)
    got = jpeg_round_trip(image, quality)
    assert got.dtype == np.float32 and got.shape == image.shape
    np.testing.assert_array_equal(got, expected.astype(np.float32) / np.float32(255))
    assert not np.array_equal(expected, quantize_8bit(image))  # JPEG is lossy: the test sees it
    with Image.open(tmp_path / "x.jpg") as im:
        assert JpegImagePlugin.get_sampling(im) == 2  # PIL's default chroma subsampling: 4:2:0


def test_the_qualities_are_the_authors():
    assert (GENERATED_QUALITY, REFERENCE_QUALITY, MASK_QUALITY) == (75, 95, 75)


def test_the_mask_round_trip_thresholds_as_the_authors_read_it(tmp_path):
    mask = np.zeros((48, 64), bool)
    mask[8:24, 16:40] = True  # blocks aligned to JPEG's 8 x 8: decoded exactly
    mask[33, 50] = True  # one pixel alone in its block
    mask[40:46, 2:13] = True  # an edge inside blocks: ringing on both sides
    decoded = pil_file_round_trip(np.where(mask, 255, 0).astype(np.uint8), tmp_path / "m.jpg")
    got = jpeg_mask_round_trip(mask)
    assert got.dtype == np.bool_
    np.testing.assert_array_equal(got, decoded >= 128)  # v / 255 >= 0.5  <=>  v >= 128
    assert got[8:24, 16:40].all() and not got[:8].any()
    assert (decoded[mask] < 255).any() and (decoded[~mask] > 0).any()  # the file is not the mask
    # the threshold itself: 127 / 255 < 0.5 <= 128 / 255 in float32
    assert np.float32(127) / np.float32(255) < 0.5 <= np.float32(128) / np.float32(255)


def test_evaluated_files(image):
    mask = np.zeros(image.shape[:2], bool)
    mask[8:32, 8:40] = True
    assert evaluated_files(image, image, mask, "png") == (image, image, mask)
    g, r, m = evaluated_files(image, image, mask, "jpeg")
    np.testing.assert_array_equal(g, jpeg_round_trip(image, 75))
    np.testing.assert_array_equal(r, jpeg_round_trip(image, 95))
    np.testing.assert_array_equal(m, jpeg_mask_round_trip(mask))
    assert evaluated_files(image, None, None, "jpeg")[1:] == (None, None)
    with pytest.raises(ValueError, match="metrics.files='jpg'.*png, jpeg"):
        evaluated_files(image, image, mask, "jpg")


@pytest.mark.parametrize("protocol", ["paper", "authors"])
def test_score_cell_scores_the_jpeg_files(image, protocol, tmp_path):
    rng = np.random.default_rng(1)
    ref = np.clip(image + 0.05 * rng.standard_normal(image.shape), 0, 1).astype(np.float32)
    mask = np.zeros(image.shape[:2], bool)
    mask[5:35, 6:50] = rng.random((30, 44)) < 0.9
    gen_file = pil_file_round_trip(quantize_8bit(image), tmp_path / "main.jpg")
    ref_file = pil_file_round_trip(quantize_8bit(ref), tmp_path / "blender.jpg", quality=95)
    mask_file = pil_file_round_trip(np.where(mask, 255, 0).astype(np.uint8), tmp_path / "blender_mask.jpg") >= 128
    jpeg = score_cell(image, ref, mask, "p", None, protocol=protocol, files="jpeg")
    f32 = lambda a: a.astype(np.float32) / np.float32(255)  # noqa: E731 - as the authors read a file
    files = score_cell(f32(gen_file), f32(ref_file), mask_file, "p", None, protocol=protocol)
    png = score_cell(image, ref, mask, "p", None, protocol=protocol)
    for name in ("psnr", "mae"):
        assert jpeg["metrics"][name] == files["metrics"][name] != png["metrics"][name]


def test_a_reference_that_is_already_a_jpeg_is_not_encoded_again():
    """The Cycles reference decodes the authors' blender.jpg itself: a second q95 encode would not be
    what their evaluation reads."""
    from snell_bench.metrics.files import evaluated_files

    rng = np.random.default_rng(3)
    gen, ref = rng.random((16, 24, 3)).astype(np.float32), rng.random((16, 24, 3)).astype(np.float32)
    mask = np.zeros((16, 24), bool)
    mask[4:12, 6:18] = True
    _, again, _ = evaluated_files(gen, ref, mask, "jpeg")
    _, kept, _ = evaluated_files(gen, ref, mask, "jpeg", reference_is_jpeg=True)
    assert kept is ref and not np.array_equal(again, ref)
