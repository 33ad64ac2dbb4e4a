"""``job=plan``: the cells done and left by the runner's own test, the models and their weights, the
time and memory from the README's basis or a bench_gpu.py file, and nothing written."""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from snell_bench.config import ConfigError, SamplerSettings, compose
from snell_bench.experiment.estimate import (
    README_BASIS,
    DeviceInfo,
    GridParts,
    format_plan,
    group_models,
    load_bench,
    make_plan,
    memory_plan,
    model_calls,
)

NO_GPU = DeviceInfo(cuda=False)
H100 = DeviceInfo(True, "NVIDIA H100 80GB HBM3", 85.0, 1)
H200 = DeviceInfo(True, "NVIDIA H200", 150.0, 1)

#: A grid of two cells that runs in seconds on the CPU.
TINY = [
    "+experiment=smoke",
    "scene.width=160",
    "scene.height=96",
    "warps.pano_height=64",
    "warps.cache_dir=null",
    "sampler.steps=4",
    "reference.enabled=false",
    "reference.true_render=false",
    "grid.report=false",
    "grid.scenes=[living_room]",
]


def tiny(runs: Path, *extra: str) -> list[str]:
    return [*TINY, f"runs_dir={runs}", f"reports_dir={runs.parent / 'reports'}", f"output_dir={runs.parent}", *extra]


def plan_of(overrides, device=NO_GPU, **kwargs):
    return make_plan(compose([*overrides, "job=plan"]), device=device, **kwargs)


def states(plan) -> dict[str, str]:
    return {c.name: c.state for c in plan.cells}


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """The tiny grid, run: living_room-0/sphere/{snellcaster,t2i}."""
    from snell_bench.experiment.runner import run_grid

    runs = tmp_path_factory.mktemp("plan") / "runs"
    summary = run_grid(compose(tiny(runs)))
    assert summary["ok"] == 2, summary
    return runs


@pytest.fixture
def empty_caches(monkeypatch, tmp_path):
    """No weights anywhere: an empty Hugging Face cache, torch hub and home folder."""
    import huggingface_hub.constants

    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_CACHE", str(tmp_path / "hub"))
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    return tmp_path


# ---------------------------------------------------------------------------- cells done and left
def test_done_and_left_follow_the_runner(tiny_run):
    plan = plan_of(tiny(tiny_run))
    assert states(plan) == {"living_room-0/sphere/snellcaster": "done", "living_room-0/sphere/t2i": "done"}
    assert plan.groups == 1 and len(plan.left) == 0
    more = plan_of(tiny(tiny_run, "grid.variations=[0,1]"))
    assert [c.state for c in more.cells] == ["done", "done", "new", "new"] and more.groups == 2
    assert "cells: 2 done, 2 left (2 not run)" in format_plan(more)


def test_the_runner_computes_the_cells_the_plan_leaves(tiny_run, tmp_path):
    from snell_bench.experiment.runner import run_grid

    runs = tmp_path / "runs"
    shutil.copytree(tiny_run, runs)
    cell = runs / "smoke" / "living_room-0" / "sphere"
    (cell / "t2i" / "image.png").unlink()
    record = json.loads((cell / "snellcaster" / "metrics.json").read_text())
    (cell / "snellcaster" / "metrics.json").write_text(
        json.dumps({**record, "status": "failed", "reason": "RuntimeError: out of memory"})
    )
    plan = plan_of(tiny(runs))
    assert states(plan) == {"living_room-0/sphere/snellcaster": "failed", "living_room-0/sphere/t2i": "files"}
    assert "image.png is missing" in plan.cells[1].reason
    summary = run_grid(compose(tiny(runs)))  # the runner computes exactly the cells the plan left
    assert summary["ok"] == len(plan.left) == 2 and summary["cached"] == 0
    assert {c.state for c in plan_of(tiny(runs)).cells} == {"done"}
    # a recorded skip is done: it is not run again
    (cell / "t2i" / "metrics.json").write_text(
        json.dumps(
            {**json.loads((cell / "t2i" / "metrics.json").read_text()), "status": "skipped", "reason": "needs a GPU"}
        )
    )
    plan = plan_of(tiny(runs))
    assert states(plan)["living_room-0/sphere/t2i"] == "skipped" and not plan.left
    # no claim or temporary left (the runner's released flock files stay, emptied)
    assert not [p for p in runs.rglob(".*") if not (p.name == ".lock" and p.read_text() == "")]


def test_changed_settings_are_named_as_the_runner_names_them(tiny_run):
    from snell_bench.experiment.cells import SettingsChanged
    from snell_bench.experiment.runner import run_grid

    plan = plan_of(tiny(tiny_run, "sampler.steps=5"))
    assert {c.state for c in plan.cells} == {"changed"} and len(plan.left) == 2
    assert all(c.diff["sampler.steps"] == (4, 5) for c in plan.cells)
    with pytest.raises(SettingsChanged) as e:
        run_grid(compose(tiny(tiny_run, "sampler.steps=5")))
    assert "sampler.steps: 4 -> 5 (2 cells)" in str(e.value)
    assert len(plan.warnings) == 1 and "sampler.steps: 4 -> 5 (2 cells)" in plan.warnings[0]
    assert "grid.on_change=recompute" in plan.warnings[0]
    assert not plan_of(tiny(tiny_run, "sampler.steps=5", "grid.on_change=recompute")).warnings
    assert {c.state for c in plan_of(tiny(tiny_run, "grid.recompute=true")).cells} == {"recompute"}
    # output paths, progress bars and the plan's own settings are not settings of a cell
    assert {c.state for c in plan_of(tiny(tiny_run, "sampler.progress=false")).cells} == {"done"}


def test_model_calls_equal_the_sampler_s(tiny_run):
    for method in ("snellcaster", "t2i"):
        cell = tiny_run / "smoke" / "living_room-0" / "sphere" / method
        recorded = json.loads((cell / "metrics.json").read_text())["model_calls"]
        settings = OmegaConf.to_object(
            OmegaConf.merge(OmegaConf.structured(SamplerSettings), OmegaConf.load(cell / "config.yaml").sampler)
        )
        assert model_calls(settings) == recorded, method
    # by hand: one call per step per branch, plus one per window step 0.2 T <= i < 0.8 T for a branch that
    # travelled (guided), or R - 1 per window step (repaint: 44 main-view calls at T = 20; the authors' loop makes 56 per view, see below)
    assert model_calls(SamplerSettings()) == {"main": 20 + 12, "pano": 20}
    assert model_calls(SamplerSettings(tt_mode="repaint")) == {"main": 20 + 2 * 12, "pano": 20}
    assert model_calls(SamplerSettings(tt_repeats_pano=3)) == {"main": 32, "pano": 32}
    assert model_calls(SamplerSettings(panorama=False)) == {"main": 32, "pano": 0}
    assert model_calls(SamplerSettings(sync="none")) == {"main": 20, "pano": 0}
    assert model_calls(SamplerSettings(steps=4)) == {"main": 4 + 3, "pano": 4}  # window 0.8 <= i < 3.2


# ---------------------------------------------------------------------------- composing per part
@pytest.mark.parametrize(
    "overrides",
    [
        [
            "model=tiny_flux",
            "grid.scenes=[living_room,tum_office]",
            "grid.variations=[2]",
            "grid.objects=[sphere:1.333,fox]",
            "grid.methods=[no_dpa,snellcaster_relit]",
            "sampler.steps=6",
            "++method.sampler.lam=0.3",
            "segment=tiny_sam3",
            "depth=tiny_depth_pro",  # the paper's scene pipeline of a text-to-image model (the photo keeps its depth)
            "scene.width=320",
            "scene.height=176",
        ],
        [
            "model=tiny_flux",
            "scene.source=generated",
            "depth=tiny_depth_pro",
            "grid.variations=[0,1]",
            "grid.methods=[inpaint,flux2_dev]",
            "scene.width=320",
            "scene.height=176",
        ],
    ],
)
def test_parts_give_what_composing_every_cell_gives(overrides):
    from snell_bench.experiment.order import cell_models
    from snell_bench.experiment.plan import result_settings
    from snell_bench.experiment.runner import plan_grid

    cfg = compose(["+experiment=smoke", *overrides])
    cells = plan_grid(cfg)
    parts = GridParts(cfg)
    for cell in cells:
        r = cell.record
        ident = (r["scene"], r["variation"], r["object_spec"], r["method"])
        assert parts.settings(*ident) == result_settings(cell.config), cell.name
        models = group_models(cell.extra["inputs_config"]) + cell_models(cell.config)
        assert parts.models(r["scene"], r["method"]) == models, cell.name
    g = cfg.grid
    assert parts.compositions == len(g.scenes) + len(g.objects) + len(g.methods)  # not one per cell


# ---------------------------------------------------------------------------- models and weights
def test_the_main_grid_is_planned_per_part_and_names_missing_weights(empty_caches):
    runs = empty_caches / "runs"
    calls = []

    def counting(overrides):
        calls.append(overrides)
        return compose(overrides)

    t0 = time.perf_counter()
    plan = plan_of(["+experiment=main", "model=flux_dev", f"runs_dir={runs}"], compose_fn=counting)
    seconds = time.perf_counter() - t0
    assert len(plan.cells) == 1800 and plan.groups == 300 and {c.state for c in plan.cells} == {"new"}
    assert len(calls) == 10 + 6  # one composition per scene and per method, none per cell (~0.1 s each)
    assert seconds < 60, seconds  # composing the 1800 cells one by one takes minutes
    models = {m.kind if m.kind != "pipeline" else m.name: m for m in plan.models}
    assert models["generator"].weights == "missing" and "model.path=/data/FLUX.1-dev" in models["generator"].fix
    assert models["fill"].weights == "missing" and "model.fill.model_id=/data/FLUX.1-Fill-dev" in models["fill"].fix
    # the paper's scene pipeline: FLUX.1-dev generates every group's I⁻ (so every cell needs it), MoGe-2
    # estimates its depth, SAM 3 finds the surface
    assert models["generator"].cells == 1800 and models["fill"].cells == 300 and models["fill"].methods == ["inpaint"]
    assert (
        models["depth"].name == "moge2"
        and models["depth"].weights == "missing"
        and "depth.path=" in models["depth"].fix
    )
    assert models["segmenter"].name == "SAM 3" and models["segmenter"].weights == "missing"
    assert "segment.path=" in models["segmenter"].fix
    for name, method in (("FLUX.2-dev", "flux2_dev"), ("Qwen-Image", "qwen_image"), ("SD3.5-Large", "sd35_large")):
        assert models[name].weights == "missing" and f"conf/method/{method}.yaml" in models[name].fix
        assert "method.model_id=" in models[name].fix and models[name].needs_gpu
    for kind, key in (("lpips", "lpips_weights"), ("clip", "clip_weights"), ("image_reward", "image_reward_python")):
        assert models[kind].weights == "missing" and f"metrics.{key}=" in models[kind].fix
    text = format_plan(plan)
    assert "MISSING FLUX.1-dev" in text and "set model.path=/data/FLUX.1-dev" in text
    assert "documented basis" in text and "not a measurement" in text and "no CUDA GPU here" in text
    assert not runs.exists()


def test_random_init_needs_no_flux_weights(empty_caches):
    plan = plan_of(["+experiment=main", "model=flux_dev", "model.random_init=true", f"runs_dir={empty_caches}/runs"])
    by_kind = {m.kind: m for m in plan.models}
    assert by_kind["generator"].weights == by_kind["fill"].weights == "random"
    assert not by_kind["generator"].fix and "random weights, real shapes, meaningless pixels" in format_plan(plan)
    assert {m.weights for m in plan.models if m.kind == "pipeline"} == {"missing"}  # the baselines are not FLUX.1


def test_weights_found_are_named(empty_caches):
    folder = empty_caches / "FLUX.1-dev"
    folder.mkdir()
    (folder / "model_index.json").write_text("{}")
    lora = empty_caches / "relight.safetensors"
    lora.write_bytes(b"")
    plan = plan_of(
        [
            "+experiment=ablation",
            "model=flux_dev",
            "preset=paper",
            f"model.path={folder}",
            f"relight.lora={lora}",
            "grid.scenes=[living_room]",
            "grid.methods=[snellcaster_relit]",
        ]
    )
    by_kind = {m.kind: m for m in plan.models}
    assert by_kind["generator"].weights == "found" and by_kind["generator"].where == str(folder)
    assert by_kind["lora"].weights == "found" and by_kind["lora"].where == str(lora.parent)
    assert by_kind["relighter"].weights == "missing" and "model.relighter.model_id=" in by_kind["relighter"].fix


def test_the_default_clip_lookup_agrees_with_the_metric(monkeypatch, empty_caches):
    from snell_bench.metrics.alignment import CLIP_DEFAULT, default_clip_checkpoint, resolve_clip_checkpoint
    from snell_bench.metrics.functional import MetricUnavailable

    for fn in (default_clip_checkpoint, lambda: resolve_clip_checkpoint(None)):
        with pytest.raises(MetricUnavailable):
            fn()
    repo, names, _ = CLIP_DEFAULT
    entry = empty_caches / "hub" / f"models--{repo.replace('/', '--')}"
    (entry / "snapshots" / "abc").mkdir(parents=True)
    (entry / "refs").mkdir()
    (entry / "refs" / "main").write_text("abc")
    (entry / "snapshots" / "abc" / names[1]).write_bytes(b"")
    assert default_clip_checkpoint() == resolve_clip_checkpoint(None) == str(entry / "snapshots" / "abc" / names[1])


# ---------------------------------------------------------------------------- time and memory
def bench(path: Path, **change) -> Path:
    data = {
        "device": "NVIDIA H100 80GB HBM3",
        "dtype": "bfloat16",
        "random_weights": True,
        "settings": {"steps": 20, "height": 720, "width": 1280, "pano_height": 1024, "recipe": "paper"},
        "pair": {
            "total_s": 41.0,
            "model_calls": {"main": 32, "pano": 20},
            "per_step_s": {"transformer": 1.5, "vae_decode": 0.2, "vae_encode": 0.1, "warps_blends": 0.1},
            "peak_memory_gb": 39.0,
            "host_device_bytes_per_step": 0,
        },
        "t2i": {"total_s": 7.0, "steps": 20, "peak_memory_gb": 36.0},
        "fill": {"total_s": 12.0, "steps": 30, "peak_memory_gb": 37.0},
        "kontext": {"total_s": 33.0, "steps": 28, "candidates": 3, "peak_memory_gb": 38.0},
        "memory_gb": {"flux_dev": 33.7, "fill": 33.7, "kontext": 33.7, "shared_text_vae": 9.9},
    }
    for key, value in change.items():
        *parents, leaf = key.split("__")
        node = data
        for p in parents:
            node = node[p]
        if value is None:
            node.pop(leaf)
        else:
            node[leaf] = value
    path.write_text(json.dumps(data))
    return path


GPU_GRID = [
    "+experiment=main",
    "model=flux_dev",
    "grid.scenes=[living_room]",
    "grid.variations=[0]",
    "grid.objects=[sphere]",
    "grid.methods=[snellcaster,t2i,inpaint,snellcaster_relit,qwen_image,flux2_dev]",
]


def test_the_readme_basis_scaled_by_model_calls(tmp_path):
    plan = plan_of([*GPU_GRID, f"runs_dir={tmp_path}"])
    t = {x.method: x for x in plan.times}
    main, pano = 720 * 1280, 2 * 1024 * 1024
    # the basis: the authors' 56 + 56 calls (test_the_authors_loop_makes_56_calls_per_view); ours 32 + 20
    ratio = (32 * main + 20 * pano) / (56 * main + 56 * pano)
    assert ratio == pytest.approx(0.4226, abs=1e-4)
    assert t["snellcaster"].per_cell == pytest.approx((50 * ratio, 75 * ratio), rel=1e-12)
    assert t["t2i"].per_cell == (10.0, 10.0) and t["inpaint"].per_cell == (15.0, 15.0)
    relit = 20 * 20.0  # relight.candidates = 20 at Kontext's 20 s
    assert t["snellcaster_relit"].per_cell == pytest.approx((50 * ratio + relit, 75 * ratio + relit), rel=1e-12)
    assert t["qwen_image"].per_cell == (60.0, 60.0) and t["flux2_dev"].per_cell is None
    assert t["snellcaster_relit"].weights_gb == 34 + 34 - 10  # Kontext shares the text encoders and VAE
    assert {x.basis for x in plan.times} == {"README", "none"} and plan.basis is README_BASIS
    half = {x.method: x for x in plan_of([*GPU_GRID, f"runs_dir={tmp_path}", "sampler.steps=10"]).times}
    assert half["t2i"].per_cell == (5.0, 5.0)  # linear in model calls


def test_a_bench_file_sets_the_figures_and_the_label(tmp_path):
    plan = plan_of([*GPU_GRID, f"runs_dir={tmp_path}", f"plan.bench={bench(tmp_path / 'bench.json')}"])
    t = {x.method: x for x in plan.times}
    assert plan.basis.label.startswith(
        "measured: benchmarks/bench_gpu.py on NVIDIA H100 80GB HBM3 (bfloat16 with random"
    )
    assert t["snellcaster"].per_cell == (41.0, 41.0) and t["snellcaster"].peak_gb == 39.0  # the bench's settings
    assert t["t2i"].per_cell == (7.0, 7.0) and t["inpaint"].per_cell == (12.0, 12.0)
    assert t["snellcaster_relit"].per_cell == pytest.approx((41.0 + 20 * 11.0,) * 2)  # 33 s for 3 candidates
    assert {x.method: x.basis for x in plan.times} == {
        "snellcaster": "bench",
        "t2i": "bench",
        "inpaint": "bench",
        "snellcaster_relit": "bench",
        "qwen_image": "README",  # the bench does not measure the baselines
        "flux2_dev": "none",
    }
    assert t["snellcaster_relit"].weights_gb == pytest.approx(33.7 * 2 - 9.9)
    text = format_plan(plan)
    assert "bench: measured: benchmarks/bench_gpu.py" in text and "README: estimate: documented basis" in text


@pytest.mark.parametrize(
    "content,error,match",
    [
        ("{not json", ConfigError, r"plan.bench='.*bench.json' is not a JSON file"),
        (None, ConfigError, r"(?s)pair.total_s missing.*t2i.steps 0 is not usable"),
        ("missing", FileNotFoundError, r"plan.bench='.*nowhere.json': no such bench_gpu.py JSON file"),
    ],
)
def test_a_malformed_bench_file_names_plan_bench(tmp_path, content, error, match):
    path = tmp_path / "bench.json"
    if content is None:
        bench(path, pair__total_s=None, t2i__steps=0)
    elif content == "missing":
        path = tmp_path / "nowhere.json"
    else:
        path.write_text(content)
    with pytest.raises(error, match=match):
        plan_of([*GPU_GRID, f"runs_dir={tmp_path}", f"plan.bench={path}"])


def test_memory_counts_shared_weights_and_plans_offloading(tmp_path):
    grid = [*GPU_GRID[:-1], "grid.methods=[snellcaster,inpaint,snellcaster_relit,flux2_dev]", f"runs_dir={tmp_path}"]
    plan = plan_of(grid, device=H100)
    # the FLUX family (the scene pipeline's MoGe-2 and SAM 3 are left out: this counts shared weights)
    flux = [m for m in plan.models if m.name != "FLUX.2-dev" and m.kind not in ("depth", "segmenter")]

    def memory(device=H100, basis=README_BASIS, **models):
        models_cfg = OmegaConf.create({"memory_gb": None, "offload": True, **models})
        return "\n".join(memory_plan(flux, models_cfg, device, basis))

    h100 = memory()
    assert h100.startswith("GPU weights together: 82 GB")  # 3 x 34 GB, the 10 GB of text encoders + VAE once
    assert "activations: 10 GB" in h100  # 82 + 10 > 85 GB
    assert "do not fit together on NVIDIA H100 80GB HBM3 (85 GB): set models.memory_gb=69 (GiB" in h100  # 75 GB
    assert "they fit together on NVIDIA H200" in memory(H200)
    budget = memory(memory_gb=40)
    assert "model-major" in budget and "do not fit together" in budget and "host memory (models.offload=true)" in budget
    assert "dropped and loaded again" in memory(memory_gb=40, offload=False)
    measured = memory(basis=load_bench(bench(tmp_path / "bench.json")))
    assert "activations: 5 GB (the bench's largest peak less its weights)" in measured  # 39 - 33.7
    assert "FLUX.2-dev (112 GB) is larger than NVIDIA H100 80GB HBM3 (85 GB): it cannot load there" in plan.memory
    assert "device: CUDA NVIDIA H100 80GB HBM3" in format_plan(plan)


# ---------------------------------------------------------------------------- the command line
def run_cli(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(
        os.environ,
        HF_HUB_OFFLINE="1",
        HF_HUB_CACHE=str(cwd.parent / "hub"),
        TORCH_HOME=str(cwd.parent / "torch"),
        HOME=str(cwd.parent / "home"),
    )
    return subprocess.run(
        [sys.executable, "-m", "snell_bench", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )


def test_the_command_line_prints_the_plan_and_writes_nothing(tmp_path):
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    res = run_cli(cwd, "job=plan", "+experiment=main", "model=flux_dev")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "1800 cells" in res.stdout and "set model.path=/data/FLUX.1-dev" in res.stdout
    assert "documented basis" in res.stdout
    assert list(cwd.rglob("*")) == []  # no runs/ folder, no Hydra folder, .hydra/ or log file


def test_a_plan_is_never_a_sweep(tmp_path):
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    res = run_cli(cwd, "-m", "job=plan", "+experiment=smoke")
    assert res.returncode != 0 and "run it without -m/--multirun" in res.stderr
    assert list(cwd.rglob("*")) == []


def test_the_authors_loop_makes_56_calls_per_view():
    """Walk the authors' dual-view loop (pipeline_snellcaster_flux_dual_view.py) step by step: each
    step calls ``_compute_noise_predictions`` once (the transformer on both views); a step with
    ``int(0.2 T) <= i < int(0.8 T)`` and R > 1 then runs ``_apply_time_travel``: R - 1 renoise-and-call
    rounds (both views; ``tt_sigma_idx > 0`` there) and one re-prediction (both views)."""
    from snell_bench.experiment.estimate import README_BASIS
    from snell_bench.sampler.authors_calls import authors_model_calls

    def walk(T, R, start=0.2, end=0.8):
        t_start, t_end = int(T * start), int(T * end)
        main = pano = 0
        for i in range(T):
            main, pano = main + 1, pano + 1  # the step's own call
            if t_start <= i < t_end and R > 1:
                tt_sigma_idx = i
                for _ in range(R - 1):
                    if tt_sigma_idx <= 0:
                        break
                    main, pano = main + 1, pano + 1  # at the noisier level, output discarded
                main, pano = main + 1, pano + 1  # the re-prediction at the step's level
        return {"main": main, "pano": pano}

    assert walk(20, 3) == {"main": 56, "pano": 56}
    assert README_BASIS.pair_calls == (56, 56)
    for T, R, window in ((20, 3, [0.2, 0.8]), (20, 1, [0.2, 0.8]), (28, 2, [0.2, 0.8]), (10, 4, [0.0, 0.5])):
        s = SamplerSettings(steps=T, tt_repeats_main=R, tt_window=window)
        assert authors_model_calls(s) == walk(T, R, *window), (T, R, window)
