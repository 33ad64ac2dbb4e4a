"""Surface segmenters: the tiny random SAM 3, SAM 3's loading path, mask files, the config group."""

from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf
from PIL import Image

from snell_bench.models.errors import WeightsNotFoundError
from snell_bench.models.segment import (
    MaskFileSegmenter,
    Sam3Segmenter,
    SurfaceMask,
    SurfaceSegmenter,
    TinySam3Segmenter,
    pick_instance,
    read_mask,
    surface_region,
)
from snell_bench.models.tiny_segment import tiny_sam3

CONF = Path(__file__).resolve().parents[2] / "snell_bench" / "conf" / "segment"


def photo(h=64, w=96, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).random((h, w, 3)).astype(np.float32)


@pytest.fixture(scope="module")
def tiny() -> TinySam3Segmenter:
    return TinySam3Segmenter(seed=0, threshold=0.0)


# ---------------------------------------------------------------------------- tiny SAM 3
def test_tiny_sam3_is_a_small_eval_model_and_leaves_the_global_rng_alone():
    state = torch.random.get_rng_state()
    model, processor = tiny_sam3(3)
    assert torch.equal(state, torch.random.get_rng_state())
    assert not model.training
    assert sum(p.numel() for p in model.parameters()) < 500_000
    assert model.config.text_config.vocab_size == len(processor.tokenizer) == 49408
    a, _ = tiny_sam3(3)
    b, _ = tiny_sam3(4)
    sa, sb = a.state_dict(), b.state_dict()
    assert all(torch.equal(v, model.state_dict()[k]) for k, v in sa.items())
    assert any(not torch.equal(v, sb[k]) for k, v in sa.items())


def test_tiny_sam3_gives_a_bool_mask_at_the_input_size_deterministically(tiny):
    import time

    image = photo()
    start = time.perf_counter()
    mask = tiny(image, "wooden coffee table")
    assert time.perf_counter() - start < 2.0
    assert isinstance(tiny, SurfaceSegmenter) and tiny.name == "tiny_sam3"
    assert mask.dtype == np.bool_ and mask.shape == (64, 96)
    assert mask.any()  # threshold 0 keeps every query
    assert np.array_equal(mask, tiny(image, "wooden coffee table"))
    assert np.array_equal(mask, TinySam3Segmenter(seed=0, threshold=0.0)(image, "wooden coffee table"))
    found = tiny.instances(image, "wooden coffee table")
    assert found["masks"].shape == (4, 64, 96) and found["masks"].dtype == np.bool_
    assert np.all(np.diff(found["scores"]) <= 0)  # best first
    assert np.array_equal(found["masks"].any(0), mask)  # the union
    other = tiny(photo(50, 70, seed=1), "floor")
    assert other.shape == (50, 70)


def test_nothing_found_is_an_empty_mask_and_surface_region_names_the_phrase():
    seg = TinySam3Segmenter(seed=0)  # threshold 0.5: random scores stay near 0.25
    image = photo()
    mask = seg(image, "wooden coffee table")
    assert mask.dtype == np.bool_ and mask.shape == (64, 96) and not mask.any()
    assert seg.instances(image, "wooden coffee table")["masks"].shape == (0, 64, 96)
    with pytest.raises(ValueError, match="'wooden coffee table'.*scene.surface.*segment.threshold"):
        surface_region(seg, image, "wooden coffee table")


def test_surface_region_passes_a_found_surface(tiny):
    image = photo()
    assert np.array_equal(surface_region(tiny, image, "table"), tiny(image, "table"))
    with pytest.raises(ValueError, match="phrase"):
        tiny(image, "  ")
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        tiny(image[..., 0], "table")


def test_sam3_segmenter_loads_a_saved_model_folder(tmp_path):
    """The loading path of the real SAM 3 (from_pretrained, local files only) on the tiny model."""
    model, processor = tiny_sam3(0)
    model.save_pretrained(tmp_path)
    processor.save_pretrained(tmp_path)
    seg = Sam3Segmenter(tmp_path, device="cpu", threshold=0.0)
    assert seg.name == "sam3" and not seg.model.training
    built = TinySam3Segmenter(seed=0, threshold=0.0)
    # The masks threshold the mask logits, so a pixel whose logit lies within rounding of the threshold
    # may flip when the loaded and the built weights are summed in other orders (other alignments). In
    # float64 (the float32 weights are exact there) the logits agree to ~1e-13, and a pixel of the
    # 64 x 96 image lies that close to the threshold with a probability of ~1e-9: the masks are equal.
    seg.model.double()
    built.model.double()
    image = photo()
    assert np.array_equal(seg(image, "wooden coffee table"), built(image, "wooden coffee table"))


def test_missing_sam3_weights_name_segment_path(tmp_path):
    for path in (tmp_path / "no-such-folder", tmp_path, "nobody-here/no-such-sam3"):
        with pytest.raises(WeightsNotFoundError, match="segment.path"):
            Sam3Segmenter(path)
    (tmp_path / "file").write_text("x")
    with pytest.raises(WeightsNotFoundError, match="segment.path"):
        Sam3Segmenter(tmp_path / "file")
    with pytest.raises(WeightsNotFoundError, match="segment.path"):
        Sam3Segmenter(None)


@pytest.mark.weights
def test_real_sam3_finds_the_desk_of_the_tum_frame():
    from snell_bench.scene.image_source import load_image

    try:
        seg = Sam3Segmenter("facebook/sam3", device=None)
    except WeightsNotFoundError as err:
        pytest.skip(str(err)[:120])
    root = Path(__file__).resolve().parents[2]
    image = load_image(root / "snell_bench" / "datasets" / "rgbd" / "tum_fr3_office" / "color.png")
    mask = seg(image, "desk")
    assert mask.shape == image.shape[:2] and mask.dtype == np.bool_
    assert 0.02 < mask.mean() < 0.9


# ---------------------------------------------------------------------------- segment.instance
def three_instances():
    """Three instances in score order; the model's query order is 2, 0, 1 (so the first query is
    not the best one, as SAM 3's queries are not sorted)."""
    masks = np.zeros((3, 8, 10), bool)
    masks[0, 0:2, 0:3] = masks[1, 4:6, 5:9] = masks[2, 6:8, 0:2] = True
    boxes = np.array([[0, 0, 3, 2], [5, 4, 9, 6], [0, 6, 2, 8]], np.float32)
    return {"masks": masks, "scores": np.array([0.9, 0.8, 0.8]), "boxes": boxes, "query": np.array([2, 0, 1])}


def test_pick_instance_union_best_first():
    found = three_instances()
    union = pick_instance(found, "union", (8, 10))
    assert isinstance(union, SurfaceMask) and np.array_equal(union, found["masks"].any(0))
    assert np.array_equal(union.box, [0, 0, 9, 8])
    best = pick_instance(found, "best", (8, 10))
    assert np.array_equal(best, found["masks"][0]) and np.array_equal(best.box, [0, 0, 3, 2])
    first = pick_instance(found, "first", (8, 10))
    assert np.array_equal(first, found["masks"][1]) and np.array_equal(first.box, [5, 4, 9, 6])
    tie = dict(found, scores=np.array([0.8, 0.8, 0.8]))  # a tie: the earlier query wins
    assert np.array_equal(pick_instance(tie, "best", (8, 10)), found["masks"][1])
    empty = pick_instance({k: v[:0] for k, v in found.items()}, "first", (8, 10))
    assert empty.shape == (8, 10) and not empty.any() and empty.box is None
    with pytest.raises(ValueError, match="segment.instance='all'"):
        pick_instance(found, "all", (8, 10))


class StubSam3:
    """Instances only; ``__call__`` is the union (as :class:`Sam3Segmenter`)."""

    name = "stub"

    def instances(self, image, phrase):
        return three_instances()

    def __call__(self, image, phrase):
        return pick_instance(self.instances(image, phrase), "union", image.shape[:2])


def test_surface_region_takes_the_instance_the_config_names(tmp_path):
    image = photo(8, 10)
    first = surface_region(StubSam3(), image, "table", instance="first")
    assert np.array_equal(first, three_instances()["masks"][1]) and np.array_equal(first.box, [5, 4, 9, 6])
    union = surface_region(StubSam3(), image, "table")
    assert np.array_equal(union, three_instances()["masks"].any(0)) and union.box is not None
    Image.fromarray(np.full((8, 10), 255, np.uint8)).save(tmp_path / "m.png")
    drawn = surface_region(MaskFileSegmenter(tmp_path / "m.png"), image, "table", instance="first")
    assert drawn.all() and getattr(drawn, "box", None) is None  # a mask file has one region
    with pytest.raises(ValueError, match="segment.instance"):
        surface_region(StubSam3(), image, "table", instance="largest")


def test_tiny_sam3_keeps_the_query_order(tiny):
    image = photo()
    found = tiny.instances(image, "table")
    assert sorted(found["query"]) == list(range(len(found["query"])))
    first = tiny(image, "table", instance="first")
    i = int(np.argmin(found["query"]))
    assert np.array_equal(first, found["masks"][i]) and np.array_equal(first.box, found["boxes"][i])
    assert np.array_equal(tiny(image, "table", instance="best"), found["masks"][0])
    assert np.array_equal(tiny(image, "table"), found["masks"].any(0))


def test_segment_instance_is_checked_by_the_schema():
    from snell_bench.config.errors import ConfigError
    from snell_bench.config.schema import SegmentConfig

    assert SegmentConfig().instance == "union"
    with pytest.raises(ConfigError, match="segment.instance='all'"):
        SegmentConfig(instance="all")


# ---------------------------------------------------------------------------- mask files
def test_mask_file_round_trips_exactly(tmp_path):
    rng = np.random.default_rng(0)
    mask = rng.random((40, 60)) > 0.5
    image = photo(40, 60)
    cases = {
        "grey.png": (mask * 255).astype(np.uint8),
        "one.png": (mask * 1).astype(np.uint8),
        "wide.png": (mask * 1000).astype(np.uint16),
    }
    for name, arr in cases.items():
        Image.fromarray(arr).save(tmp_path / name)
    Image.fromarray(mask).save(tmp_path / "bits.png")  # mode "1"
    rgba = np.zeros((40, 60, 4), np.uint8)
    rgba[..., 2] = mask  # a faint blue is surface
    rgba[..., 3] = 255  # opaque black is not
    Image.fromarray(rgba, "RGBA").save(tmp_path / "rgba.png")
    for name in (*cases, "bits.png", "rgba.png"):
        seg = MaskFileSegmenter(tmp_path / name)
        out = seg(image, "ignored")
        assert seg.name == "mask" and isinstance(seg, SurfaceSegmenter)
        assert out.dtype == np.bool_ and np.array_equal(out, mask), name
        out[:] = False  # a copy
        assert np.array_equal(seg(image, "ignored"), mask)
    assert np.array_equal(read_mask(tmp_path / "grey.png"), mask)


def test_mask_file_errors_name_segment_mask(tmp_path):
    Image.fromarray(np.full((40, 60), 255, np.uint8)).save(tmp_path / "m.png")
    seg = MaskFileSegmenter(str(tmp_path / "m.png"))
    with pytest.raises(ValueError, match=r"segment\.mask.*60x40 pixels but the image is 61x40"):
        seg(photo(40, 61), "table")
    with pytest.raises(FileNotFoundError, match=r"segment\.mask"):
        MaskFileSegmenter(tmp_path / "missing.png")
    with pytest.raises(ValueError, match=r"segment\.mask"):
        MaskFileSegmenter(None)
    (tmp_path / "bad.png").write_text("not an image")
    with pytest.raises(ValueError, match=r"segment\.mask"):
        MaskFileSegmenter(tmp_path / "bad.png")


# ---------------------------------------------------------------------------- config group
def _segment_node(name: str, **overrides):
    node = OmegaConf.load(CONF / f"{name}.yaml")
    assert node.defaults == ["base_segment", "_self_"]
    del node["defaults"]
    base = OmegaConf.create({"name": "", "path": None, "mask": None, "device": None, "threshold": 0.5})
    return OmegaConf.merge(base, node, overrides)


def test_config_group_builds_each_segmenter(tmp_path):
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate

    assert sorted(p.stem for p in CONF.glob("*.yaml")) == ["mask", "ransac", "sam3", "tiny_sam3"]
    assert _segment_node("ransac").segmenter is None
    tiny = instantiate(_segment_node("tiny_sam3").segmenter)
    assert isinstance(tiny, TinySam3Segmenter) and tiny.threshold == 0.0
    Image.fromarray(np.full((8, 8), 255, np.uint8)).save(tmp_path / "m.png")
    seg = instantiate(_segment_node("mask", mask=str(tmp_path / "m.png")).segmenter)
    assert isinstance(seg, MaskFileSegmenter)
    node = _segment_node("sam3")
    assert node.path == "facebook/sam3"
    with pytest.raises(InstantiationException, match="segment.path") as info:  # hydra wraps the error
        instantiate(_segment_node("sam3", path=str(tmp_path / "nothing")).segmenter)
    assert isinstance(info.value.__cause__, WeightsNotFoundError)


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA is available here")
def test_missing_cuda_names_segment_device():
    from snell_bench.models.errors import DeviceNotAvailableError

    with pytest.raises(DeviceNotAvailableError, match="segment.device"):
        Sam3Segmenter("facebook/sam3", device="cuda")  # before any weights are looked for
