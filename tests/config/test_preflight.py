"""Checks before Hydra creates a folder or a log file: a bad setting or an unwritable folder fails
with its key named, and nothing is created."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from snell_bench.config import compose
from snell_bench.config.preflight import check_writable, output_folder_problems, output_folders

REPO = Path(__file__).resolve().parents[2]


def run_cli(tmp_path, *args):
    env = dict(os.environ, HF_HUB_OFFLINE="1")
    return subprocess.run(
        [sys.executable, "-m", "snell_bench", *args], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300
    )


@pytest.mark.parametrize(
    "args,expected",
    [
        (["job=preview", "+warps.max_bounce=1"], "warps.max_bounce: no setting has this name"),
        (["job=preview", "+object.iorr=3"], "did you mean object.ior?"),
        (["job=preview", "scene.width=0"], "scene.width=0: must be a positive multiple"),
        (["+experiment=smoke", "grid.methods=[nope]"], "grid.methods: unknown method 'nope'"),
        (["+experiment=tradeoff", "grid.scenes=[nope]"], "grid.scenes: unknown scene 'nope'"),
        (["+experiment=smoke", "warps.pano_height=100"], "use warps.pano_height=96 (96x192) or warps.pano_height=104"),
    ],
)
def test_a_bad_setting_fails_before_any_folder_is_created(tmp_path, args, expected):
    res = run_cli(tmp_path, *args, "hydra.run.dir=out/run", "runs_dir=out/runs", "reports_dir=out/reports")
    assert res.returncode != 0 and expected in res.stderr, res.stderr[-2000:]
    assert not (tmp_path / "out").exists()


def test_an_unwritable_output_folder_names_its_key(tmp_path):
    (tmp_path / "blocked").write_text("a file, not a folder")
    res = run_cli(tmp_path, "job=preview", "hydra.run.dir=blocked/run")
    assert res.returncode != 0
    assert "hydra.run.dir='blocked/run'" in res.stderr and "is a file, not a folder" in res.stderr, res.stderr[-2000:]
    assert "Unable to configure handler" not in res.stderr
    res = run_cli(tmp_path, "+experiment=smoke", "hydra.run.dir=out/run", "runs_dir=blocked/runs")
    assert res.returncode != 0 and "runs_dir='blocked/runs'" in res.stderr, res.stderr[-2000:]
    assert not (tmp_path / "out").exists()


def test_a_read_only_folder_names_its_key(tmp_path, monkeypatch):
    ro = tmp_path / "ro"
    ro.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if Path(p) == ro else real(p, mode))
    with pytest.raises(
        PermissionError, match=r"runs_dir='.*ro/runs': the folder would be created in .*ro, which is not writable"
    ):
        check_writable(ro / "runs", "runs_dir")
    with pytest.raises(PermissionError, match="set hydra.run.dir to a writable folder"):
        check_writable(ro, "hydra.run.dir")
    check_writable(tmp_path / "new" / "deeper", "runs_dir")  # creatable: fine, and nothing is created
    assert not (tmp_path / "new").exists()


def test_a_folder_the_permission_bits_allow_but_no_file_can_be_created_in_is_refused(tmp_path, monkeypatch):
    """os.access reads the permission bits (root passes them everywhere, /proc included); the
    check creates and removes a probe file, and leaves the folder as it was."""
    import tempfile

    folder = tmp_path / "looks_writable"
    folder.mkdir()
    check_writable(folder / "reports", "reports_dir")
    assert list(folder.iterdir()) == []  # the probe is gone

    def refuse(*args, **kwargs):
        raise FileNotFoundError(2, "No such file or directory")

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(
        PermissionError, match=r"reports_dir='.*looks_writable/reports': the folder would be created in"
    ):
        check_writable(folder / "reports", "reports_dir")


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs procfs")
def test_procfs_is_not_writable_even_for_root():
    with pytest.raises(PermissionError, match=r"reports_dir='/proc/snell_bench/x': .* not writable"):
        check_writable("/proc/snell_bench/x", "reports_dir")


@pytest.mark.parametrize(
    "overrides, keys",
    [
        (["job=preview"], ["warps.cache_dir"]),
        (["+experiment=smoke"], ["runs_dir", "reports_dir", "warps.cache_dir"]),
        (["+experiment=smoke", "grid.report=false", "warps.cache_dir=null"], ["runs_dir"]),
        (["+experiment=smoke", "tracker=tensorboard"], ["runs_dir", "reports_dir", "warps.cache_dir", "tracker.dir"]),
        (["+experiment=smoke", "tracker=mlflow"], ["runs_dir", "reports_dir", "warps.cache_dir", "tracker.uri"]),
        (["+experiment=tradeoff", "scene.source=generated"], ["runs_dir", "reports_dir", "scene.cache_dir"]),
        (["+experiment=tradeoff", "grid.report=false"], ["runs_dir"]),  # its warps are traced, never cached
        (["job=report"], ["reports_dir"]),
        (["job=plan"], []),
    ],
)
def test_every_folder_a_job_writes_is_checked(overrides, keys):
    assert [key for key, _, _ in output_folders(compose(overrides))] == keys


def test_unwritable_caches_and_tracker_folders_name_their_keys(tmp_path):
    (tmp_path / "file").write_text("")
    cfg = compose(
        [
            "+experiment=smoke",
            "tracker=tensorboard",
            f"warps.cache_dir={tmp_path}/file/w",
            f"tracker.dir={tmp_path}/file/t",
        ]
    )
    text = "\n".join(output_folder_problems(cfg))
    assert "warps.cache_dir=" in text and "tracker.dir=" in text and "is a file, not a folder" in text, text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs procfs")
def test_an_unwritable_reports_dir_stops_the_run_before_any_work(tmp_path):
    res = run_cli(tmp_path, "+experiment=smoke", "hydra.run.dir=out/run", "runs_dir=out/runs", "reports_dir=/proc/x")
    assert res.returncode != 0, res.stderr[-2000:]
    assert "reports_dir='/proc/x' (the folder /proc/x/smoke)" in res.stderr and "reports_dir=/tmp/" in res.stderr
    assert "Traceback" not in res.stderr
    assert list(tmp_path.iterdir()) == []
