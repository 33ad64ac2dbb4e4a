"""Experiment tracking (tracker=mlflow | tensorboard | wandb): each finished cell logged once, read
back with each library's own reader and compared with the cell's metrics.json, and the results
unchanged by tracking."""

import io
import json
import logging
import multiprocessing
import os
import re
import struct
import subprocess
import sys
import types
import zlib
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf
from PIL import Image

from snell_bench.config import ConfigError, check_config, compose
from snell_bench.experiment.tracking import (
    IMAGE_FILES,
    METRIC_SECTIONS,
    TRACKERS,
    MlflowTracker,
    Tracker,
    WandbTracker,
    cell_metrics,
    log_cell,
    make_tracker,
)
from tests.experiment.test_runner import REPO, TINY, make_cfg, metrics_of

#: A sphere with Snellcaster (panorama, reference) and the text-to-image baseline, a cell skipped
#: here (a GPU model) and a fox whose open mesh fails its cells: every status a tracker logs.
GRID = [
    "grid.scenes=[living_room]",
    "grid.objects=[sphere,fox]",
    "grid.methods=[snellcaster,t2i,flux2_dev]",
    "grid.report=false",
]


def open_mesh(tmp_path: Path) -> Path:
    """A box without its lid: the fox cells that build it fail (not watertight)."""
    import trimesh

    path = tmp_path / "open_box.ply"
    box = trimesh.creation.box()
    box.update_faces(box.face_normals[:, 2] < 0.5)
    box.export(path)
    return path


def grid_cfg(tmp_path: Path, tracker: str, *extra: str):
    return make_cfg(tmp_path, [*GRID, f"object.path={open_mesh(tmp_path)}", f"tracker={tracker}", *extra])


def run(cfg) -> dict:
    from snell_bench.experiment.runner import run_grid

    return run_grid(cfg)


def records_of(tmp_path: Path) -> dict[str, dict]:
    """``{cell name: metrics.json}`` of the smoke experiment under ``tmp_path``."""
    return metrics_of(tmp_path / "runs" / "smoke")


def float32_tolerance(value: float) -> float:
    """How far a float64 may move when stored as float32: rounding to nearest with a 24-bit
    significand changes a normal number by at most half a unit in the last place,
    ``|v| * 2**-24`` (0 is exact)."""
    return abs(value) * 2.0**-24


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    """The grid without a tracker."""
    tmp = tmp_path_factory.mktemp("none")
    summary = run(grid_cfg(tmp, "none"))
    return tmp, summary


@pytest.fixture(scope="module")
def mlflow_grid(tmp_path_factory):
    """The same grid with tracker=mlflow, and the store's client."""
    pytest.importorskip("mlflow")
    from mlflow import MlflowClient

    tmp = tmp_path_factory.mktemp("mlflow")
    summary = run(grid_cfg(tmp, "mlflow"))
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MLFLOW_ALLOW_FILE_STORE", "true")  # MLflow 3 opens a file store on request only
        client = MlflowClient(tracking_uri=(tmp / "runs" / "smoke" / "mlruns").as_uri())
    return tmp, summary, client


def mlflow_runs(client) -> dict[str, object]:
    exp = client.get_experiment_by_name("smoke")
    runs = client.search_runs([exp.experiment_id], max_results=1000)
    names = [r.info.run_name for r in runs]
    assert len(names) == len(set(names)), f"a cell logged twice: {sorted(names)}"
    return {r.info.run_name: r for r in runs}


# ---------------------------------------------------------------------------- MLflow
def test_mlflow_logs_one_run_per_cell_with_its_exact_metrics(mlflow_grid):
    tmp, summary, client = mlflow_grid
    records = records_of(tmp)
    runs = mlflow_runs(client)
    assert sorted(runs) == sorted(records) and len(records) == 6
    assert summary["tracker"]["runs"] == 6 and summary["tracker"]["failures"] == 0
    for name, rec in records.items():
        logged = runs[name].data.metrics
        expected = {}
        for section in METRIC_SECTIONS:  # every number of the record, read independently of the tracker
            for key, value in (rec.get(section) or {}).items():
                if isinstance(value, (int, float)) and not isinstance(value, bool):
                    expected[f"{section}/{key}"] = value
        for key, value in expected.items():
            assert logged[key] == value, (name, key)  # MLflow keeps float64: exact
        for key, value in (rec.get("metrics") or {}).items():
            if value is None:
                assert f"metrics/{key}" not in logged
        assert len(logged) == len(cell_metrics(rec))


def test_mlflow_params_tags_and_status(mlflow_grid):
    tmp, _, client = mlflow_grid
    records = records_of(tmp)
    runs = mlflow_runs(client)
    for name, rec in records.items():
        run_ = runs[name]
        params, tags = run_.data.params, run_.data.tags
        # the run's overrides, as the cell's config.yaml recorded them
        saved = OmegaConf.load(tmp / "runs" / "smoke" / name / "config.yaml")
        assert params["scene.width"] == "160" == str(saved.scene.width)
        assert params["sampler.steps"] == str(saved.sampler.steps) and params["reference.spp"] == "4"
        assert params["method.name"] == rec["method"] and params["seed"] == "0"
        assert params["object.ior"] == str(saved.object.ior) and params["model.name"] == rec["model"]
        assert "tracker.name" not in params and "grid.methods" not in params  # not result settings
        for key in ("status", "scene", "variation", "object", "method", "model", "recipe"):
            assert tags[key] == str(rec[key]), (name, key)
        assert tags["seed"] == "0" and tags["experiment"] == "smoke"
        assert run_.info.status == ("FAILED" if rec["status"] == "failed" else "FINISHED")
        if rec["status"] != "ok":
            assert tags["reason"] == rec["reason"] and rec["reason"] in tags["mlflow.note.content"]
        for metric, why in (rec.get("missing") or {}).items():
            assert tags[f"missing.{metric}"] == why
    statuses = {rec["status"] for rec in records.values()}
    assert {"ok", "failed"} <= statuses  # the fox's open mesh fails
    assert "not watertight" in runs["living_room-0/fox/t2i"].data.tags["reason"]


def test_mlflow_artifacts_are_the_cells_images(mlflow_grid):
    tmp, _, client = mlflow_grid
    runs = mlflow_runs(client)
    for name, rec in records_of(tmp).items():
        folder = tmp / "runs" / "smoke" / name
        have = sorted(f for f in IMAGE_FILES if (folder / f).is_file())
        listed = sorted(Path(a.path).name for a in client.list_artifacts(runs[name].info.run_id, "images"))
        assert listed == have, name
        if rec["status"] == "ok":
            assert {"image.png", "reference.png", "mask.png"} <= set(have)
        if not have:  # a cell that failed before its image
            continue
        dst = tmp / "download" / name
        dst.mkdir(parents=True)
        local = Path(client.download_artifacts(runs[name].info.run_id, "images", str(dst)))
        for f in have:
            assert (local / f).read_bytes() == (folder / f).read_bytes()
    assert "panorama.png" in [
        Path(a.path).name for a in client.list_artifacts(runs["living_room-0/sphere/snellcaster"].info.run_id, "images")
    ]


def test_tracking_changes_no_result(baseline, mlflow_grid):
    """Every cell's scores, status and image bytes are those of the run without a tracker."""
    none_tmp, none_summary = baseline
    tmp, summary, _ = mlflow_grid
    a, b = records_of(none_tmp), records_of(tmp)
    assert sorted(a) == sorted(b)
    for name in a:
        assert b[name]["status"] == a[name]["status"] and b[name].get("metrics") == a[name].get("metrics"), name
        image = Path("runs", "smoke", name, "image.png")
        if (none_tmp / image).is_file():
            assert (tmp / image).read_bytes() == (none_tmp / image).read_bytes(), name
    for key in ("ok", "failed", "skipped", "cached"):
        assert summary[key] == none_summary[key]


def test_a_resumed_grid_logs_nothing_new(mlflow_grid, baseline):
    """The sphere's cells are finished (ok or skipped): run again, none is computed or logged (the
    fox's failed cells would be computed, and logged, again)."""
    tmp, _, client = mlflow_grid
    before = {r.info.run_id for r in mlflow_runs(client).values()}
    again = run(grid_cfg(tmp, "mlflow", "grid.objects=[sphere]"))
    assert again["cached"] == 3 and again["ok"] == again["failed"] == 0 and again["tracker"]["runs"] == 0
    assert {r.info.run_id for r in mlflow_runs(client).values()} == before
    # cells computed without a tracker are finished with one too (the tracker is no result setting)
    none_tmp, _ = baseline
    resumed = run(grid_cfg(none_tmp, "mlflow", "grid.objects=[sphere]"))
    assert resumed["cached"] == 3 and resumed["tracker"]["runs"] == 0


def test_model_major_order_and_prefetch_workers_log_each_cell_once(tmp_path, monkeypatch):
    """Cells sampled ahead in model-major order, groups prepared by a worker process: each cell is
    logged once, by the process that finishes it, with its record's scores."""
    pytest.importorskip("mlflow")
    from mlflow import MlflowClient

    grid = ["grid.methods=[snellcaster,t2i]", "grid.report=false", "models.memory_gb=1e-9", "grid.prefetch=1"]
    summary = run(make_cfg(tmp_path, [*grid, "tracker=mlflow"]))
    assert summary["order"] == "model-major" and summary["prefetch"]["ahead"] == 1
    records = records_of(tmp_path)
    assert len(records) == 4 and all(r["status"] == "ok" for r in records.values())
    monkeypatch.setenv("MLFLOW_ALLOW_FILE_STORE", "true")
    runs = mlflow_runs(MlflowClient(tracking_uri=(tmp_path / "runs" / "smoke" / "mlruns").as_uri()))
    assert sorted(runs) == sorted(records)
    for name, rec in records.items():
        assert runs[name].data.metrics["metrics/psnr"] == rec["metrics"]["psnr"]


def test_concurrent_processes_share_one_experiment(tmp_path):
    """Processes that start at once on a new file store find or create one experiment."""
    pytest.importorskip("mlflow")
    uri = (tmp_path / "mlruns").as_uri()
    ctx = multiprocessing.get_context("fork")
    barrier, queue = ctx.Barrier(4), ctx.Queue()
    procs = [ctx.Process(target=_open_store, args=(uri, barrier, queue)) for _ in range(4)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=120)
    assert all(p.exitcode == 0 for p in procs)
    ids = {queue.get(timeout=5) for _ in procs}
    assert len(ids) == 1
    metas = [p for p in (tmp_path / "mlruns").glob("*/meta.yaml") if "name: race" in p.read_text()]
    assert len(metas) == 1


def _open_store(uri, barrier, queue):
    barrier.wait()
    queue.put(MlflowTracker("race", uri).experiment_id)


# ---------------------------------------------------------------------------- TensorBoard
@pytest.fixture(scope="module")
def tensorboard_grid(tmp_path_factory):
    pytest.importorskip("tensorboard")
    tmp = tmp_path_factory.mktemp("tensorboard")
    summary = run(make_cfg(tmp, ["grid.scenes=[living_room]", "grid.report=false", "tracker=tensorboard"]))
    return tmp, summary


def test_tensorboard_scalars_images_and_hparams(tensorboard_grid):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from tensorboard.plugins.hparams.plugin_data_pb2 import HParamsPluginData

    tmp, summary = tensorboard_grid
    records = records_of(tmp)
    assert sorted(records) == ["living_room-0/sphere/snellcaster", "living_room-0/sphere/t2i"]
    assert summary["tracker"]["runs"] == 2
    for name, rec in records.items():
        folder = tmp / "runs" / "smoke" / "tensorboard" / name
        assert len(list(folder.glob("events.out.tfevents.*"))) == 1
        acc = EventAccumulator(str(folder), size_guidance={"images": 0, "scalars": 0})
        acc.Reload()
        scalars = acc.Tags()["scalars"]
        for section in ("metrics", "timings_s", "model_calls"):
            for key, value in rec[section].items():
                if value is None:
                    assert f"{section}/{key}" not in scalars
                    continue
                (event,) = acc.Scalars(f"{section}/{key}")
                assert event.step == 0 and abs(event.value - value) <= float32_tolerance(value), (name, key)
        cell = tmp / "runs" / "smoke" / name
        images = acc.Tags()["images"]
        for f in IMAGE_FILES:
            tag = f"images/{Path(f).stem}"
            assert (tag in images) == (cell / f).is_file(), (name, tag)
            if tag in images:  # the PNG file itself
                (event,) = acc.Images(tag)
                assert event.encoded_image_string == (cell / f).read_bytes(), (name, tag)
                with Image.open(io.BytesIO(event.encoded_image_string)) as im:
                    assert (event.width, event.height) == im.size
        start = None
        for content in acc.PluginTagToContent("hparams").values():
            data = HParamsPluginData.FromString(content)
            if data.HasField("session_start_info"):
                start = data.session_start_info.hparams
        assert start["sampler.steps"].number_value == 8 and start["scene.width"].number_value == 160
        assert start["method.name"].string_value == rec["method"] and start["status"].string_value == "ok"


# ---------------------------------------------------------------------------- Weights & Biases
def wandb_records(path: Path):
    """The records of a W&B offline run's transaction log (``run-<id>.wandb``), parsed with W&B's
    own protobuf messages: a header (``:W&B``, 0xBEE1, version 0), then 32 KiB blocks of LevelDB-log
    chunks, each with a header (CRC-32 of its type and data, length, type: 1 whole, 2 first,
    3 middle, 4 last)."""
    from wandb.proto import wandb_internal_pb2

    data = path.read_bytes()
    assert struct.unpack("<4sHB", data[:7]) == (b":W&B", 0xBEE1, 0)
    pos, pending = 7, b""
    while pos + 7 <= len(data):
        left = 32768 - pos % 32768
        if left < 7:  # a block's tail too short for a header is padding
            pos += left
            continue
        crc, length, kind = struct.unpack("<IHB", data[pos : pos + 7])
        chunk = data[pos + 7 : pos + 7 + length]
        pos += 7 + length
        assert zlib.crc32(bytes([kind]) + chunk) == crc
        pending += chunk
        if kind in (1, 4):
            yield wandb_internal_pb2.Record.FromString(pending)
            pending = b""


def wandb_run(folder: Path) -> dict:
    """A W&B offline run folder read back: its run record, config, summary and exit code."""
    (log_file,) = folder.glob("run-*.wandb")
    out = {"config": {}, "summary": {}, "run": None, "exit_code": None}
    for rec in wandb_records(log_file):
        kind = rec.WhichOneof("record_type")
        if kind == "run":
            out["run"] = rec.run
        elif kind == "config":
            out["config"].update({u.key: json.loads(u.value_json) for u in rec.config.update})
        elif kind in ("summary", "history"):
            items = rec.summary.update if kind == "summary" else rec.history.item
            out["summary"].update({"/".join(u.nested_key) or u.key: json.loads(u.value_json) for u in items})
        elif kind == "exit":
            out["exit_code"] = rec.exit.exit_code
    return out


def test_wandb_offline_writes_one_run_folder_per_cell(tmp_path, monkeypatch):
    pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    monkeypatch.setenv("WANDB_DIR", str(tmp_path / "wandb_dir"))
    monkeypatch.setenv("WANDB_BASE_URL", "http://127.0.0.1:9")  # nothing listens: no server to reach
    summary = run(make_cfg(tmp_path, ["grid.scenes=[living_room]", "grid.report=false", "tracker=wandb"]))
    records = records_of(tmp_path)
    folders = sorted((tmp_path / "runs" / "smoke" / "wandb").glob("offline-run-*"))
    assert len(folders) == len(records) == 2 and summary["tracker"]["runs"] == 2
    seen = set()
    for folder in folders:
        logged = wandb_run(folder)
        name = logged["run"].display_name
        rec = records[name]
        seen.add(name)
        assert logged["run"].run_group == "smoke" and logged["run"].project == "snell_bench"
        assert "status:ok" in logged["run"].tags and f"method:{rec['method']}" in logged["run"].tags
        assert logged["exit_code"] == 0
        for section in ("metrics", "timings_s", "model_calls"):
            for key, value in rec[section].items():
                if value is not None:  # JSON keeps the float64's shortest repr: exact
                    assert logged["summary"][f"{section}/{key}"] == value, (name, key)
        assert logged["config"]["sampler.steps"] == 8 and logged["config"]["method.name"] == rec["method"]
        assert len(list((folder / "files" / "media" / "images").rglob("*.png"))) == len(
            [f for f in IMAGE_FILES if (tmp_path / "runs" / "smoke" / name / f).is_file()]
        )
    assert seen == set(records)


class FakeWandb(types.ModuleType):
    """A stand-in for the ``wandb`` module that records every call."""

    def __init__(self):
        super().__init__("wandb")
        self.calls = []

    def Settings(self, **kw):  # noqa: N802 - wandb's name
        return ("Settings", kw)

    def Image(self, path):  # noqa: N802 - wandb's name
        return ("Image", path)

    def init(self, **kw):
        self.calls.append(("init", kw))
        fake = self

        class Run:
            class config:  # noqa: N801 - wandb's attribute
                @staticmethod
                def update(d, allow_val_change=False):
                    fake.calls.append(("config", dict(d)))

            @staticmethod
            def log(d, step=None):
                fake.calls.append(("log", dict(d), step))

            @staticmethod
            def finish(exit_code=0):
                fake.calls.append(("finish", exit_code))

        return Run

    def teardown(self):
        self.calls.append(("teardown",))


def test_wandb_calls_with_a_recording_module(tmp_path, monkeypatch):
    from snell_bench.experiment.cells import Cell

    fake = FakeWandb()
    monkeypatch.setitem(sys.modules, "wandb", fake)
    tracker = WandbTracker("exp", str(tmp_path), project="proj")
    folder = tmp_path / "cell"
    folder.mkdir()
    Image.fromarray(np.zeros((4, 6, 3), np.uint8)).save(folder / "image.png")
    cfg = compose(["scene.width=160", "scene.height=96"])
    ok = {"status": "ok", "method": "t2i", "scene": "kitchen", "metrics": {"psnr": 21.5, "lpips": None}}
    ok["missing"] = {"lpips": "no weights"}
    failed = {"status": "failed", "method": "t2i", "reason": "ValueError: broken"}
    assert log_cell(tracker, Cell("kitchen-0/sphere/t2i", folder, cfg, {}), ok)
    assert log_cell(tracker, Cell("kitchen-0/sphere/no", folder, cfg, {}), failed)
    tracker.close()
    inits = [c[1] for c in fake.calls if c[0] == "init"]
    assert [i["name"] for i in inits] == ["kitchen-0/sphere/t2i", "kitchen-0/sphere/no"]
    assert all(i["mode"] == "offline" and i["group"] == "exp" and i["project"] == "proj" for i in inits)
    assert all(i["dir"] == str(tmp_path) for i in inits)
    assert "status:ok" in inits[0]["tags"] and "method:t2i" in inits[0]["tags"]
    assert inits[0]["notes"] == "missing lpips: no weights" and "ValueError: broken" in inits[1]["notes"]
    logs = [c for c in fake.calls if c[0] == "log"]
    assert logs[0][1]["metrics/psnr"] == 21.5 and "metrics/lpips" not in logs[0][1] and logs[0][2] == 0
    assert logs[0][1]["images/image"] == ("Image", str(folder / "image.png"))
    configs = [c[1] for c in fake.calls if c[0] == "config"]
    assert configs[0]["scene.width"] == 160
    assert [c[1] for c in fake.calls if c[0] == "finish"] == [0, 1]  # a failed cell's run fails
    assert fake.calls[-1] == ("teardown",)


# ---------------------------------------------------------------------------- errors
def test_a_missing_library_stops_the_run_before_any_cell(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "mlflow", None)  # import mlflow raises ImportError
    fix = r"tracker=mlflow needs mlflow: pip install 'snell_bench\[track\]' or set tracker=none"
    with pytest.raises(ConfigError, match=fix):  # the check Hydra's preflight runs
        check_config(compose(["tracker=mlflow"]))
    with pytest.raises(ConfigError, match=fix):
        run(make_cfg(tmp_path, ["tracker=mlflow"]))
    assert not list(tmp_path.rglob("metrics.json")) and not list(tmp_path.rglob("mlruns"))
    # on the command line: said before Hydra makes a folder
    args = ["+experiment=smoke", "tracker=mlflow", f"runs_dir={tmp_path / 'cli'}", f"reports_dir={tmp_path / 'cli'}"]
    code = f"import sys; sys.modules['mlflow'] = None; sys.argv = ['snell_bench', *{args!r}]; "
    code += "from snell_bench.__main__ import cli; cli()"
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 1 and re.search(fix, out.stderr), out.stderr
    assert not (tmp_path / "cli").exists() and not (tmp_path / "outputs").exists()


def test_a_bad_wandb_mode_is_named():
    with pytest.raises(ConfigError, match="tracker.mode='ofline': must be one of offline, online"):
        check_config(compose(["tracker=wandb", "tracker.mode=ofline"]))


def test_the_registry_holds_each_tracker_config_and_names_the_choices(tmp_path):
    from hydra.utils import get_class

    confs = {p.stem: OmegaConf.load(p) for p in (REPO / "snell_bench" / "conf" / "tracker").glob("*.yaml")}
    assert sorted(TRACKERS) == sorted(set(confs) - {"none"})
    for name, tracker in TRACKERS.items():
        assert tracker.name == name and get_class(confs[name].backend._target_) is tracker
    # a backend node without _target_ is built by the class registered under tracker.name
    pytest.importorskip("tensorboard")
    untargeted = ["tracker=tensorboard", "~tracker.backend._target_", f"runs_dir={tmp_path}"]
    cfg = compose(untargeted)
    tracker = make_tracker(cfg)
    assert type(tracker) is TRACKERS["tensorboard"] and tracker.dir == Path(cfg.tracker.dir).absolute()
    with pytest.raises(ConfigError, match=r"tracker='tb': no such tracker; one of mlflow, tensorboard, wandb, none"):
        make_tracker(compose([*untargeted, "tracker.name=tb"]))


class BrokenTracker(Tracker):
    """A tracker whose store fails on every metric."""

    name = "broken"
    where = "nowhere"

    def __init__(self, experiment="x", log_images=True):
        super().__init__(experiment, log_images=log_images)
        self.ended = []

    def start_run(self, name, tags):
        pass

    def log_params(self, params):
        pass

    def log_metrics(self, metrics):
        raise OSError("the store is full")

    def log_images(self, images):
        pass

    def end_run(self, status):
        self.ended.append(status)


def test_a_failing_tracker_warns_and_the_cell_stays_ok(tmp_path, caplog):
    target = f"{BrokenTracker.__module__}.BrokenTracker"
    cfg = make_cfg(
        tmp_path,
        [
            "grid.scenes=[living_room]",
            "grid.methods=[t2i]",
            "grid.report=false",
            "reference.enabled=false",
            "reference.true_render=false",
            "tracker.name=broken",
            f"tracker.backend={{_target_:{target}}}",
        ],
    )
    with caplog.at_level(logging.WARNING, logger="snell_bench.experiment.tracking"):
        summary = run(cfg)
    assert summary["ok"] == 1 and summary["failed"] == 0 and summary["failures"] == []
    assert summary["tracker"]["failures"] == 1 and summary["tracker"]["runs"] == 0
    assert records_of(tmp_path)["living_room-0/sphere/t2i"]["status"] == "ok"
    assert "could not log cell living_room-0/sphere/t2i" in caplog.text and "the store is full" in caplog.text


# ---------------------------------------------------------------------------- several processes
@pytest.mark.slow
@pytest.mark.parametrize("tracker", ["mlflow", "tensorboard"])
def test_parallel_launcher_processes_each_log_their_cells(tmp_path, tracker, monkeypatch):
    """Two scene subsets in two processes (Hydra's joblib launcher): every cell logged once, in one
    experiment."""
    pytest.importorskip(tracker)
    monkeypatch.setenv("MLFLOW_ALLOW_FILE_STORE", "true")  # to read the file store here
    cmd = [
        sys.executable,
        "-m",
        "snell_bench",
        "-m",
        "+experiment=smoke",
        *TINY,
        "grid.methods=[t2i]",
        "reference.enabled=false",
        "reference.true_render=false",
        "grid.report=false",
        f"tracker={tracker}",
        f"runs_dir={tmp_path / 'runs'}",
        "grid.scenes=[living_room],[kitchen]",
        "hydra/launcher=local_processes",
        f"hydra.sweep.dir={tmp_path / 'multirun'}",
    ]
    subprocess.run(cmd, cwd=REPO, check=True, timeout=600, env={**os.environ, "HF_HUB_OFFLINE": "1"})
    names = sorted(records_of(tmp_path))
    assert names == ["kitchen-0/sphere/t2i", "living_room-0/sphere/t2i"]
    if tracker == "mlflow":
        from mlflow import MlflowClient

        client = MlflowClient(tracking_uri=(tmp_path / "runs" / "smoke" / "mlruns").as_uri())
        assert sorted(mlflow_runs(client)) == names
    else:
        logs = tmp_path / "runs" / "smoke" / "tensorboard"
        assert sorted(str(p.parent.relative_to(logs)) for p in logs.rglob("events.out.tfevents.*")) == names
