"""``job=relight`` (``+experiment=relighting``) on one small cell: the truth, every method's image,
the scores and the report, and a finished cell kept on a second run."""

import json
import math

import pandas as pd
import pytest

pytest.importorskip("mitsuba")

from snell_bench.config import compose  # noqa: E402
from snell_bench.experiment import run_job  # noqa: E402
from snell_bench.experiment.relighting import METHODS  # noqa: E402


def _cfg(tmp_path):
    return compose(
        [
            "+experiment=relighting",
            "scene.width=96",
            "scene.height=56",
            "grid.scenes=[landscape]",
            "grid.objects=[sphere]",
            "relight.truth_spp=32",
            "relight.relighter.caustic_rays=20000",
            "relight.relighter.env_samples=16",
            f"runs_dir={tmp_path / 'runs'}",
            f"reports_dir={tmp_path / 'reports'}",
            f"output_dir={tmp_path}",
        ]
    )


def test_relighting_experiment_scores_every_method_and_keeps_finished_cells(tmp_path, monkeypatch):
    monkeypatch.setenv("SNELL_BENCH_MITSUBA_VARIANT", "scalar_rgb")
    cfg = _cfg(tmp_path)
    assert run_job(cfg) == 0
    cell = tmp_path / "runs" / "relighting" / "landscape-0" / "sphere"
    rows = json.loads((cell / "scores.json").read_text())
    assert [r["method"] for r in rows] == list(METHODS)
    for name in ("unrelit", "truth", "none", "shadow", "traced_true", "traced"):
        assert (cell / f"{name}.png").is_file(), name
    by = {r["method"]: r for r in rows}
    assert "weights" in by["kontext"]["missing"]
    assert by["none"]["shadow_iou"] == 0.0  # nothing darkened
    assert by["traced_true"]["psnr_region"] > by["none"]["psnr_region"] + 5
    table = pd.read_csv(tmp_path / "reports" / "relighting" / "relighting.csv")
    assert set(table["method"]) == set(METHODS) and (table["scene"] == "mean").sum() == len(METHODS)
    assert (tmp_path / "reports" / "relighting" / "relighting.png").stat().st_size > 1000
    before = (cell / "scores.json").stat().st_mtime_ns
    assert run_job(_cfg(tmp_path)) == 0  # the finished cell is kept
    assert (cell / "scores.json").stat().st_mtime_ns == before


@pytest.mark.slow
def test_traced_relighting_with_the_true_lights_is_within_the_truths_noise(tmp_path):
    """The hardest cell of ``+experiment=relighting`` at its own settings (a cylinder under a lamp):
    ``relight=traced`` with the scene's lights errs by less than the path-traced truth's own noise
    (their mean squared errors add, so a gap under 10 log10 2 dB)."""
    cfg = compose(
        [
            "+experiment=relighting",
            "grid.scenes=[living_room]",
            "grid.objects=[cylinder]",
            f"runs_dir={tmp_path / 'runs'}",
            f"reports_dir={tmp_path / 'reports'}",
            f"output_dir={tmp_path}",
        ]
    )
    assert run_job(cfg) == 0
    table = pd.read_csv(tmp_path / "reports" / "relighting" / "relighting.csv")
    row = table[(table["scene"] == "living_room") & (table["method"] == "traced_true")].iloc[0]
    assert row["noise_gap_db"] < 10 * math.log10(2.0), row.to_dict()
    assert row["noise_gap_db"] > -1.0  # not better than a perfect relighting by more than the noise estimate's spread
