"""A result that cannot mean anything is not ``ok``: void warps, an empty metric mask and a
reference without one finite pixel are ``degenerate`` cells, shown and in no mean; and the report
and the runner agree on which cells are finished (one rule)."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from tiny_runs import smoke_cfg

from snell_bench.pipeline.degenerate import reference_problem, warps_problem

EXTRA = ["grid.scenes=[living_room]"]


def _cfg(root: Path, *more):
    return smoke_cfg(root, *EXTRA, *more)


def test_every_object_ray_trapped_is_a_degenerate_cell_in_no_mean(tmp_path, caplog):
    """warps.max_bounces=1 on a sphere: a ray that enters cannot leave (two interfaces), so
    refraction is valid in no object pixel: each cell of the group is degenerate, with the reason,
    done (a second run computes nothing), listed in the report and in none of its means."""
    from snell_bench.experiment.runner import run_grid
    from snell_bench.reports import collect

    summary = run_grid(_cfg(tmp_path, "warps.max_bounces=1"))
    assert summary["degenerate"] == 2 and summary["ok"] == 0 and summary["exit_status"] == 0, summary
    rec = json.loads(
        (tmp_path / "runs" / "smoke" / "living_room-0" / "sphere" / "snellcaster" / "metrics.json").read_text()
    )
    assert rec["status"] == "degenerate" and "valid in 0 of" in rec["reason"] and "warps.max_bounces" in rec["reason"]
    assert "degenerate" in caplog.text
    again = run_grid(_cfg(tmp_path, "warps.max_bounces=1"))
    assert again["cached"] == 2 and again["degenerate"] == 0
    df = collect(tmp_path / "runs" / "smoke")
    assert set(df["status"]) == {"degenerate"}
    table = (tmp_path / "reports" / "smoke" / "method_table.md").read_text()
    assert "degenerate" in table or "degenerate" in (tmp_path / "reports" / "smoke" / "index.html").read_text()


def test_a_reference_without_a_finite_pixel_or_mask_cannot_score():
    image = np.full((4, 4, 3), np.nan, np.float32)
    assert "no finite pixel" in reference_problem(SimpleNamespace(image=image, mask=np.ones((4, 4), bool)))
    ok = np.zeros((4, 4, 3), np.float32)
    assert "metric mask is empty" in reference_problem(SimpleNamespace(image=ok, mask=np.zeros((4, 4), bool)))
    assert reference_problem(SimpleNamespace(image=ok, mask=np.eye(4, dtype=bool))) is None
    assert reference_problem(None) is None
    void = SimpleNamespace(object_mask=np.eye(4, dtype=bool), refraction_valid=np.zeros((4, 4), bool))
    assert "valid in 0 of its 4 pixels" in warps_problem(void, 1)
    assert (
        warps_problem(SimpleNamespace(object_mask=np.zeros((4, 4), bool), refraction_valid=void.refraction_valid))
        is None
    )


def test_the_report_and_the_runner_agree_on_a_cell_whose_image_is_gone(tmp_path, caplog):
    from snell_bench.experiment.runner import run_grid
    from snell_bench.reports import collect

    one = ["grid.methods=[t2i]", "reference.enabled=false", "grid.report=false"]
    run_grid(_cfg(tmp_path, *one))
    cell = tmp_path / "runs" / "smoke" / "living_room-0" / "sphere" / "t2i"
    (cell / "image.png").unlink()
    df = collect(tmp_path / "runs" / "smoke")
    row = df[df["method"] == "t2i"].iloc[0]
    assert row["status"] == "failed" and "image.png is missing" in row["reason"]  # not scored
    assert run_grid(_cfg(tmp_path, *one))["ok"] == 1  # the runner computes it again
