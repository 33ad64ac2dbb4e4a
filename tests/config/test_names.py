"""Names that become folder names (``experiment_name``, ``scene.name``, ``object.name``, grid object
specs, sweep setting labels) are one path component: nothing is written outside ``runs_dir`` and
``reports_dir``. Spaces and other Unicode characters are valid names."""

import os
import subprocess
import sys

import pytest
from omegaconf import OmegaConf

from snell_bench.config import ConfigError, check_config, compose
from snell_bench.config.names import NAME_MAX, folder_name_problem, setting_slug


def problems(cfg) -> str:
    with pytest.raises(ConfigError) as e:
        check_config(cfg)
    return str(e.value)


@pytest.mark.parametrize(
    "value, why",
    [
        ("../../x", "a folder name, not a path"),
        ("/tmp/elsewhere", "not an absolute path"),
        ("a/b", "cannot hold '/'"),
        ("a\\b", "cannot hold '/' or '\\\\'"),
        ("", "must not be empty"),
        ("   ", "must not be empty"),
        (".", "is the current or the parent folder"),
        ("..", "is the current or the parent folder"),
        ("-rf", "must not start with '-'"),
        ("a\x00b", "NUL"),
        ("a\nb", "control characters"),
        ("x" * (NAME_MAX - 3), "longer than the 255 bytes"),
        ("é" * 126, "longer than the 255 bytes"),  # 252 bytes in UTF-8, plus '.log'
    ],
)
def test_an_experiment_name_that_is_not_a_folder_name_is_refused(value, why):
    cfg = compose(["+experiment=smoke"])
    cfg.experiment_name = value  # some of these cannot be typed as an override
    text = problems(cfg)
    assert text.startswith(f"experiment_name={value[:40]!r}") and why in text, text
    assert "e.g. experiment_name=my_run" in text, text


def test_names_with_spaces_and_unicode_are_valid():
    check_config(compose(["+experiment=smoke", 'experiment_name="my run é 実験"']))
    assert folder_name_problem("x" * (NAME_MAX - 4), "experiment_name", suffix=".log") is None


def test_the_length_limit_is_the_file_systems(tmp_path):
    """The longest name accepted makes a log file the file system takes; one byte more it refuses."""
    if os.pathconf(tmp_path, "PC_NAME_MAX") != NAME_MAX:
        pytest.skip("this file system's name limit is not 255 bytes")
    longest = "é" * ((NAME_MAX - 4) // 2) + "x" * ((NAME_MAX - 4) % 2)  # 251 bytes + '.log' = 255
    assert folder_name_problem(longest, "experiment_name", suffix=".log") is None
    (tmp_path / f"{longest}.log").write_text("")
    assert folder_name_problem(longest + "x", "experiment_name", suffix=".log") is not None
    with pytest.raises(OSError):
        (tmp_path / f"{longest}x.log").write_text("")


@pytest.mark.parametrize(
    "overrides, expected",
    [
        (["scene.name=../up"], "scene.name='../up': a folder name, not a path"),
        (["object.name=/abs"], "object.name='/abs': a folder name, not an absolute path"),
        (["object.name=''"], "object.name='': must not be empty"),
        (["+experiment=smoke", "grid.objects=[sphere:../x]"], "grid.objects: entry 'sphere:../x'"),
        (
            [
                "+experiment=tradeoff",
                "+grid.axes.long={" + "a" * 260 + ": ['sampler.steps=4']}",
                "grid.only=[long]",
            ],
            "grid.axes.long: the setting 'long=aaaa",
        ),
    ],
)
def test_every_name_that_becomes_a_folder_is_checked(overrides, expected):
    assert expected in problems(compose(overrides))


def test_a_setting_slug_is_one_folder_name():
    for label in ("preset:fast", "steps=../../x", "a/b", "res=é x"):
        assert folder_name_problem(setting_slug(label), "label") is None, setting_slug(label)


def run_cli(cwd, *args):
    env = dict(os.environ, HF_HUB_OFFLINE="1")
    return subprocess.run(
        [sys.executable, "-m", "snell_bench", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )


def test_a_path_as_experiment_name_writes_nothing(tmp_path):
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    res = run_cli(work, "+experiment=smoke", "experiment_name=../../escaped", "runs_dir=runs", "reports_dir=reports")
    assert res.returncode != 0, res.stderr[-2000:]
    assert "experiment_name='../../escaped': a folder name, not a path" in res.stderr, res.stderr[-2000:]
    assert "Traceback" not in res.stderr
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == ["a", "a/b"]


@pytest.mark.slow
def test_a_unicode_experiment_name_runs_end_to_end(tmp_path):
    """A quoted name with spaces and accents names the run's, the report's and the log's folders."""
    name = "my run é"
    res = run_cli(
        tmp_path,
        "+experiment=smoke",
        f'experiment_name="{name}"',
        "grid.scenes=[living_room]",
        "grid.methods=[snellcaster]",
        "scene.width=64",
        "scene.height=32",
        "warps.pano_height=32",
        "reference.spp=8",
        "sampler.steps=2",
        "sampler.levels=2",
        "runs_dir=runs",
        "reports_dir=reports",
    )
    assert res.returncode == 0, res.stderr[-3000:]
    assert (tmp_path / "runs" / name / "living_room-0" / "sphere" / "snellcaster" / "metrics.json").is_file()
    assert (tmp_path / "reports" / name / "index.html").is_file()
    assert list((tmp_path / "runs" / name / "logs").glob(f"*/{name}.log"))
    summary = OmegaConf.load(tmp_path / "runs" / name / "summary.json")
    assert summary.ok == 1
