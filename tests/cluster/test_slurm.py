"""A real single-node Slurm (slurm.py): job arrays, submitit's executor, requeueing, the daemons'
lifetime."""

import time

import pytest

from .slurm import local_slurm, missing_reason

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]


def wait_for(predicate, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"{what}: not after {timeout} s"
        time.sleep(0.2)


def test_sbatch_array_runs_every_task(slurm_cluster, tmp_path):
    """Both tasks of ``sbatch --array=0-1`` run, each with its own index, and write their outputs."""
    job = slurm_cluster.sbatch(
        "--array=0-1",
        f"--output={tmp_path}/slurm-%A_%a.out",
        "--wrap",
        f'echo "task $SLURM_ARRAY_TASK_ID of $SLURM_ARRAY_JOB_ID" > {tmp_path}/task_$SLURM_ARRAY_TASK_ID.txt; echo done',
    )
    assert slurm_cluster.wait_jobs([job], timeout=50) == {f"{job}_0": "COMPLETED", f"{job}_1": "COMPLETED"}
    for i in (0, 1):
        assert (tmp_path / f"task_{i}.txt").read_text() == f"task {i} of {job}\n"
        assert (tmp_path / f"slurm-{job}_{i}.out").read_text() == "done\n"


def test_submitit_map_array_through_the_scheduler(slurm_environ, tmp_path):
    """submitit's AutoExecutor finds the cluster through SLURM_CONF, submits one array of two tasks
    to the ``debug`` partition and reads back both results."""
    submitit = pytest.importorskip("submitit")

    def task(x):
        import os

        return x * x, os.environ["SLURM_ARRAY_TASK_ID"], os.environ["SLURM_CONF"]

    executor = submitit.AutoExecutor(folder=tmp_path / "submitit")
    assert executor.cluster == "slurm"
    executor.update_parameters(slurm_partition="debug", timeout_min=5)
    jobs = executor.map_array(task, [2, 3])
    conf = str(slurm_environ.conf)
    assert [j.result() for j in jobs] == [(4, "0", conf), (9, "1", conf)]
    array = jobs[0].job_id.split("_")[0]
    assert [j.job_id for j in jobs] == [f"{array}_0", f"{array}_1"]
    assert slurm_environ.wait_jobs([array], timeout=30) == {f"{array}_0": "COMPLETED", f"{array}_1": "COMPLETED"}


def test_a_requeued_job_runs_again_from_the_start(slurm_cluster, tmp_path):
    """``scontrol requeue`` stops a running job, which then starts its script again with
    SLURM_RESTART_COUNT=1 (unset on the first run); the first run never reaches its end."""
    log = tmp_path / "runs.log"
    script = tmp_path / "job.sh"
    script.write_text(
        "#!/bin/sh\n"
        f'echo "start ${{SLURM_RESTART_COUNT:-unset}}" >> {log}\n'
        # the first run waits to be requeued (and ends by itself if it never is)
        'if [ -z "$SLURM_RESTART_COUNT" ]; then sleep 50; fi\n'
        f'echo "end ${{SLURM_RESTART_COUNT:-unset}}" >> {log}\n'
    )
    job = slurm_cluster.sbatch(f"--output={tmp_path}/slurm-%j.out", str(script))
    wait_for(lambda: log.exists() and log.read_text() == "start unset\n", 20, "first run started")
    slurm_cluster.requeue(job)
    assert slurm_cluster.wait_jobs([job], timeout=40) == {job: "COMPLETED"}
    assert log.read_text().splitlines() == ["start unset", "start 1", "end 1"]
    assert "Restarts=1 " in slurm_cluster.run(["scontrol", "show", "job", job]).stdout


def test_a_second_cluster_runs_beside_a_first_and_stops_cleanly(slurm_cluster, tmp_path):
    """A cluster started while another runs (such as a leftover of a killed run) takes other ports
    and its own munge socket, sees only its own jobs, and leaves no daemon or folder behind."""
    if missing_reason():
        pytest.skip(missing_reason())
    with local_slurm() as second:
        assert second.conf != slurm_cluster.conf
        job = second.sbatch("--job-name=on-second", f"--output={tmp_path}/out.txt", "--wrap", "echo second")
        assert second.wait_jobs([job], timeout=30) == {job: "COMPLETED"}
        assert (tmp_path / "out.txt").read_text() == "second\n"
        assert second.run(["squeue", "--states=all", "--noheader", "--format=%j"]).stdout.split() == ["on-second"]
        assert "on-second" not in slurm_cluster.run(["squeue", "--states=all", "--noheader", "--format=%j"]).stdout
        procs, root = dict(second.procs), second.root
        assert all(p.poll() is None for p in procs.values())
    assert sorted(procs) == ["munged", "slurmctld", "slurmd"]
    assert all(p.poll() is not None for p in procs.values())
    assert not root.exists()
