"""Scoring one cell: load_scorers keeps every failure as a reason, score_cell gives the numbers of
the metric functions, with and without a reference, and against the true render."""

import json
import math

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf
from omegaconf.errors import ValidationError

from snell_bench.metrics import (
    EMPTY_MASK_REASON,
    METRIC_NAMES,
    PROMPT_METRICS,
    PSNR_CEILING_DB,
    REFERENCE_METRICS,
    SCORER_NAMES,
    MaskedLPIPS,
    MetricUnavailable,
    Scorers,
    load_scorers,
    masked_mae,
    masked_psnr,
    score_all,
    score_cell,
)

PROMPT = "a glass sphere on a wooden table"
NO_IR = "ImageReward not configured: set metrics.image_reward_python"


def fake_lpips(generated, reference, mask, histogram_match=True):
    return float(np.abs(np.asarray(generated, float) - np.asarray(reference, float))[mask].mean())


def fake_clip(image, prompt):
    return float(np.asarray(image, float).mean() * 100 + len(prompt))


@pytest.fixture
def cell():
    rng = np.random.default_rng(5)
    ref = rng.random((30, 40, 3)).astype(np.float32)
    gen = np.clip(ref + 0.1 * rng.standard_normal(ref.shape), 0, 1).astype(np.float32)
    true = np.clip(ref + 0.05 * rng.standard_normal(ref.shape), 0, 1).astype(np.float32)
    mask = np.zeros((30, 40), bool)
    mask[5:25, 8:30] = True
    obj = np.zeros((30, 40), bool)
    obj[3:27, 4:34] = True
    return gen, ref, mask, true, obj


@pytest.fixture
def scorers():
    return Scorers(lpips=fake_lpips, clip=fake_clip, image_reward=MetricUnavailable(NO_IR))


def test_metric_groups_cover_the_metric_names():
    assert set(REFERENCE_METRICS) | set(PROMPT_METRICS) == set(METRIC_NAMES)
    assert not set(REFERENCE_METRICS) & set(PROMPT_METRICS)
    assert set(SCORER_NAMES) <= set(METRIC_NAMES)


def test_with_a_reference_the_numbers_of_the_metric_functions(cell, scorers):
    gen, ref, mask, true, obj = cell
    res = score_cell(gen, ref, mask, PROMPT, scorers, true_render=true, object_mask=obj)
    assert tuple(res["metrics"]) == METRIC_NAMES + ("psnr_true",)
    m = res["metrics"]
    assert m["psnr"] == masked_psnr(gen, ref, mask) and m["mae"] == masked_mae(gen, ref, mask)
    assert m["lpips"] == fake_lpips(gen, ref, mask) and m["clip"] == fake_clip(gen, PROMPT)
    assert m["psnr_true"] == masked_psnr(gen, true, obj)
    assert m["image_reward"] is None and res["missing"] == {"image_reward": NO_IR}
    expected = score_all(
        gen, ref, mask, PROMPT, lpips=fake_lpips, clip=fake_clip, image_reward=MetricUnavailable(NO_IR)
    )
    assert {k: m[k] for k in METRIC_NAMES} == expected["metrics"]
    json.dumps(res)  # serialisable as is


def test_a_torch_image_scores_like_its_numpy_form(cell, scorers):
    gen, ref, mask, true, obj = cell
    as_numpy = score_cell(gen, ref, mask, PROMPT, scorers, true_render=true, object_mask=obj)
    tensor = torch.from_numpy(gen).permute(2, 0, 1)
    for t in (tensor, tensor[None]):
        assert score_cell(t, ref, mask, PROMPT, scorers, true_render=true, object_mask=obj) == as_numpy


def test_without_a_reference_only_the_prompt_metrics_are_scored(cell, scorers):
    gen, _, _, true, obj = cell
    res = score_cell(
        gen, None, None, PROMPT, scorers, reference_reason="reference.enabled=false", true_render=true, object_mask=obj
    )
    m = res["metrics"]
    assert [m[k] for k in REFERENCE_METRICS] == [None] * len(REFERENCE_METRICS)
    assert m["clip"] == fake_clip(gen, PROMPT) and m["image_reward"] is None
    assert m["psnr_true"] == masked_psnr(gen, true, obj)  # the true render needs no reference
    assert res["missing"] == {**{k: "reference.enabled=false" for k in REFERENCE_METRICS}, "image_reward": NO_IR}
    plain = score_cell(gen, None, None, PROMPT, Scorers(clip=MetricUnavailable("no CLIP weights")))
    assert plain["missing"] == {
        **{k: "no reference" for k in REFERENCE_METRICS},
        "clip": "no CLIP weights",
        "image_reward": "not configured (set metrics.image_reward_python)",
    }
    assert "psnr_true" not in plain["metrics"]


def test_a_scorer_failing_at_scoring_time_keeps_its_reason(cell):
    gen = cell[0]

    def broken_clip(image, prompt):
        raise MetricUnavailable("prompt too long for this CLIP")

    res = score_cell(gen, None, None, PROMPT, Scorers(clip=broken_clip))
    assert res["metrics"]["clip"] is None and res["missing"]["clip"] == "prompt too long for this CLIP"


def test_the_reason_a_scorer_is_missing_wins(cell):
    gen, ref, mask, _, _ = cell
    why = "LPIPS backbone weights not found at /x: set metrics.lpips_weights"
    res = score_cell(gen, ref, mask, PROMPT, {"lpips": MetricUnavailable(why)})
    assert res["missing"]["lpips"] == why
    assert res["missing"]["clip"].startswith("not configured (set metrics.clip_weights")  # None: not configured
    no_ref = score_cell(gen, None, None, PROMPT, {"lpips": MetricUnavailable(why)}, reference_reason="no reference.png")
    assert no_ref["missing"]["lpips"] == why and no_ref["missing"]["psnr"] == "no reference.png"


def test_a_perfect_match_is_recorded_at_the_psnr_ceiling_and_counts_in_the_mean(cell):
    """Identical pixels (infinite PSNR) are a result, not a missing value: the record holds the
    stated ceiling with a note, and a mean over cells counts the perfect cell."""
    gen, ref, mask, _, obj = cell
    res = score_cell(gen, gen.copy(), mask, PROMPT, None, true_render=gen.copy(), object_mask=obj)
    assert math.isinf(masked_psnr(gen, gen, mask))
    assert res["metrics"]["psnr"] == PSNR_CEILING_DB and res["metrics"]["psnr_true"] == PSNR_CEILING_DB
    assert "psnr" not in res["missing"] and "psnr_true" not in res["missing"]
    assert "80 dB ceiling" in res["notes"]["psnr"] and "identical" in res["notes"]["psnr_true"]
    assert res["metrics"]["mae"] == 0.0
    worse = score_cell(gen, ref, mask, PROMPT, None)
    assert worse["notes"] == {} and worse["metrics"]["psnr"] < PSNR_CEILING_DB
    cells = [res["metrics"]["psnr"], worse["metrics"]["psnr"]]
    assert np.mean(cells) == pytest.approx((PSNR_CEILING_DB + worse["metrics"]["psnr"]) / 2)
    # 10 log10(1 / 1e-8): the authors' evaluation calls any MSE <= 1e-8 zero
    assert PSNR_CEILING_DB == pytest.approx(10 * math.log10(1 / 1e-8))


def test_the_record_of_a_perfect_cell_is_strict_json_with_the_ceiling(cell, tmp_path):
    from snell_bench.reports.records import GRID_RECORD, record_problem
    from snell_bench.utils.io import write_json

    gen, _, mask, _, _ = cell
    res = score_cell(gen, gen.copy(), mask, PROMPT, None)
    rec = {"status": "ok", "experiment": "e", "scene": "s", "variation": 0, "object": "o", "method": "m", **res}
    write_json(tmp_path / "metrics.json", rec)
    back = json.loads((tmp_path / "metrics.json").read_text())
    assert back["metrics"]["psnr"] == PSNR_CEILING_DB and record_problem(back, GRID_RECORD) is None
    assert "not of type" in record_problem({**back, "notes": {"psnr": 3}}, GRID_RECORD)


def test_empty_masks(cell):
    gen, ref, mask, true, obj = cell
    res = score_cell(gen, ref, np.zeros_like(mask), PROMPT, None, true_render=true, object_mask=np.zeros_like(obj))
    assert res["metrics"]["psnr"] is None and res["missing"]["psnr"] == EMPTY_MASK_REASON
    assert res["metrics"]["psnr_true"] is None and res["missing"]["psnr_true"] == EMPTY_MASK_REASON
    with pytest.raises(ValueError, match="object_mask"):
        score_cell(gen, ref, mask, PROMPT, None, true_render=true)


def test_load_scorers_turns_every_failure_into_a_reason(tmp_path, cell):
    broken = tmp_path / "vgg16-397923af.pth"
    broken.write_bytes(b"not a checkpoint")
    cfg = OmegaConf.create(
        {"lpips_weights": str(broken), "clip_weights": str(tmp_path / "no.bin"), "image_reward_python": None}
    )
    scorers = load_scorers(cfg)
    assert isinstance(scorers, Scorers) and set(scorers) == set(SCORER_NAMES)
    assert all(isinstance(s, MetricUnavailable) for s in scorers.values())
    assert scorers.lpips is None and scorers.clip is None and scorers.image_reward is None
    reasons = scorers.reasons
    assert set(reasons) == set(SCORER_NAMES)
    assert reasons["lpips"].split(":")[0].isidentifier()  # "<exception type>: <message>"
    assert "metrics.clip_weights" in reasons["clip"] and "metrics.image_reward_python" in reasons["image_reward"]
    gen, ref, mask, _, _ = cell
    res = score_cell(gen, ref, mask, PROMPT, scorers)
    assert res["missing"] == reasons and res["metrics"]["psnr"] == masked_psnr(gen, ref, mask)
    assert score_all(gen, ref, mask, PROMPT, **scorers)["missing"] == reasons  # still the score_all keywords


def test_load_scorers_keeps_a_scorer_that_builds(tmp_path, monkeypatch):
    import snell_bench.metrics.scoring as scoring

    monkeypatch.setattr(scoring, "MaskedLPIPS", lambda weights, device: MaskedLPIPS(allow_random_backbone=True))
    scorers = load_scorers({"clip_weights": str(tmp_path / "no.bin")})
    assert isinstance(scorers.lpips, MaskedLPIPS) and "lpips" not in scorers.reasons


# ------------------------------------------------------------------------------------------
# The evaluation protocol
# ------------------------------------------------------------------------------------------


class RecordingLPIPS:
    """A stand-in LPIPS scorer that records how it is called."""

    def __init__(self):
        self.calls = []

    def __call__(self, generated, reference, mask, **kwargs):
        self.calls.append(kwargs)
        return fake_lpips(generated, reference, mask)


def test_the_protocol_is_recorded_and_paper_is_the_default(cell, scorers):
    gen, ref, mask, true, obj = cell
    default = score_cell(gen, ref, mask, PROMPT, scorers, true_render=true, object_mask=obj)
    assert default["protocol"] == "paper"
    assert score_cell(gen, ref, mask, PROMPT, scorers, true_render=true, object_mask=obj, protocol="paper") == default
    no_ref = score_cell(gen, None, None, PROMPT, scorers, protocol="authors")
    assert no_ref["protocol"] == "authors"
    json.dumps(no_ref)


def test_authors_protocol_is_passed_down(cell):
    gen, ref, mask, true, obj = cell
    lp = RecordingLPIPS()
    res = score_cell(
        gen, ref, mask, PROMPT, Scorers(lpips=lp, clip=fake_clip), true_render=true, object_mask=obj, protocol="authors"
    )
    m = res["metrics"]
    assert res["protocol"] == "authors"
    assert m["psnr"] == masked_psnr(gen, ref, mask, protocol="authors") != masked_psnr(gen, ref, mask)
    assert m["mae"] == masked_mae(gen, ref, mask, protocol="authors")
    assert m["psnr_true"] == masked_psnr(gen, true, obj, protocol="authors")
    assert lp.calls == [{"protocol": "authors"}, {"protocol": "authors", "box": True, "box_range": "signed"}]
    assert tuple(m) == ("psnr", "mae", "lpips", "lpips_box", "clip", "image_reward", "psnr_true")
    assert m["clip"] == fake_clip(gen, PROMPT)  # the text scores do not depend on the protocol
    # the paper protocol calls the LPIPS scorer once, with no option, and has no lpips_box
    paper = score_cell(gen, ref, mask, PROMPT, Scorers(lpips=lp))
    assert lp.calls[-1] == {} and len(lp.calls) == 3
    assert "lpips_box" not in paper["metrics"] and "lpips_box" not in paper["missing"]


def test_unknown_protocol_is_a_value_error_naming_the_config_key(cell, scorers):
    gen, ref, mask, _, _ = cell
    for protocol in ("author", "PAPER", "", None):
        with pytest.raises(ValueError, match=r"metrics\.protocol") as exc:
            score_cell(gen, ref, mask, PROMPT, scorers, protocol=protocol)
        assert "'paper'" in str(exc.value) and "'authors'" in str(exc.value)
    with pytest.raises(ValueError, match=r"metrics\.protocol"):  # also without a reference
        score_cell(gen, None, None, PROMPT, scorers, protocol="author")


def test_load_scorers_reads_the_protocol(tmp_path):
    from snell_bench.config import MetricsConfig

    cfg = OmegaConf.structured(MetricsConfig(clip_weights=str(tmp_path / "no.bin")))
    assert set(load_scorers(cfg)) == set(SCORER_NAMES)
    cfg.protocol = "authors"
    assert set(load_scorers(cfg)) == set(SCORER_NAMES)
    assert set(load_scorers({"protocol": None, "clip_weights": str(tmp_path / "no.bin")})) == set(SCORER_NAMES)
    with pytest.raises(ValueError, match=r"metrics\.protocol.*'paper', 'authors'"):
        load_scorers({"protocol": "author"})  # a plain mapping: the config's enum rejects it earlier
    with pytest.raises(ValidationError, match="expected one of"):
        cfg.protocol = "author"


@pytest.mark.parametrize("protocol", ["paper", "authors"])
def test_identical_and_constant_images_never_give_nan(cell, protocol):
    gen, ref, mask, _, obj = cell
    res = score_cell(gen, gen.copy(), mask, PROMPT, None, true_render=gen.copy(), object_mask=obj, protocol=protocol)
    if protocol == "paper":
        assert res["metrics"]["psnr"] == res["metrics"]["psnr_true"] == PSNR_CEILING_DB
        assert res["metrics"]["mae"] == 0.0 and "psnr" not in res["missing"]
    else:  # the authors' matching is not the identity on identical images (test_authors_protocol.py)
        assert all(math.isfinite(res["metrics"][k]) for k in ("psnr", "mae", "psnr_true"))
    flat = np.full_like(gen, 0.4)
    res = score_cell(flat, ref, mask, PROMPT, None, protocol=protocol)
    assert all(isinstance(res["metrics"][k], float) and math.isfinite(res["metrics"][k]) for k in ("psnr", "mae"))
    for name, value in res["metrics"].items():
        assert value is not None or name in res["missing"]
