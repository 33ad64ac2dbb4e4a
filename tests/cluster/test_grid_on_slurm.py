"""The smoke grid on a real (single-node) Slurm: a 2-task job array sharded by snell_bench computes
every cell once and reports exactly what a local run reports; a task requeued in the middle of a
cell finishes the grid with nothing lost and no stray file."""

import filecmp
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.experiment.test_runner import TINY as RUNNER_TINY

ROOT = Path(__file__).resolve().parents[2]
#: the runner tests' small cells, 4 steps; scalar_rgb (below): a reference render independent of
#: thread timing (compared bit for bit)
TINY = ["+experiment=smoke", *RUNNER_TINY, "sampler.steps=4"]
SLURM = [
    "hydra/launcher=slurm_cpu",
    "grid.shards=2",
    "hydra.launcher.partition=debug",
    "hydra.launcher.gpus_per_node=0",
    "hydra.launcher.cpus_per_task=1",
    "hydra.launcher.mem_gb=1",
    "hydra.launcher.timeout_min=20",
]


def _env(extra=None):
    return {
        **os.environ,
        "HF_HUB_OFFLINE": "1",
        "SNELL_BENCH_MITSUBA_VARIANT": "scalar_rgb",
        "PYTHONPATH": str(ROOT),
        **(extra or {}),
    }


def _run(args, tmp, name, **kw):
    cmd = [sys.executable, "-m", "snell_bench", *args, *TINY]
    cmd += [f"runs_dir={tmp / name / 'runs'}", f"reports_dir={tmp / name / 'reports'}"]
    return subprocess.run(cmd, cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=900, **kw)


def _reports_equal(a: Path, b: Path) -> list[str]:
    """Report files that differ (tables and README; the figures are compared as files too)."""
    names = sorted(p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file())
    assert names == sorted(p.relative_to(b).as_posix() for p in b.rglob("*") if p.is_file())
    return [n for n in names if not filecmp.cmp(a / n, b / n, shallow=False)]


def _stray(root: Path) -> list[str]:
    """Files a finished grid must not hold: claims (a flock's .lock stays, emptied), temporaries, hand-overs."""

    def claimed(p: Path) -> bool:
        return p.name.startswith(".lease") or (p.name == ".lock" and p.read_text() != "")

    return sorted(
        p.relative_to(root).as_posix()
        for p in root.rglob("*")
        if p.is_file() and (claimed(p) or p.suffix in (".tmp", ".link") or p.name.startswith("sampling-"))
    )


@pytest.mark.slow
def test_the_smoke_grid_as_a_job_array_reports_what_a_local_run_reports(slurm_environ, tmp_path):
    local = _run(["job=grid"], tmp_path, "local")
    assert local.returncode == 0, local.stderr[-3000:]
    sweep = _run(["-m", *SLURM, f"hydra.sweep.dir={tmp_path / 'multirun'}"], tmp_path, "slurm")
    assert sweep.returncode == 0, sweep.stderr[-3000:] + slurm_environ.logs()
    root = tmp_path / "slurm" / "runs" / "smoke"
    summaries = [json.loads(p.read_text()) for p in sorted((root / "jobs").glob("*/summary.json"))]
    assert sorted(s["job"]["shard"] for s in summaries) == [0, 1]
    assert all("_" in p.parent.name for p in (root / "jobs").glob("*/summary.json"))  # <array job>_<task>
    assert sum(s["ok"] for s in summaries) == 4 and all(s["failed"] == 0 for s in summaries)  # every cell once
    assert _reports_equal(tmp_path / "local" / "reports" / "smoke", tmp_path / "slurm" / "reports" / "smoke") == []
    assert _stray(root) == []


@pytest.mark.slow
def test_a_task_requeued_in_the_middle_of_a_cell_finishes_the_grid(slurm_environ, tmp_path):
    """Sampling sleeps (model=sleeping) so a cell is surely running when its task is requeued."""
    args = ["-m", *SLURM, "model=sleeping", "model.generator.sleep_s=0.5", f"hydra.sweep.dir={tmp_path / 'multirun'}"]
    root = tmp_path / "slurm" / "runs" / "smoke"
    requeued: list[str] = []

    def requeue_when_a_cell_runs():
        deadline = time.time() + 300
        while time.time() < deadline and not requeued:
            for lock in (p for p in root.rglob(".lock") if p.read_text().strip()):  # a cell being computed
                jobs = slurm_environ.run(["squeue", "-h", "-t", "R", "-o", "%i"]).stdout.split()
                if jobs:
                    slurm_environ.requeue(jobs[0])
                    requeued.append(f"{jobs[0]} during {lock.parent.relative_to(root)}")
                    return
            time.sleep(0.2)

    watcher = threading.Thread(target=requeue_when_a_cell_runs, daemon=True)
    watcher.start()
    sweep = _run(args, tmp_path, "slurm")
    watcher.join(timeout=5)
    assert sweep.returncode == 0, sweep.stderr[-3000:] + slurm_environ.logs()
    assert requeued, "no cell was seen running"
    cells = {p.parent.relative_to(root).as_posix(): json.loads(p.read_text()) for p in root.rglob("metrics.json")}
    assert len(cells) == 4 and all(c["status"] == "ok" for c in cells.values()), cells
    summaries = [json.loads(p.read_text()) for p in sorted((root / "jobs").glob("*/summary.json"))]
    restarts = {s["job"]["id"]: s["job"]["restarts"] for s in summaries}
    acct = slurm_environ.run(["scontrol", "show", "job", "-o"], check=False).stdout
    import re

    assert max(restarts.values()) >= 1, (
        requeued,
        restarts,
        re.findall(r"JobId=\S+|Restarts=\S+|JobState=\S+", acct),
    )  # the requeued task ran again
    assert _stray(root) == []
