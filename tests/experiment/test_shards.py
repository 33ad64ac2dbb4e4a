"""Sharding a grid between jobs (``grid.shards``, ``grid.shard``), per-job summaries, the report
built once every cell has its record, and ``job=status`` across the jobs."""

import json
import os
import subprocess
import sys

import pytest

from snell_bench.config import ConfigError, check_config, compose
from snell_bench.experiment.cells import Cell
from snell_bench.experiment.runner import job_id, plan_grid, run_grid, shard_cells
from snell_bench.experiment.status import format_status, grid_status
from tests.experiment.test_runner import REPO, TINY, make_cfg, metrics_of

FAST = [*TINY, "sampler.steps=2", "grid.methods=[t2i,snellcaster]", "reference.spp=2"]


def test_shards_split_whole_groups_balanced_and_cover_the_grid():
    cells = [Cell(f"g{g}/m{m}", REPO, None, {}, shares=f"g{g}") for g in range(5) for m in range(3)]
    parts = [shard_cells(cells, 3, k) for k in range(3)]
    names = [c.name for p in parts for c in p]
    assert sorted(names) == sorted(c.name for c in cells)  # every cell once
    for p in parts:  # whole groups
        groups = {c.shares for c in p}
        assert all(sum(c.shares == g for c in p) == 3 for g in groups)
    assert sorted(len(p) for p in parts) == [3, 6, 6]  # 5 groups of 3 cells: 2, 2, 1
    assert [c.name for c in shard_cells(cells, 1, 0)] == [c.name for c in cells]


def test_a_multirun_sweeps_one_job_per_shard_through_the_sweepers_params():
    """``hydra.sweeper.params`` makes ``grid.shard=range(0,N)`` of ``grid.shards=N`` (N >= 2), and
    the single unsharded job otherwise; Hydra's sweeper lets the command line's ``grid.shard`` win."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_module

    from snell_bench.config import register_configs

    register_configs()
    with initialize_config_module("snell_bench.conf", version_base="1.3"):
        for shards, sweep in ((3, "range(0,3)"), (1, "null")):
            cfg = hydra_compose("config", [f"grid.shards={shards}"], return_hydra_config=True)
            assert cfg.hydra.sweeper.params["grid.shard"] == sweep


def test_bad_shards_name_the_key():
    with pytest.raises(ConfigError, match=r"grid.shard=2: must be below grid.shards=2"):
        check_config(compose(["grid.shards=2", "grid.shard=2"]))
    with pytest.raises(ConfigError, match=r"grid.shards=0"):
        check_config(compose(["grid.shards=0"]))
    with pytest.raises(ConfigError, match=r"grid.lock='nfs'"):
        check_config(compose(["grid.lock=nfs"]))


def test_job_id_under_slurm_under_submitit_and_elsewhere(monkeypatch):
    for k in (
        "SLURM_ARRAY_JOB_ID",
        "SLURM_ARRAY_TASK_ID",
        "SLURM_JOB_ID",
        "SUBMITIT_LOCAL_JOB_ID",
        "SUBMITIT_EXECUTOR",
    ):
        monkeypatch.delenv(k, raising=False)
    assert job_id().endswith(f"-{os.getpid()}")
    monkeypatch.setenv("SUBMITIT_LOCAL_JOB_ID", "4321")  # submitit's local executor
    monkeypatch.setenv("SUBMITIT_EXECUTOR", "local")
    assert job_id() == "4321"
    monkeypatch.delenv("SUBMITIT_LOCAL_JOB_ID")
    monkeypatch.delenv("SUBMITIT_EXECUTOR")
    monkeypatch.setenv("SLURM_JOB_ID", "77")
    assert job_id() == "77"
    monkeypatch.setenv("SLURM_ARRAY_JOB_ID", "70")
    monkeypatch.setenv("SLURM_ARRAY_TASK_ID", "1")
    assert job_id() == "70_1"


def test_two_shards_compute_every_cell_once_and_the_last_one_reports(tmp_path, monkeypatch):
    """Two jobs in turn (as a job array would run them): each computes its own groups, writes its
    summary under jobs/<id>/, and the report comes only when every cell has its record; the
    cells equal an unsharded run's."""
    grid = ["grid.scenes=[living_room,kitchen]", *FAST]
    every = plan_grid(make_cfg(tmp_path, grid))
    summaries = []
    for k, task in enumerate(("0", "1")):
        monkeypatch.setenv("SLURM_JOB_ID", f"90{task}")  # Slurm sets all three for an array task
        monkeypatch.setenv("SLURM_ARRAY_JOB_ID", "900")
        monkeypatch.setenv("SLURM_ARRAY_TASK_ID", task)
        st = grid_status(make_cfg(tmp_path, [*grid, "grid.shards=2"]))
        assert st.counts["done"] == 2 * k and st.counts["left"] == 4 - 2 * k
        summaries.append(run_grid(make_cfg(tmp_path, [*grid, "grid.shards=2", f"grid.shard={k}"])))
    assert [s["ok"] for s in summaries] == [2, 2] and all(s["cached"] == 0 for s in summaries)
    assert "reports" not in summaries[0] and summaries[1]["reports"]  # the last job reports
    root = tmp_path / "runs" / "smoke"
    jobs = sorted(p.parent.name for p in (root / "jobs").glob("*/summary.json"))
    assert jobs == ["900_0", "900_1"] and not (root / "summary.json").exists()
    job = json.loads((root / "jobs" / "900_1" / "summary.json").read_text())["job"]
    assert job["shard"] == 1 and job["shards"] == 2 and job["restarts"] == 0
    cells = metrics_of(root)
    assert sorted(cells) == sorted(str(c.folder.relative_to(root)) for c in every)
    by_shard = {}
    for k in range(2):
        for c in shard_cells(every, 2, k):
            by_shard[str(c.folder.relative_to(root))] = k
    assert set(by_shard.values()) == {0, 1}
    # job=status reads it all back: every cell done, both jobs listed
    st = grid_status(make_cfg(tmp_path, [*grid, "grid.shards=2"]))
    assert st.counts["done"] == 4 and not st.running and not st.failed
    text = format_status(st)
    assert "4 done" in text and "900_0" in text and "shard 1" in text
    # a claim file marks a cell as running, with its owner
    (root / "kitchen-0" / "sphere" / "t2i" / "metrics.json").unlink()
    (root / "kitchen-0" / "sphere" / "t2i" / ".lock").write_text("4242 node7\n")
    st = grid_status(make_cfg(tmp_path, [*grid, "grid.shards=2"]))
    assert st.counts["running"] == 1 and st.running == [("kitchen-0/sphere/t2i", "4242 node7")]


@pytest.mark.slow
def test_status_on_the_command_line_writes_nothing(tmp_path):
    cmd = [sys.executable, "-m", "snell_bench", "job=status", "+experiment=smoke", f"runs_dir={tmp_path / 'runs'}"]
    out = subprocess.run(
        cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env={**os.environ, "HF_HUB_OFFLINE": "1"}
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "cells:" in out.stdout and "left" in out.stdout
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_grid_shards_on_the_command_line_make_one_job_per_shard(tmp_path):
    """``-m ... grid.shards=2`` through submitit's local executor (the Slurm launcher's twin): two
    jobs, every cell computed once, one summary per job, one report."""
    cmd = [
        sys.executable,
        "-m",
        "snell_bench",
        "-m",
        "+experiment=smoke",
        *FAST,
        "grid.methods=[t2i]",
        f"runs_dir={tmp_path / 'runs'}",
        f"reports_dir={tmp_path / 'reports'}",
        "grid.shards=2",
        "hydra/launcher=submitit_local",
        f"hydra.sweep.dir={tmp_path / 'multirun'}",
    ]
    subprocess.run(cmd, cwd=REPO, check=True, timeout=600, env={**os.environ, "HF_HUB_OFFLINE": "1"})
    root = tmp_path / "runs" / "smoke"
    summaries = [json.loads(p.read_text()) for p in sorted((root / "jobs").glob("*/summary.json"))]
    assert sorted(s["job"]["shard"] for s in summaries) == [0, 1]
    assert sum(s["ok"] for s in summaries) == len(metrics_of(root)) == 2
    assert (tmp_path / "reports" / "smoke" / "README.md").is_file()
