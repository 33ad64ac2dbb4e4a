"""Checks before Hydra creates a folder or a log file: a bad setting or an unwritable folder fails
with its key named, and nothing is created."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from snell_bench.config.preflight import check_writable

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
        (["+experiment=tradeoff", "tradeoff.scenes=[nope]"], "tradeoff.scenes: unknown scene 'nope'"),
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
