"""Preparing groups in worker processes while the generator samples (grid.prefetch): the same files
as the serial path, a failing or dying worker, the automatic rule, the model-major order."""

import json
import multiprocessing
import os
from pathlib import Path

import pytest
import torch

from snell_bench.config import compose
from snell_bench.experiment.prefetch import AUTO_AHEAD, auto_prefetch, needs_models, settings_of
from snell_bench.render.variants import VARIANT_ENV
from snell_bench.scene.objects import GlassObject

TINY = [
    "+experiment=smoke",
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
    "grid.report=false",
]

#: The IOR that marks the group whose object factory fails (or whose worker dies) here.
MARKED_IOR = 1.7


def sphere_or_fail(ior, **kwargs):
    """An object factory: the glass sphere, except at :data:`MARKED_IOR`, where it fails."""
    if ior == MARKED_IOR:
        raise ValueError(f"no sphere of IOR {ior} here")
    return GlassObject.sphere(ior=ior, **kwargs)


def sphere_or_die(ior, **kwargs):
    """An object factory: the glass sphere, except at :data:`MARKED_IOR` in a worker process,
    which it ends at once (as the kernel's out-of-memory killer would)."""
    if ior == MARKED_IOR and multiprocessing.parent_process() is not None:
        os._exit(3)
    return GlassObject.sphere(ior=ior, **kwargs)


@pytest.fixture(scope="module", autouse=True)
def scalar_variant():
    """Mitsuba's scalar variant, bit for bit reproducible on any machine and thread count (the
    workers inherit the environment)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(VARIANT_ENV, "scalar_rgb")
        yield


def _run(tmp: Path, name: str, extra: list[str]) -> dict:
    from snell_bench.experiment.runner import run_grid

    cfg = compose([*TINY, f"runs_dir={tmp / name}", f"reports_dir={tmp / 'reports'}", *extra])
    return run_grid(cfg)


#: What a ``metrics.json`` records of where and how fast its cell ran.
_WHERE_AND_HOW_FAST = ("timings_s", "sampler_timings_s", "seconds", "cache")


def _results(m):
    """A record without :data:`_WHERE_AND_HOW_FAST` and the listed hash of ``config.yaml``."""
    if isinstance(m, dict):
        return {k: _results(v) for k, v in m.items() if k not in _WHERE_AND_HOW_FAST and k != "config.yaml"}
    return [_results(v) for v in m] if isinstance(m, list) else m


def _same_results(a: Path, b: Path) -> int:
    """Assert that the run folders ``a`` and ``b`` hold the same files with the same bytes, but
    for what says where and how fast they ran: ``config.yaml`` (compared by result settings),
    ``metrics.json`` (compared by :func:`_results`), ``summary.json``,
    and the kept inputs (``inputs-*.pkl``: with their timings; the files they hold are compared).
    Returns the number of files compared."""
    from omegaconf import OmegaConf

    from snell_bench.experiment.plan import result_settings

    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file() and p.name != "summary.json")
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file() and p.name != "summary.json")
    for rel in files:
        if rel.name == "config.yaml":
            assert result_settings(OmegaConf.load(a / rel)) == result_settings(OmegaConf.load(b / rel)), rel
        elif rel.name == "metrics.json":
            ma, mb = (_results(json.loads((root / rel).read_text())) for root in (a, b))
            assert ma == mb, rel
        elif rel.suffix != ".pkl":
            assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    return len(files)


# ---------------------------------------------------------------------------- the same files
@pytest.fixture(scope="module")
def serial_and_prefetched(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("prefetch")
    one = ["grid.methods=[snellcaster]"]
    serial = _run(tmp, "serial", [*one, "grid.prefetch=0"])
    prefetched = _run(tmp, "prefetched", [*one, "grid.prefetch=2", "grid.workers=1"])
    return tmp, serial, prefetched


def test_prefetch_changes_no_file(serial_and_prefetched):
    """Two groups: the first prepared here with its references rendered by a worker while its cell
    samples, the second prepared by the worker ahead (stages 1-3 read back, then its references);
    every file is the serial path's, byte for byte."""
    tmp, serial, prefetched = serial_and_prefetched
    assert serial["ok"] == prefetched["ok"] == 2 and serial["failed"] == prefetched["failed"] == 0
    assert serial["prefetch"] == {"ahead": 0, "workers": 0}
    assert prefetched["prefetch"] == {
        "ahead": 2,
        "workers": 1,
        "prepared_ahead": 1,
        "prepared_here": 1,
        "references_in_workers": 2,
        "references_here": 0,
        "fallback": None,
    }
    assert _same_results(tmp / "serial" / "smoke", tmp / "prefetched" / "smoke") > 2 * 12
    assert not list((tmp / "prefetched").rglob("*.pkl"))  # handed over, then removed


def test_stage_timings_come_from_the_worker(serial_and_prefetched):
    tmp, _, _ = serial_and_prefetched
    for path in (tmp / "prefetched" / "smoke").rglob("metrics.json"):
        timings = json.loads(path.read_text())["timings_s"]
        assert list(timings)[:4] == ["scene", "warps", "reference", "true_render"], path
        assert all(timings[k] > 0 for k in ("scene", "warps", "reference", "true_render")), path


# ---------------------------------------------------------------------------- settings
def test_every_method_of_a_group_keeps_one_inputs_file(tmp_path):
    """The kept inputs are named by the settings stages 1-5 read: not the method's."""
    from snell_bench.experiment.files import inputs_file
    from snell_bench.experiment.runner import plan_grid

    cells = plan_grid(compose([*TINY, f"runs_dir={tmp_path}"]))
    assert len(cells) == 4 and len({inputs_file(c) for c in cells}) == 2
    assert {inputs_file(c).parent for c in cells} == {c.shares / "_inputs" for c in cells}


def test_cells_with_random_weights_say_so(tmp_path):
    from snell_bench.experiment.runner import plan_grid

    base = [
        *TINY,
        "grid.scenes=[kitchen]",
        "grid.methods=[t2i]",
        "model=tiny_flux",
        "scene.source=procedural",
        f"runs_dir={tmp_path}",
    ]
    assert "random_weights" not in plan_grid(compose(base))[0].record
    assert plan_grid(compose([*base, "model.random_init=true"]))[0].record["random_weights"] is True


def test_automatic_prefetch_is_on_where_the_generator_samples_on_cuda(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert auto_prefetch(compose(["model=tiny_flux"])) == AUTO_AHEAD == 2  # model.device unset: CUDA
    assert auto_prefetch(compose(["model=tiny_flux", "model.device=cuda:0"])) == 2
    assert auto_prefetch(compose(["model=tiny_flux", "model.device=cpu"])) == 0
    assert auto_prefetch(compose(["model=analytic"])) == 0  # a CPU stand-in built from the scene
    assert settings_of(compose(["model=tiny_flux"])) == (2, 1)
    assert settings_of(compose(["model=tiny_flux", "grid.prefetch=0"])) == (0, 1)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert auto_prefetch(compose(["model=tiny_flux"])) == 0  # no GPU: the cores are shared
    assert settings_of(compose(["model=analytic", "grid.prefetch=3", "grid.workers=2"])) == (3, 2)


def test_bad_settings_name_their_key():
    with pytest.raises(ValueError, match=r"grid.prefetch=-1.*>= 0"):
        settings_of(compose(["grid.prefetch=-1"]))
    with pytest.raises(ValueError, match=r"grid.workers=0.*>= 1"):
        settings_of(compose(["grid.workers=0"]))


def test_groups_whose_stages_need_a_model_are_not_prepared_in_workers():
    assert not needs_models(compose([]))
    assert needs_models(compose(["scene.source=generated", "model=tiny_flux", "depth=tiny_depth_pro"]))
    assert needs_models(compose(["segment=tiny_sam3", "scene.surface=table"]))
    photo = compose(["+experiment=photo"])
    assert photo.scene.depth and not needs_models(photo)  # an RGB-D frame: no estimator


# ---------------------------------------------------------------------------- failures
@pytest.mark.slow
def test_a_failing_group_fails_its_cells_and_the_sweep_goes_on(tmp_path):
    """The second group (IOR 1.7) fails in the worker: its cell records the worker's error, the
    other groups finish."""
    summary = _run(
        tmp_path,
        "failing",
        [
            "grid.prefetch=2",
            "grid.scenes=[living_room,kitchen]",
            f"grid.objects=[sphere,'sphere:{MARKED_IOR}']",
            "grid.methods=[t2i]",
            f"object.factory._target_={__name__}.sphere_or_fail",
        ],
    )
    assert summary["ok"] == 2 and summary["failed"] == 2, summary
    assert summary["prefetch"]["prepared_ahead"] >= 1 and summary["prefetch"]["fallback"] is None
    for scene in ("living_room-0", "kitchen-0"):
        rec = json.loads((tmp_path / f"failing/smoke/{scene}/sphere-ior1.7/t2i/metrics.json").read_text())
        assert rec["status"] == "failed" and "no sphere of IOR 1.7 here" in rec["reason"], rec["reason"]
        ok = json.loads((tmp_path / f"failing/smoke/{scene}/sphere/t2i/metrics.json").read_text())
        assert ok["status"] == "ok"


@pytest.mark.slow
def test_a_dying_worker_leaves_its_groups_to_this_process(tmp_path):
    """The worker preparing the second group dies: the workers break, that group and the next are
    prepared here, every cell finishes, and the summary says why."""
    summary = _run(
        tmp_path,
        "dying",
        [
            "grid.prefetch=2",
            "grid.scenes=[living_room,kitchen]",
            f"grid.objects=[sphere,'sphere:{MARKED_IOR}']",
            "grid.methods=[t2i]",
            f"object.factory._target_={__name__}.sphere_or_die",
        ],
    )
    assert summary["ok"] == 4 and summary["failed"] == 0, summary
    assert "BrokenProcessPool" in summary["prefetch"]["fallback"]
    assert summary["prefetch"]["prepared_here"] >= 2 and summary["prefetch"]["references_here"] >= 1
    assert not list(tmp_path.rglob("*.pkl"))


# ---------------------------------------------------------------------------- other orders and sources
# a text-to-image model on the smoke grid's procedural scenes (named: its default is a generated I⁻)
TINY_FLUX = [
    "model=tiny_flux",
    "scene.source=procedural",
    "model.device=cpu",
    "relight.candidates=2",
    "relight.steps=2",
]


@pytest.mark.slow
def test_prefetch_in_the_model_major_order_changes_no_file(tmp_path):
    """With a memory budget the cells run model by model: relit cells sample ahead, the groups are
    prepared by two workers ahead of their cells, the inputs are kept, each model loads once, and
    the files are those of the serial model-major run."""
    grid = [*TINY_FLUX, "grid.methods=[snellcaster_relit,t2i]", "models.memory_gb=1e-9"]
    serial = _run(tmp_path, "serial", [*grid, "grid.prefetch=0"])
    prefetched = _run(tmp_path, "prefetched", [*grid, "grid.prefetch=2", "grid.workers=2"])
    assert serial["ok"] == prefetched["ok"] == 4 and prefetched["order"] == "model-major"
    assert prefetched["prefetch"]["prepared_ahead"] + prefetched["prefetch"]["prepared_here"] == 2
    loads = [(x["kind"], x["key"]) for x in prefetched["models"]["loads"] if x["event"] == "load"]
    assert len(loads) == len(set(loads)), loads
    assert _same_results(tmp_path / "serial" / "smoke", tmp_path / "prefetched" / "smoke") > 4 * 12
    assert len(list((tmp_path / "prefetched").rglob("inputs-*.pkl"))) == 2  # kept, one per group
    assert not list((tmp_path / "prefetched").rglob("sampling-*.pkl"))


@pytest.mark.slow
def test_a_generated_scene_is_prepared_here_and_its_references_in_a_worker(tmp_path, monkeypatch):
    """I⁻ generated by the generator and its depth estimated by the depth model: stages 1-3 in this
    process, with its models, only the references in a worker; the files are the serial path's."""
    import numpy as np

    from snell_bench.scene import placement

    plane = placement.SupportPlane(  # random depth has no real plane: a table 0.3 below, 2 in front
        point=np.array([0.0, 0.3, 2.0]), normal=np.array([0.0, -1.0, 0.0]), inliers=100, pixel=np.array([32.0, 40.0])
    )
    monkeypatch.setattr(placement, "find_support_plane", lambda depth, camera, **kwargs: plane)
    grid = [
        *TINY_FLUX,
        "scene.source=generated",
        "depth=tiny_depth_pro",
        "grid.scenes=[living_room]",
        "grid.methods=[snellcaster,t2i]",
        "sampler.levels=2",
    ]
    serial = _run(tmp_path, "serial", [*grid, "grid.prefetch=0", f"scene.cache_dir={tmp_path / 'scenes0'}"])
    prefetched = _run(tmp_path, "prefetched", [*grid, "grid.prefetch=2", f"scene.cache_dir={tmp_path / 'scenes2'}"])
    assert serial["ok"] == prefetched["ok"] == 2
    assert prefetched["prefetch"]["prepared_ahead"] == 0 and prefetched["prefetch"]["prepared_here"] == 1
    assert prefetched["prefetch"]["references_in_workers"] == 1
    _same_results(tmp_path / "serial" / "smoke", tmp_path / "prefetched" / "smoke")
