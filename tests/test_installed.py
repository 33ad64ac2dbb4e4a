"""snell_bench as an installed tool: the bundled files found from any folder, the ``--help`` page, the
``snell-bench`` command and its shell completion, the licence and citation files, and (slow) a
``pip install --target`` copy running the preview of the fox and the photo experiment from a folder
that is not the checkout."""

import json
import os
import shutil
import string
import subprocess
import sys
from importlib.resources import files
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from snell_bench.config import Job, compose, group_options
from snell_bench.config import help as snell_help
from snell_bench.utils.paths import PACKAGE_ROOT, candidates, data_path

try:
    import tomllib
except ImportError:  # Python 3.10: pytest's own TOML reader
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
CONF = REPO / "snell_bench" / "conf"
DATASETS = REPO / "snell_bench" / "datasets"
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
ENV = {**os.environ, "HF_HUB_OFFLINE": "1"}
ENV.pop("PYTHONPATH", None)

#: Small enough for a test, as tests/experiment/test_photo.py runs the photo: the images keep the
#: frame's own size, the panorama, steps and reference samples shrink.
CHEAP = ["warps.pano_height=64", "warps.cache_dir=null", "sampler.steps=4", "reference.spp=2"]
#: The preview of the fox at a reduced size.
SMALL_PREVIEW = ["scene.width=320", "scene.height=192", "scene.supersample=1", "warps.pano_height=64"]


def experiment_names() -> list[str]:
    """The shipped experiments, from the files on disk."""
    return sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))


def run(args, cwd, env=ENV, timeout=300, **kw) -> subprocess.CompletedProcess:
    """``args`` run in ``cwd``; fails the test with the output when it exits non-zero."""
    out = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout, **kw)
    assert out.returncode == 0, f"{args} exited {out.returncode}:\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}"
    return out


# --- files a config names -------------------------------------------------------------------------


def test_a_bundled_path_is_found_inside_the_package_from_another_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    found = data_path("datasets/meshes/fox.ply", "object.path", "mesh file")
    assert Path(found) == PACKAGE_ROOT / "datasets" / "meshes" / "fox.ply"
    assert Path(found).read_bytes() == files("snell_bench").joinpath("datasets/meshes/fox.ply").read_bytes()


def test_a_file_in_the_working_folder_shadows_the_bundled_one(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    own = tmp_path / "datasets" / "meshes" / "fox.ply"
    own.parent.mkdir(parents=True)
    own.write_bytes(b"ply\n")
    assert data_path("datasets/meshes/fox.ply", "object.path") == "datasets/meshes/fox.ply"
    assert candidates("datasets/meshes/fox.ply") == [own, PACKAGE_ROOT / "datasets" / "meshes" / "fox.ply"]


def test_a_missing_file_names_every_place_looked_and_the_key(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(FileNotFoundError) as err:
        data_path("datasets/meshes/foxx.ply", "object.path", "mesh file")
    message = str(err.value)
    assert message.startswith("object.path='datasets/meshes/foxx.ply': no such mesh file")
    assert str(tmp_path / "datasets" / "meshes" / "foxx.ply") in message
    assert str(PACKAGE_ROOT / "datasets" / "meshes" / "foxx.ply") in message
    assert "set object.path to an existing mesh file" in message
    with pytest.raises(
        FileNotFoundError, match=r"scene\.image='/no/such\.png': no such image file \(looked for /no/such\.png\)"
    ):
        data_path("/no/such.png", "scene.image", "image file")


def test_every_file_a_shipped_config_names_ships_in_the_package(tmp_path, monkeypatch):
    """From a folder without ``datasets/``, each object's mesh and each photo scene's image and
    depth resolve to a file inside the package, the same bytes as the checkout's copy."""
    monkeypatch.chdir(tmp_path)
    named = []
    for obj in group_options("object"):
        named.append(("object.path", compose([f"object={obj}"]).object.path))
    for scene in group_options("scene"):
        sc = compose([f"scene={scene}"]).scene
        named += [("scene.image", sc.image), ("scene.depth", sc.depth)]
    named = [(key, value) for key, value in named if value]
    assert {v for _, v in named} >= {"datasets/meshes/fox.ply", "datasets/rgbd/tum_fr3_office/color.png"}
    for key, value in named:
        found = Path(data_path(value, key))
        assert found.is_relative_to(PACKAGE_ROOT), (key, value, found)
        assert found.read_bytes() == (DATASETS / found.relative_to(PACKAGE_ROOT / "datasets")).read_bytes()


# --- the help page ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def help_page(tmp_path_factory) -> str:
    """``python -m snell_bench scene=kitchen --help`` from a folder that is not the checkout."""
    cwd = tmp_path_factory.mktemp("help")
    return run([sys.executable, "-m", "snell_bench", "scene=kitchen", "--help"], cwd).stdout


def section(page: str, title: str) -> str:
    """The lines of ``== title ... ==`` up to the next section."""
    start = page.index(f"== {title}")
    return page[start : page.index("\n== ", start + 1)]


def entries(text: str) -> dict[str, str]:
    """``name -> text`` of a section's two-column entries (wrapped lines joined)."""
    out, name = {}, None
    for line in text.splitlines()[1:]:
        if line.startswith("  ") and not line.startswith("   "):
            name, _, rest = line.strip().partition(" ")
            out[name] = rest.strip()
        elif line.strip() and name is not None:
            out[name] += " " + line.strip()
    return out


def test_help_lists_every_job_with_its_line(help_page):
    jobs = section(help_page, "Jobs")
    assert "now: preview" in jobs.splitlines()[0]
    assert entries(jobs) == {job.value: snell_help.JOB_LINES[job] for job in Job}


def test_help_lists_every_shipped_experiment_with_its_first_sentence(help_page):
    listed = entries(section(help_page, "Experiments"))
    assert list(listed) == experiment_names()
    for name, described in listed.items():
        lines = (CONF / "experiment" / f"{name}.yaml").read_text().splitlines()
        comment = " ".join(x.lstrip("#").strip() for x in lines if x.startswith("# ") and "@package" not in x)
        assert described.endswith(".") and comment.startswith(described), name


def test_help_lists_the_config_groups_without_schema_nodes(help_page):
    assert "base_" not in help_page
    groups = {k: [o.strip() for o in v.split(",")] for k, v in entries(section(help_page, "Config groups")).items()}
    for folder in sorted(
        p for p in CONF.iterdir() if p.is_dir() and p.name not in ("experiment", "hydra", "scene_source")
    ):
        assert [o.rstrip("*") for o in groups[folder.name]] == sorted(p.stem for p in folder.glob("*.yaml")), folder
    assert "kitchen*" in groups["scene"] and "living_room" in groups["scene"]
    assert sum(o.endswith("*") for o in groups["scene"]) == 1
    launchers = {o.rstrip("*") for o in groups["hydra/launcher"]}
    assert {p.stem for p in (CONF / "hydra" / "launcher").glob("*.yaml")} | {"basic"} <= launchers


def test_help_shows_examples_and_where_to_look_next(help_page):
    for text in (
        "== Examples ==",
        "snell-bench +experiment=smoke",
        "--cfg job",
        "--info",
        "--hydra-help",
        "-sc install=bash",
    ):
        assert text in help_page


def test_hydra_help_is_hydras_own(tmp_path):
    page = run([sys.executable, "-m", "snell_bench", "--hydra-help"], tmp_path).stdout
    assert page.startswith("Hydra (") and "hydra/launcher" in page and "== Jobs" not in page


def test_every_job_has_a_help_line():
    assert set(snell_help.JOB_LINES) == set(Job)


def test_a_dollar_in_a_list_survives_hydras_template(monkeypatch):
    monkeypatch.setitem(snell_help.JOB_LINES, Job.plan, "costs $5 and ${x}")
    text = string.Template(snell_help.help_section("jobs")).substitute()
    assert "costs $5 and ${x}" in text


def test_an_unknown_help_list_names_the_known_ones():
    with pytest.raises(
        ValueError, match=r"snell_help:commands\} is unknown; use one of \['experiments', 'groups', 'jobs'\]"
    ):
        snell_help.help_section("commands")


@pytest.mark.parametrize(
    "text, sentence",
    [
        ("# @package _global_\n# A fast look: half size. More here.\njob: grid\n", "A fast look: half size."),
        ("# IOR 1.5 and\n# 2.418, in one scene.\n", "IOR 1.5 and 2.418, in one scene."),
        ("# no full stop\njob: grid\n", "no full stop"),
        ("job: grid\n# a later comment.\n", ""),
    ],
)
def test_first_sentence_of_a_leading_comment(text, sentence):
    assert snell_help.first_sentence(text) == sentence


def test_completion_answers_for_the_command(tmp_path):
    """Hydra's query mode, as the bash function ``snell-bench -sc install=bash`` installs calls it."""
    line = "snell-bench object=f"
    env = {**ENV, "COMP_LINE": line, "COMP_POINT": str(len(line))}
    out = run([sys.executable, "-m", "snell_bench", "-sc", "query=bash"], tmp_path, env=env).stdout
    assert out.split() == ["object=fox"]


# --- licence and citation ---------------------------------------------------------------------------


def test_the_licence_is_mit_as_pyproject_says():
    """The code is MIT (LICENSE); the bundled data's licences are in their SOURCES.md, which ship as
    licence files beside it (the TUM RGB-D frame is CC BY 4.0)."""
    text = (REPO / "LICENSE").read_text()
    assert PYPROJECT["project"]["license"] == "MIT AND CC-BY-4.0"
    assert PYPROJECT["project"]["license-files"] == ["LICENSE", "snell_bench/datasets/*/SOURCES.md"]
    assert "CC BY 4.0" in (REPO / "snell_bench/datasets/rgbd/SOURCES.md").read_text()
    assert text.startswith("MIT License\n\nCopyright (c) 2026 snell_bench contributors\n")
    assert 'THE SOFTWARE IS PROVIDED "AS IS", WITHOUT WARRANTY OF ANY KIND' in text


def test_citation_file_has_the_required_keys_and_cites_the_paper():
    cff = yaml.safe_load((REPO / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0"
    for key in ("cff-version", "message", "title", "authors"):
        assert cff[key], key
    assert cff["type"] == "software"
    assert (
        str(cff["version"]) == PYPROJECT["project"]["version"]
        and " AND ".join(cff["license"]) == PYPROJECT["project"]["license"]
    )
    for ref in cff["references"]:
        for key in ("type", "title", "authors"):
            assert ref[key], (ref.get("title"), key)
    paper = next(r for r in cff["references"] if r["type"] == "conference-paper")
    assert paper["title"] == "Refracting Reality: Generating Images with Realistic Transparent Objects"
    assert [(a["given-names"], a["family-names"]) for a in paper["authors"]] == [
        ("Yue", "Yin"),
        ("Enze", "Tao"),
        ("Dylan", "Campbell"),
    ]
    assert paper["year"] == 2026 and paper["url"] == "https://arxiv.org/abs/2511.17340"
    code = next(r for r in cff["references"] if r["type"] == "software")
    assert code["repository-code"] == PYPROJECT["project"]["urls"]["Authors' code"]


# --- the installed package (slow) -------------------------------------------------------------------

#: Folders of the checkout that are outputs or environments, not part of the package's sources.
_NOT_SOURCES = {".venv", ".git", "runs", "reports", "build", "site", "multirun", "outputs", "mlruns", "wandb"}


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """``pip install --no-deps --target DIR`` of a copy of the checkout (building writes ``build/``
    and ``*.egg-info`` beside the sources); returns DIR."""
    root = tmp_path_factory.mktemp("installed")
    src, site = root / "src", root / "site"

    def skip(folder, names):
        top = Path(folder) == REPO
        return [
            n
            for n in names
            if (top and (n in _NOT_SOURCES or n.endswith(".egg-info"))) or n.endswith("_cache") or n == "__pycache__"
        ]

    shutil.copytree(REPO, src, ignore=skip)
    pip = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--target", str(site)]
    run([*pip, str(src)], root, timeout=600)
    return site


@pytest.fixture
def elsewhere(installed, tmp_path) -> tuple[Path, dict]:
    """A folder that is not the checkout, and an environment importing the installed copy."""
    return tmp_path, {**ENV, "PYTHONPATH": str(installed)}


@pytest.mark.slow
def test_the_installed_tree_holds_the_datasets_configs_and_licence(installed):
    shipped = sorted(p.relative_to(DATASETS) for p in DATASETS.rglob("*") if p.is_file())
    assert {p.suffix for p in shipped} >= {".md", ".ply", ".obj", ".png"}
    for rel in shipped:
        assert (installed / "snell_bench" / "datasets" / rel).read_bytes() == (DATASETS / rel).read_bytes(), rel
    assert (installed / "snell_bench" / "conf" / "hydra" / "help" / "snell_bench.yaml").is_file()
    assert (installed / "snell_bench" / "conf" / "experiment" / "smoke.yaml").is_file()
    (dist,) = installed.glob("snell_bench-*.dist-info")
    assert (dist / "licenses" / "LICENSE").read_bytes() == (REPO / "LICENSE").read_bytes()
    assert "snell-bench = snell_bench.__main__:cli" in (dist / "entry_points.txt").read_text()


@pytest.mark.slow
def test_the_command_imports_the_installed_copy_and_composes_an_experiment(installed, elsewhere):
    cwd, env = elsewhere
    found = run([sys.executable, "-c", "import snell_bench; print(snell_bench.__file__)"], cwd, env=env).stdout
    assert found.strip() == str(installed / "snell_bench" / "__init__.py")
    out = run([str(installed / "bin" / "snell-bench"), "+experiment=smoke", "--cfg", "job"], cwd, env=env).stdout
    assert yaml.safe_load(out)["experiment_name"] == "smoke"


@pytest.mark.slow
def test_the_command_help_lists_jobs_and_experiments_and_no_schema_node(installed, elsewhere):
    cwd, env = elsewhere
    page = run([str(installed / "bin" / "snell-bench"), "--help"], cwd, env=env).stdout
    assert "base_" not in page
    assert list(entries(section(page, "Jobs"))) == [job.value for job in Job]
    assert list(entries(section(page, "Experiments"))) == experiment_names()
    assert "snell-bench -sc install=bash" in page  # Hydra's flags, for the command by its own name


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("bash") is None, reason="bash is not installed")
def test_bash_completion_of_the_installed_command(installed, elsewhere):
    """``eval "$(snell-bench -sc install=bash)"``, then the completion function as bash calls it on Tab."""
    cwd, env = elsewhere
    env = {**env, "PATH": f"{installed / 'bin'}{os.pathsep}{env['PATH']}"}
    script = """
    eval "$(snell-bench -sc install=bash)"
    complete -p snell-bench
    for COMP_LINE in "snell-bench object=f" "snell-bench +experiment=ph"; do
        COMP_POINT=${#COMP_LINE}; COMP_WORDS=($COMP_LINE); COMP_CWORD=$(( ${#COMP_WORDS[@]} - 1 ))
        hydra_bash_completion
        echo "reply: ${COMPREPLY[*]}"
    done
    """
    out = run(["bash", "-c", script], cwd, env=env).stdout
    assert "-F hydra_bash_completion snell-bench" in out
    assert [x for x in out.splitlines() if x.startswith("reply:")] == ["reply: object=fox", "reply: +experiment=photo"]


@pytest.mark.slow
def test_the_fox_preview_runs_from_another_folder_as_from_the_checkout(installed, elsewhere, tmp_path_factory):
    """``python -m snell_bench object=fox`` (the default job: the refraction preview) from the
    installed copy writes the same mask as the checkout's package: the same bundled mesh."""
    cwd, env = elsewhere
    args = [sys.executable, "-m", "snell_bench", "object=fox", *SMALL_PREVIEW, "warps.cache_dir=null"]
    run(args, cwd, env=env)
    out = cwd / "runs" / "preview" / "living_room-0" / "fox"
    assert not (cwd / "datasets").exists()
    assert yaml.safe_load((out / ".hydra" / "config.yaml").read_text())["object"]["path"] == "datasets/meshes/fox.ply"
    mask = np.asarray(Image.open(out / "mask.png")) > 0
    assert mask.shape == (192, 320) and mask.sum() > 0
    assert json.loads((out / "summary.json").read_text())["object"]["name"] == "fox"
    for name in ("preview.png", "composite.png", "warp.png", "I_minus.png", "panorama.png"):
        assert (out / name).is_file(), name

    reference = tmp_path_factory.mktemp("from_checkout")
    run(args, reference, env={**ENV, "PYTHONPATH": str(REPO)})
    assert np.array_equal(
        mask, np.asarray(Image.open(reference / "runs" / "preview" / "living_room-0" / "fox" / "mask.png")) > 0
    )


@pytest.mark.slow
def test_the_photo_experiment_runs_from_another_folder_on_the_bundled_frame(installed, elsewhere):
    """``python -m snell_bench +experiment=photo`` from the installed copy: both cells and the report,
    I⁻ the bundled photo pixel for pixel, the depth its 16-bit file / 5000."""
    cwd, env = elsewhere
    run([sys.executable, "-m", "snell_bench", "+experiment=photo", *CHEAP], cwd, env=env, timeout=600)
    summary = json.loads((cwd / "runs" / "photo" / "summary.json").read_text())
    assert (summary["cells"], summary["ok"], summary["failed"]) == (2, 2, 0)
    group = cwd / "runs" / "photo" / "tum_office-0" / "sphere"
    for method in ("snellcaster", "t2i"):
        for name in ("image.png", "reference.png", "mask.png", "metrics.json"):
            assert (group / method / name).is_file(), (method, name)
    assert (cwd / "reports" / "photo" / "method_table.md").is_file()

    frame = DATASETS / "rgbd" / "tum_fr3_office"
    photo = np.asarray(Image.open(frame / "color.png").convert("RGB"))
    assert np.array_equal(np.asarray(Image.open(group / "_inputs" / "I_minus.png").convert("RGB")), photo)
    raw = np.asarray(Image.open(frame / "depth.png")).astype(np.float64)
    depth = np.load(group / "_inputs" / "depth.npy")
    assert np.array_equal(np.isnan(depth), raw == 0)
    # stored as float32: within one unit in the last place (2^-23 relative) of raw / 5000
    valid = raw > 0
    np.testing.assert_allclose(depth[valid], raw[valid] / 5000, rtol=2.0**-23, atol=0)
