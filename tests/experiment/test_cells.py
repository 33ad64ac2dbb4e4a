"""The cell loop: resume, failures, skips, shared values, atomic records, no stray files."""

import json

import pytest
from omegaconf import OmegaConf

from snell_bench.experiment.cells import Cell, Policy, SharedCache, record_done, run_cells
from snell_bench.pipeline import Skip


def temporaries(root):
    """Hidden files left under ``root``, but the emptied flock files that stay in claimed folders."""
    return [p for p in root.rglob(".*") if not (p.name == ".lock" and p.read_text() == "")]


def cells_in(root, names, shares=None):
    cfg = OmegaConf.create({"x": 1, "output_dir": ""})
    return [Cell(name=n, folder=root / n, config=cfg, record={"name": n}, shares=(shares or {}).get(n)) for n in names]


def test_ok_skipped_failed_recorded_and_the_loop_goes_on(tmp_path):
    def fn(cell, shared):
        if cell.name == "skip":
            raise Skip("needs a GPU")
        if cell.name == "bad":
            raise RuntimeError("boom")
        return {"value": len(cell.name)}

    summary = run_cells(cells_in(tmp_path, ["a", "skip", "bad", "bb"]), fn, root=tmp_path)
    assert (summary["ok"], summary["skipped"], summary["failed"], summary["cached"]) == (2, 1, 1, 0)
    rec = {n: json.loads((tmp_path / n / "metrics.json").read_text()) for n in ("a", "skip", "bad", "bb")}
    files = rec["a"].pop("files")
    assert rec["a"].pop("settings_hash") == rec["bb"]["settings_hash"]  # the same config
    assert rec["a"] == {"name": "a", "status": "ok", "reason": None, "value": 1}
    assert (
        set(files) == {"config.yaml"}
        and files["config.yaml"]["bytes"] == (tmp_path / "a" / "config.yaml").stat().st_size
    )
    assert rec["skip"]["status"] == "skipped" and rec["skip"]["reason"] == "needs a GPU"
    assert (
        rec["bad"]["status"] == "failed"
        and rec["bad"]["reason"] == "RuntimeError: boom"
        and "Traceback" in rec["bad"]["traceback"]
    )
    assert summary["failures"] == [(str(tmp_path / "bad"), "RuntimeError: boom")]
    assert OmegaConf.load(tmp_path / "a" / "config.yaml").output_dir == str(tmp_path / "a")
    assert json.loads((tmp_path / "summary.json").read_text())["ok"] == 2
    assert not temporaries(tmp_path)


def test_resume_redoes_only_unfinished_cells(tmp_path):
    calls = []

    def fn(cell, shared):
        calls.append(cell.name)
        if cell.name == "bad":
            raise RuntimeError("boom")
        return {}

    cells = cells_in(tmp_path, ["a", "b", "bad"])
    run_cells(cells, fn, root=tmp_path)
    (tmp_path / "b" / "metrics.json").unlink()  # an interrupted cell
    calls.clear()
    summary = run_cells(cells, fn, root=tmp_path)
    assert calls == ["b", "bad"] and summary["cached"] == 1  # failed cells are retried
    calls.clear()
    run_cells(cells, fn, root=tmp_path, policy=Policy(recompute=True))
    assert calls == ["a", "b", "bad"]
    assert record_done(tmp_path / "a" / "metrics.json") and not record_done(tmp_path / "bad" / "metrics.json")
    (tmp_path / "a" / "metrics.json").write_text("{trunc")
    assert not record_done(tmp_path / "a" / "metrics.json")


def test_shared_values_are_computed_once_and_dropped_after_their_last_cell(tmp_path):
    computed, alive = [], []

    def fn(cell, shared):
        value = shared.get(cell.shares, lambda: computed.append(cell.shares) or {"key": cell.shares, "from": cell.name})
        alive.append(sorted(k for k in shared._values))
        if cell.shares == "broken":
            raise AssertionError("unreachable")
        return {"from": value["from"], "key": value["key"]}

    shares = {"a1": "A", "a2": "A", "b1": "B"}
    summary = run_cells(cells_in(tmp_path, ["a1", "a2", "b1"], shares), fn, root=tmp_path)
    assert summary["ok"] == 3 and computed == ["A", "B"]
    assert alive == [["A"], ["A"], ["B"]]  # A is dropped once a2 is done
    assert json.loads((tmp_path / "a2" / "metrics.json").read_text())["from"] == "a1"


def test_a_failed_shared_value_fails_every_cell_that_needs_it():
    cache = SharedCache(["k", "k"])
    n = []

    def compute():
        n.append(1)
        raise OSError("disk full")

    for _ in range(2):
        with pytest.raises(OSError, match="disk full"):
            cache.get("k", compute)
    assert n == [1]


def test_links_are_idempotent(tmp_path):
    from snell_bench.utils.io import link_or_copy, write_text

    src = write_text(tmp_path / "src.txt", "x")
    (tmp_path / "cell").mkdir()
    for _ in range(3):
        link_or_copy(src, tmp_path / "cell" / "src.txt")
    assert [p.name for p in (tmp_path / "cell").iterdir()] == ["src.txt"]
    assert (tmp_path / "cell" / "src.txt").read_text() == "x"


def test_a_finished_cell_with_a_missing_or_changed_file_is_unfinished(tmp_path):
    calls = []

    def fn(cell, shared):
        calls.append(cell.name)
        (cell.folder / "image.png").write_bytes(b"image of " + cell.name.encode())
        return {}

    cells = cells_in(tmp_path, ["a", "b", "c"])
    run_cells(cells, fn, root=tmp_path)
    files = json.loads((tmp_path / "a" / "metrics.json").read_text())["files"]
    assert set(files) == {"config.yaml", "image.png"} and len(files["image.png"]["sha256"]) == 64
    (tmp_path / "a" / "image.png").unlink()  # deleted
    (tmp_path / "b" / "image.png").write_bytes(b"image of c")  # same size, other content
    calls.clear()
    summary = run_cells(cells, fn, root=tmp_path)
    assert calls == ["a", "b"] and summary["cached"] == 1 and summary["ok"] == 2


def _cfg_cells(root, **values):
    cfg = OmegaConf.create({"output_dir": "", "seed": 0, "sampler": {"steps": 4, "progress": True}, **values})
    return [Cell(name=n, folder=root / n, config=cfg.copy(), record={"name": n}) for n in ("a", "b")]


def test_changed_settings_stop_before_any_work_naming_the_keys_and_the_choices(tmp_path):
    from snell_bench.experiment.cells import SettingsChanged

    calls = []

    def fn(cell, shared):
        calls.append(cell.name)
        return {}

    run_cells(_cfg_cells(tmp_path), fn, root=tmp_path)
    changed = _cfg_cells(tmp_path)
    changed[0].config.sampler.steps = 8
    changed[1].config.seed = 3
    calls.clear()
    with pytest.raises(SettingsChanged) as e:
        run_cells(changed, fn, root=tmp_path)
    msg = str(e.value)
    assert "sampler.steps: 4 -> 8 (1 cell)" in msg and "seed: 0 -> 3 (1 cell)" in msg, msg
    assert "grid.on_change=recompute" in msg and "grid.recompute=true" in msg and "experiment_name" in msg
    assert calls == []  # nothing ran
    # keys that do not change a result (progress bars, output paths) are not settings
    quiet = _cfg_cells(tmp_path)
    for c in quiet:
        c.config.sampler.progress = False
    assert run_cells(quiet, fn, root=tmp_path)["cached"] == 2 and calls == []
    # on_change=recompute redoes exactly the changed cells, which then count as done
    summary = run_cells(changed[:1] + _cfg_cells(tmp_path)[1:], fn, root=tmp_path, policy=Policy(on_change="recompute"))
    assert calls == ["a"] and summary["ok"] == 1 and summary["cached"] == 1
    assert run_cells(changed[:1], fn, root=tmp_path)["cached"] == 1


def _sweep_process(root, log, names):
    import time

    def fn(cell, shared):
        with open(log, "a") as f:
            f.write(f"{cell.name}\n")
        time.sleep(0.2)
        return {}

    run_cells(cells_in(root, names), fn, root=root)


def test_sweeps_running_at_once_compute_each_cell_once_and_leave_no_temporary(tmp_path):
    import multiprocessing

    names = [f"c{i}" for i in range(8)]
    log = tmp_path / "calls.txt"
    ctx = multiprocessing.get_context("fork")
    procs = [ctx.Process(target=_sweep_process, args=(tmp_path / "runs", log, names)) for _ in range(3)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
    assert all(p.exitcode == 0 for p in procs)
    calls = log.read_text().split()
    assert sorted(calls) == names  # each cell once
    assert all(record_done(tmp_path / "runs" / n / "metrics.json") for n in names)
    assert not temporaries(tmp_path / "runs")


def _lease_sweep_process(root, log, names):
    import time

    def fn(cell, shared):
        with open(log, "a") as f:
            f.write(f"{cell.name}\n")
        time.sleep(0.2)
        return {}

    run_cells(cells_in(root, names), fn, root=root, policy=Policy(lock="lease", lease_ttl_s=0.6))


def test_sweeps_running_at_once_with_leases_compute_each_cell_once(tmp_path):
    """Lease files (``grid.lock=lease``) exclude like flock: each cell once, no file left."""
    import multiprocessing

    names = [f"c{i}" for i in range(8)]
    log = tmp_path / "calls.txt"
    ctx = multiprocessing.get_context("fork")
    procs = [ctx.Process(target=_lease_sweep_process, args=(tmp_path / "runs", log, names)) for _ in range(3)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
    assert all(p.exitcode == 0 for p in procs)
    assert sorted(log.read_text().split()) == names
    assert all(record_done(tmp_path / "runs" / n / "metrics.json") for n in names)
    assert not temporaries(tmp_path / "runs")


def test_a_lock_left_by_a_dead_process_is_free(tmp_path):
    import fcntl
    import os

    from snell_bench.experiment.cells import LOCK_NAME, claim

    folder = tmp_path / "a"
    folder.mkdir()
    pid = os.fork()
    if pid == 0:  # a sweep that takes the lock and is killed
        fd = os.open(folder / LOCK_NAME, os.O_RDWR | os.O_CREAT)
        fcntl.flock(fd, fcntl.LOCK_EX)
        os._exit(0)
    os.waitpid(pid, 0)
    assert (folder / LOCK_NAME).exists()  # the file stays; its lock died with the process
    summary = run_cells(cells_in(tmp_path, ["a"]), lambda c, s: {}, root=tmp_path)
    assert summary["ok"] == 1 and (folder / LOCK_NAME).read_text() == ""  # released: its owner line emptied
    with claim(folder) as mine:  # held: a second claim fails
        assert mine
        with claim(folder) as other:
            assert not other


def test_a_cell_whose_folder_cannot_be_written_fails_alone(tmp_path):
    (tmp_path / "b").write_text("a file where the cell's folder should be")
    summary = run_cells(cells_in(tmp_path, ["a", "b", "c"]), lambda c, s: {}, root=tmp_path)
    assert summary["ok"] == 2 and summary["failed"] == 1
    assert summary["failures"][0][0] == str(tmp_path / "b") and "cannot be written" in summary["failures"][0][1]


def test_a_setting_added_to_the_schema_at_its_default_is_no_change(tmp_path):
    """A cell computed before ``object.repair`` existed had its default behaviour: still done."""
    from snell_bench.experiment.cells import SettingsChanged

    old = _cfg_cells(tmp_path, object={"ior": 1.5})
    run_cells(old, lambda c, s: {}, root=tmp_path)
    new = _cfg_cells(tmp_path, object={"ior": 1.5, "repair": False})
    assert run_cells(new, lambda c, s: {}, root=tmp_path)["cached"] == 2
    on = _cfg_cells(tmp_path, object={"ior": 1.5, "repair": True})  # not the default: a change
    with pytest.raises(SettingsChanged, match=r"object.repair: '<absent>' -> True"):
        run_cells(on, lambda c, s: {}, root=tmp_path)


def test_temporaries_of_a_killed_run_are_removed_when_the_cell_is_computed(tmp_path):
    (tmp_path / "a").mkdir()
    for name in (".image.png.k3j2.tmp", ".depth.npy.x9.link"):  # what a SIGKILL mid-write leaves
        (tmp_path / "a" / name).write_bytes(b"partial")
    assert run_cells(cells_in(tmp_path, ["a"]), lambda c, s: {}, root=tmp_path)["ok"] == 1
    assert not temporaries(tmp_path / "a")


def test_a_record_that_is_not_a_cell_record_is_computed_again_with_a_warning(tmp_path, caplog):
    """A finished cell whose record file was replaced (by hand, by another tool, cut short, in another
    encoding) is not done: it is computed again, and the warning names the file and the problem."""
    from snell_bench.reports.records import GRID_RECORD

    broken = {
        "array": b"[1, 2]",
        "handmade": b'{"status": "ok"}',
        "types": json.dumps(
            {"scene": "k", "variation": 0, "object": "o", "method": "types", "status": "ok", "metrics": {"psnr": "x"}}
        ).encode(),
        "truncated": b'{"status": "ok", "sce',
        "latin1": '{"scene": "caf\xe9"}'.encode("latin-1"),
    }
    names = ["fine", *broken]
    cfg = OmegaConf.create({"x": 1, "output_dir": ""})
    cells = [
        Cell(name=n, folder=tmp_path / n, config=cfg, record={"scene": "k", "variation": 0, "object": "o", "method": n})
        for n in names
    ]
    calls = []

    def fn(cell, shared):
        calls.append(cell.name)
        return {"metrics": {"psnr": 20.0}}

    assert run_cells(cells, fn, root=tmp_path, schema=GRID_RECORD)["ok"] == len(names)
    for name, raw in broken.items():
        (tmp_path / name / "metrics.json").write_bytes(raw)
    calls.clear()
    summary = run_cells(cells, fn, root=tmp_path, schema=GRID_RECORD)
    assert (summary["cached"], summary["ok"]) == (1, len(broken)) and calls == list(broken)
    for name in broken:
        path = tmp_path / name / "metrics.json"
        assert f"cell {name}: {path} is not a cell record (" in caplog.text
        assert record_done(path)  # written again, whole
    assert "a JSON array, not an object" in caplog.text and "not UTF-8 text (byte 0xe9" in caplog.text
    assert "missing the keys scene, variation, object, method, metrics" in caplog.text
    assert caplog.text.count("is not a cell record") == len(broken)  # warned once each
