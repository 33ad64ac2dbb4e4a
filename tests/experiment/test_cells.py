"""The cell loop: resume, failures, skips, shared values, atomic records, no stray files."""

import json

import pytest
from omegaconf import OmegaConf

from snell_bench.experiment.cells import Cell, SharedCache, record_done, run_cells
from snell_bench.pipeline import Skip


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
    assert rec["a"] == {"name": "a", "status": "ok", "reason": None, "value": 1}
    assert rec["skip"]["status"] == "skipped" and rec["skip"]["reason"] == "needs a GPU"
    assert (
        rec["bad"]["status"] == "failed"
        and rec["bad"]["reason"] == "RuntimeError: boom"
        and "Traceback" in rec["bad"]["traceback"]
    )
    assert summary["failures"] == [(str(tmp_path / "bad"), "RuntimeError: boom")]
    assert OmegaConf.load(tmp_path / "a" / "config.yaml").output_dir == str(tmp_path / "a")
    assert json.loads((tmp_path / "summary.json").read_text())["ok"] == 2
    assert not [p for p in tmp_path.rglob("*") if p.name.startswith(".")]  # no temporary left


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
    run_cells(cells, fn, root=tmp_path, recompute=True)
    assert calls == ["a", "b", "bad"]
    assert record_done(tmp_path / "a" / "metrics.json") and not record_done(tmp_path / "bad" / "metrics.json")
    (tmp_path / "a" / "metrics.json").write_text("{trunc")
    assert not record_done(tmp_path / "a" / "metrics.json")


def test_shared_values_are_computed_once_and_dropped_after_their_last_cell(tmp_path):
    computed, alive = [], []

    def fn(cell, shared):
        value = shared.get(cell.shares, lambda: computed.append(cell.shares) or {"key": cell.shares}, by=cell.name)
        alive.append(sorted(k for k in shared._values))
        if cell.shares == "broken":
            raise AssertionError("unreachable")
        return {"from": shared.computed_by[cell.shares], "key": value["key"]}

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
