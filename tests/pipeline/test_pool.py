"""The model pool: each model loaded once per pool, the memory budget, scopes, and a grid that loads
every model once whether they fit together or not (the same cells either way)."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from snell_bench.config import compose
from snell_bench.pipeline import ModelPool, model_bytes

MiB = 2**20


class Net(torch.nn.Module):
    def __init__(self, n: int) -> None:
        super().__init__()
        self.w = torch.nn.Parameter(torch.zeros(n, dtype=torch.float32))
        self.register_buffer("b", torch.zeros(n // 2, dtype=torch.float16))


def test_model_bytes_counts_parameters_and_buffers_once():
    net = Net(1000)
    holder = type("Holder", (), {})()
    holder.a, holder.b = net, net  # the same module twice
    holder.components = {"c": torch.nn.Linear(10, 10, bias=False)}
    assert model_bytes(net) == 1000 * 4 + 500 * 2
    assert model_bytes(holder) == 1000 * 4 + 500 * 2 + 100 * 4


def test_each_model_loads_once_and_every_load_is_recorded():
    pool, built = ModelPool(), []

    def build(n):
        built.append(n)
        return Net(n)

    a, ta = pool.get("generator", "A", lambda: build(10), label="a")
    again, ta2 = pool.get("generator", "A", lambda: build(10))
    assert again is a and ta2 == ta and built == [10]
    pool.get("relighter", "A", lambda: build(20))  # another kind: another model
    assert built == [10, 20]
    loads = pool.summary()["loads"]
    assert [(x["kind"], x["event"], x["bytes"]) for x in loads] == [
        ("generator", "load", 10 * 4 + 5 * 2),
        ("relighter", "load", 20 * 4 + 10 * 2),
    ]


def test_a_failed_load_keeps_nothing():
    pool = ModelPool()
    with pytest.raises(OSError, match="no weights"):
        pool.get("fill", "F", lambda: (_ for _ in ()).throw(OSError("no weights")))
    assert pool.held() == [] and pool.loads == []


def test_the_budget_releases_the_least_recently_used_model():
    pool = ModelPool(memory_gb=3 * MiB / 2**30)  # three 1 MiB models fit
    one = 2**18  # float32 parameters: 1 MiB; buffers 0.25 MiB more
    for name in "ABC":
        pool.get("m", name, lambda: Net(one))
    # a model loaded for the first time is assumed to need the whole budget: all others go
    assert pool.held() == ["m"] and pool.held_bytes() == int(1.25 * MiB)
    pool.get("m", "A", lambda: Net(one))  # A's size is known now: B? no, only C is held, both fit
    assert len(pool.held()) == 2
    events = [(x["key"], x["event"]) for x in pool.summary()["loads"]]
    assert events.count((ModelPool.digest("A"), "load")) == 2  # A was released for B, loaded again


def test_pinned_models_stay_and_scopes_end():
    pool = ModelPool(memory_gb=1.5 * MiB / 2**30)
    scorers, _ = pool.get("scorers", "S", lambda: Net(2**16), pin=True)
    pool.get("m", "A", lambda: Net(2**18))
    assert "scorers" in pool.held() and pool.get("scorers", "S", lambda: None)[0] is scorers
    pool.get("generator", "G", lambda: Net(8), scope=("inputs", 1))
    assert pool.in_scope(("inputs", 1))
    pool.end_scope(("inputs", 1))
    assert not pool.in_scope(("inputs", 1)) and "scorers" in pool.held()


def test_a_budget_must_be_positive():
    with pytest.raises(ValueError, match="models.memory_gb"):
        ModelPool(memory_gb=0)


# ---------------------------------------------------------------------------- a grid
GRID = [
    "+experiment=smoke",
    "model=tiny_flux",
    "scene.source=procedural",  # the generator on a procedural scene: a named choice
    "scene.width=64",
    "scene.height=48",
    "scene.supersample=1",
    "warps.pano_height=32",
    "warps.cache_dir=null",
    "sampler.steps=2",
    "sampler.levels=3",
    "reference.spp=4",
    "reference.unobserved_spp=4",
    "reference.true_spp=1",
    "relight.candidates=2",
    "relight.steps=2",
    "grid.scenes=[living_room,kitchen,office]",
    "grid.methods=[snellcaster,snellcaster_relit,inpaint,t2i]",
    "grid.report=false",
    "++method.steps=2",
]


def _run(tmp: Path, name: str, extra: list[str]) -> dict:
    from snell_bench.experiment.runner import run_grid

    cfg = compose(
        [*GRID, f"runs_dir={tmp / 'runs'}", f"reports_dir={tmp / 'reports'}", f"experiment_name={name}", *extra]
    )
    summary = run_grid(cfg)
    assert summary["ok"] == 12 and summary["failed"] == 0, summary
    on_disk = json.loads((tmp / "runs" / name / "summary.json").read_text())
    assert on_disk["models"] == json.loads(json.dumps(summary["models"]))
    return summary


def _loads(summary: dict) -> dict:
    loads = [x for x in summary["models"]["loads"] if x["event"] == "load"]
    counts: dict = {}
    for x in loads:
        counts[(x["kind"], x["key"])] = counts.get((x["kind"], x["key"]), 0) + 1
    return counts


@pytest.fixture(scope="module")
def grids(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("pool_grid")
    together = _run(tmp, "together", [])
    one_at_a_time = _run(tmp, "one_at_a_time", ["models.memory_gb=1e-9"])  # any model fills the budget
    return tmp, together, one_at_a_time


def test_every_model_of_the_grid_loads_once(grids):
    _, together, _ = grids
    counts = _loads(together)
    assert {kind for kind, _ in counts} == {"scorers", "generator", "relighter", "fill"}
    assert set(counts.values()) == {1}, counts
    assert together["order"] == "group-major"


def test_models_that_do_not_fit_together_still_load_once(grids):
    _, _, one = grids
    counts = _loads(one)
    assert {kind for kind, _ in counts} == {"scorers", "generator", "relighter", "fill"}
    assert set(counts.values()) == {1}, counts
    assert one["order"] == "model-major"
    released = [x["kind"] for x in one["models"]["loads"] if x["event"] == "release"]
    assert released == ["generator", "relighter"]  # each one released once, for the next


def test_the_order_changes_no_result(grids):
    """Model-major cells read their inputs back from ``_inputs/inputs.pkl`` and relight a result
    sampled earlier: every file of every cell is the same, byte for byte."""
    tmp, _, _ = grids
    a, b = tmp / "runs" / "together", tmp / "runs" / "one_at_a_time"
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file() and p.suffix in (".png", ".npy"))
    assert len(files) > 12 * 3
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    for rel in sorted(p.relative_to(a) for p in a.rglob("metrics.json")):
        ma, mb = (json.loads((root / rel).read_text()) for root in (a, b))
        assert ma["metrics"] == mb["metrics"] and ma["status"] == mb["status"] == "ok", rel
        assert ma["settings_hash"] == mb["settings_hash"], rel  # the budget changes no result
    assert not list(b.rglob(".unrelit.pt"))  # kept only until the cell is written
    assert np.isfinite([json.loads(p.read_text())["metrics"]["psnr"] for p in b.rglob("metrics.json")]).all()


def test_model_major_order_continues_with_the_model_the_sampling_pass_left_loaded(tmp_path):
    """Fill first in the plan, a relit method last: the relit cells sample with the generator ahead,
    so the generator's cells come first, then Fill's, then the relighter's."""
    from snell_bench.experiment.order import ModelMajor, cell_models
    from snell_bench.experiment.runner import plan_grid

    cfg = compose(
        [
            *GRID,
            "grid.scenes=[living_room,kitchen]",
            "grid.methods=[inpaint,snellcaster,snellcaster_relit]",
            f"runs_dir={tmp_path}",
            "models.memory_gb=1",
        ]
    )
    order = ModelMajor(ModelPool(1.0)).order(plan_grid(cfg))
    last = [cell_models(c.config)[-1][0] for c in order]
    assert last == ["generator"] * 2 + ["fill"] * 2 + ["relighter"] * 2
