"""The exit status of ``python -m snell_bench`` (:mod:`snell_bench.__main__`): 3 when cells of a sweep
failed (after its report), 0 with ``grid.allow_failures=true`` or when cells were only skipped, 1
for a job that cannot run (``job=report`` without cells), in a single run and in a multirun whose
every job still runs."""

import json
import os
import subprocess
import sys

import pytest

from snell_bench.experiment.cells import CELLS_FAILED_EXIT, failures_verdict
from tests.experiment.test_runner import REPO

#: A cheap grid: tiny images, no reference render, one method.
CHEAP = [
    "+experiment=smoke",
    "scene.width=160",
    "scene.height=96",
    "warps.pano_height=64",
    "warps.cache_dir=null",
    "sampler.steps=2",
    "reference.enabled=false",
    "reference.true_render=false",
    "grid.scenes=[living_room]",
    "grid.methods=[t2i]",
]


@pytest.fixture
def open_box(tmp_path):
    """A box without its lid: a cell tracing it as ``object=fox`` fails (the mesh is not watertight)."""
    import trimesh

    box = trimesh.creation.box()
    box.update_faces(box.face_normals[:, 2] < 0.5)
    path = tmp_path / "open_box.ply"
    box.export(path)
    return path


def test_failures_verdict_counts_failed_cells_only():
    assert failures_verdict(0, False, "grid.allow_failures") == (0, "")  # skipped cells are not counted
    assert failures_verdict(1, False, "grid.allow_failures")[0] == CELLS_FAILED_EXIT == 3
    assert failures_verdict(5, True, "grid.allow_failures") == (0, " (exit status 0: grid.allow_failures=true)")


def test_a_sweep_whose_cells_failed_exits_3_after_its_report(run_cli, open_box, tmp_path, capsys):
    args = [*CHEAP, "grid.objects=[fox]", f"object.path={open_box}"]
    assert run_cli(*args) == 3
    out, err = capsys.readouterr()
    assert "smoke: 0 ok, 0 already done, 0 skipped, 1 failed (exit status 3: cells failed; " in out
    assert "grid.allow_failures=true exits 0)" in out and "not watertight" in out
    assert (tmp_path / "reports" / "smoke" / "README.md").is_file()  # the report comes first
    assert "Error: cells of experiment_name=smoke failed" in err and "exit status 3" in err
    summary = json.loads((tmp_path / "runs" / "smoke" / "summary.json").read_text())
    assert summary["failed"] == 1 and summary["exit_status"] == 3

    assert run_cli(*args, "grid.allow_failures=true") == 0  # the failed cell is computed again, fails again
    out, err = capsys.readouterr()
    assert "1 failed (exit status 0: grid.allow_failures=true)" in out and "Error" not in err


@pytest.mark.slow
def test_skipped_cells_are_not_failures(run_cli, capsys):
    assert run_cli(*CHEAP, "grid.methods=[flux2_dev]") == 0  # no GPU here: skipped
    out = capsys.readouterr().out
    assert "0 ok, 0 already done, 1 skipped, 0 failed" in out and "exit status" not in out


def test_a_multirun_runs_every_job_then_exits_3(run_cli, open_box, tmp_path, capsys):
    """The basic launcher runs the jobs in this process, in order: the first one's cells fail, the
    second one still runs; the multirun then exits 3 (Hydra reports the first job's failure)."""
    args = ["-m", *CHEAP, "grid.objects=[fox],[sphere]", f"object.path={open_box}", "grid.report=false"]
    assert run_cli(*args, f"hydra.sweep.dir={tmp_path / 'multirun'}") == 3
    root = tmp_path / "runs" / "smoke" / "living_room-0"
    records = {d: json.loads((root / d / "t2i" / "metrics.json").read_text())["status"] for d in ("fox", "sphere")}
    assert records == {"fox": "failed", "sphere": "ok"}
    assert "cells of experiment_name=smoke failed" in capsys.readouterr().err


def test_a_report_without_cells_is_one_line_naming_the_folder(run_cli, tmp_path, capsys):
    assert run_cli("job=report", "experiment_name=smok") == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("Error: job=report: nothing to report for experiment_name=smok: no cell records below ")
    assert str(tmp_path / "runs" / "smok") in err
    assert not (tmp_path / "runs" / "smok").exists()  # stopped before Hydra makes its log folder there
    assert "python -m snell_bench +experiment=<experiment> experiment_name=smok" in err


@pytest.mark.slow
def test_a_multirun_in_other_processes_runs_every_job_then_exits_3(tmp_path, open_box):
    """The same with submitit's local executor (the Slurm launcher's twin): each job in its own
    process, the failed cells' exception carried back, exit status 3 once both jobs ran."""
    cmd = [
        sys.executable,
        "-m",
        "snell_bench",
        "-m",
        *CHEAP,
        "grid.objects=[fox],[sphere]",
        f"object.path={open_box}",
        "grid.report=false",
        f"runs_dir={tmp_path / 'runs'}",
        "hydra/launcher=submitit_local",
        f"hydra.sweep.dir={tmp_path / 'multirun'}",
    ]
    out = subprocess.run(
        cmd, cwd=REPO, capture_output=True, text=True, timeout=600, env={**os.environ, "HF_HUB_OFFLINE": "1"}
    )
    assert out.returncode == CELLS_FAILED_EXIT, out.stderr[-3000:]
    assert "cells of experiment_name=smoke failed" in out.stderr
    root = tmp_path / "runs" / "smoke" / "living_room-0"
    assert json.loads((root / "sphere" / "t2i" / "metrics.json").read_text())["status"] == "ok"
    assert json.loads((root / "fox" / "t2i" / "metrics.json").read_text())["status"] == "failed"
