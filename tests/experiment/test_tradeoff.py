"""The speed/accuracy sweep, a grid of named override sets: settings, resolved knobs, model calls, reuse,
resume, report, Pareto front."""

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra.core.config_store import ConfigStore
from omegaconf import OmegaConf

from snell_bench.config import compose

#: Test-size presets (the real ones are 640 x 360 and larger): the run uses ``tiny_base``, and the
#: sweep measures ``tiny`` as a preset point (a preset replaces the run's preset, as on the command line).
TINY_BASE = {
    "scene": {"width": 112, "height": 64, "supersample": 1},
    "warps": {"pano_height": 32, "max_bounces": 8},
    "sampler": {"steps": 5, "levels": 2, "tt_repeats_main": 3, "tt_repeats_pano": 1},
    "reference": {"spp": 1, "true_spp": 1},
}
TINY_PRESET = OmegaConf.to_container(
    OmegaConf.merge(
        TINY_BASE, {"sampler": {"steps": 4, "tt_repeats_main": 1, "levels": 1}, "warps": {"max_bounces": 4}}
    )
)
for _name, _node in (("tiny_base", TINY_BASE), ("tiny", TINY_PRESET)):
    ConfigStore.instance().store(group="preset", name=_name, node=_node, package="_global_")

TINY = ["preset=tiny_base", "grid.converged_spp=3"]
SCENES = ["living_room", "kitchen"]
AXES = [
    "grid.axes.steps='sampler.steps=3,5'",  # 5 is the base value
    "grid.axes.spp='reference.spp=1,2'",  # 1 is the base value
    "grid.only=[steps,spp]",
]
SETTINGS = ["baseline", "steps=3", "steps=5", "spp=1", "spp=2", "preset:tiny"]


def make_cfg(tmp_path, overrides=(), axes=AXES, presets=("tiny",), scenes=SCENES):
    return compose(
        [
            "+experiment=tradeoff",
            *TINY,
            f"runs_dir={tmp_path / 'runs'}",
            f"reports_dir={tmp_path / 'reports'}",
            f"output_dir={tmp_path}",
            *axes,
            f"grid.presets=[{','.join(presets)}]",
            f"grid.scenes=[{','.join(scenes)}]",
            *overrides,
        ]
    )


def results(root: Path) -> dict:
    """``{"<scene>-0/<setting slug>": record}`` of the sweep's cells (``<scene>-0/sphere/snellcaster@<slug>``)."""
    out = {}
    for p in sorted(root.glob("*/sphere/*/metrics.json")):
        out[f"{p.parent.parent.parent.name}/{p.parent.name.split('@', 1)[1]}"] = json.loads(p.read_text())
    return out


def run(cfg):
    from snell_bench.experiment.runner import run_grid

    return run_grid(cfg)


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tradeoff")
    cfg = make_cfg(tmp)
    return tmp, cfg, run(cfg)


# ---------------------------------------------------------------------------- Pareto front
def brute_force_front(cost, score):
    n = len(cost)
    out = np.zeros(n, bool)
    for i in range(n):
        if math.isnan(cost[i]) or math.isnan(score[i]):
            continue
        dominated = False
        for j in range(n):
            if j == i or math.isnan(cost[j]) or math.isnan(score[j]):
                continue
            if cost[j] <= cost[i] and score[j] >= score[i] and (cost[j] < cost[i] or score[j] > score[i]):
                dominated = True
                break
        out[i] = not dominated
    return out


def test_pareto_front_matches_brute_force_with_ties_and_nan():
    from snell_bench.reports import pareto_front

    rng = np.random.default_rng(0)
    for trial in range(300):
        n = int(rng.integers(0, 25))
        # small integer grids make ties in cost, in score and identical points frequent
        cost = rng.integers(0, 6, n).astype(float) if trial % 2 else rng.random(n)
        score = rng.integers(0, 6, n).astype(float) if trial % 3 else rng.random(n)
        cost[rng.random(n) < 0.15] = np.nan
        score[rng.random(n) < 0.15] = np.nan
        got = pareto_front(cost, score)
        assert got.dtype == bool and got.shape == (n,)
        np.testing.assert_array_equal(got, brute_force_front(cost, score), err_msg=f"{cost} {score}")
    # hand-made: identical best points are both on the front; a same-cost lower score is not
    np.testing.assert_array_equal(
        pareto_front([1, 1, 1, 2, 0.5, np.nan], [5, 5, 4, 6, 1, 9]), [True, True, False, True, True, False]
    )
    assert not pareto_front([np.nan, np.nan], [1, 2]).any()
    with pytest.raises(ValueError, match="same length"):
        pareto_front([1, 2], [1])


# ---------------------------------------------------------------------------- settings and errors
def test_axes_formats_labels_and_presets(tmp_path):
    from snell_bench.config.grid import CellId, grid_settings

    cfg = make_cfg(
        tmp_path,
        axes=[
            "+grid.axes.pano='warps.pano_height=256'",
            "+grid.axes.res={320x180:['scene.width=320','scene.height=180']}",
            "grid.only=[res,pano]",
        ],
        presets=("fast",),
    )
    s = grid_settings(cfg.grid)
    assert [x.label for x in s] == ["baseline", "res=320x180", "pano=256", "preset:fast"]
    assert s[1].overrides == ("scene.width=320", "scene.height=180") and s[1].value == "320x180"
    assert s[2].value == 256 and s[3].slug == "preset-fast" and s[3].overrides == ("preset=fast",)
    assert [x.label for x in grid_settings(make_cfg(tmp_path).grid)] == SETTINGS
    # crossed with the methods, innermost; a setting's overrides last, so they win
    cells = list(CellId.grid(cfg.grid))
    assert [c.entry for c in cells[:4]] == [
        "snellcaster@baseline",
        "snellcaster@res=320x180",
        "snellcaster@pano=256",
        "snellcaster@preset-fast",
    ]
    assert cells[1].overrides()[-3:] == ["method=snellcaster", "scene.width=320", "scene.height=180"]
    # no axes and no presets: the plain grid
    assert grid_settings(make_cfg(tmp_path, axes=["grid.only=[]"], presets=()).grid) == []
    # the experiment file itself: 1 + 5 + 4 + 3 + 4 + 5 + 3 + 3 + 6 + 3 settings
    full = compose(["+experiment=tradeoff", "output_dir=/tmp/x"])
    labels = [x.label for x in grid_settings(full.grid)]
    assert len(labels) == 37 and "resolution=1280x720-ss2" in labels and labels[-1] == "preset:paper"
    assert full.scene.width == 640 and full.sampler.steps == 20 and full.reference.spp == 242


@pytest.mark.parametrize(
    "axes, match",
    [
        (["grid.axes.steps='sampler.stepz=3'", "grid.only=[steps]"], "sampler.stepz"),
        (["+grid.axes.res={a:['scene.widht=320']}", "grid.only=[res]"], "scene.widht"),
        (["grid.axes.steps='sampler=3'", "grid.only=[steps]"], "sampler"),
        (["grid.axes.steps='sampler.steps=many'", "grid.only=[steps]"], "sampler.steps"),
        (["grid.axes.steps='sampler.steps=3,3'", "grid.only=[steps]"], "duplicate"),
        (["grid.axes.steps='sampler.steps='", "grid.only=[steps]"], "steps"),
        (["grid.only=[stepz]"], "stepz"),
    ],
)
def test_bad_axes_fail_before_any_folder_is_written(tmp_path, axes, match):
    cfg = make_cfg(tmp_path, axes=axes, presets=())
    with pytest.raises(ValueError, match=match) as e:
        run(cfg)
    assert "grid" in str(e.value)
    assert not (tmp_path / "runs").exists() and not (tmp_path / "reports").exists()


def test_unknown_preset_fails_before_work(tmp_path):
    with pytest.raises(ValueError, match="quick_and_dirty"):
        run(make_cfg(tmp_path, presets=("quick_and_dirty",)))
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize(
    "overrides, expect",
    [
        # guided time travel (the paper's): a step of the window [0.2 T, 0.8 T) that travels costs the main
        # view one more call (the re-prediction at t), whatever the repeats; T = 5: window [1, 4), steps 1-3
        (["sampler.steps=5"], {"main": 5 + 3, "pano": 5}),
        (["sampler.steps=3"], {"main": 3 + 2, "pano": 3}),  # window [0.6, 2.4): steps 1, 2
        (["sampler.steps=4", "sampler.tt_repeats_main=1"], {"main": 4, "pano": 4}),
        # travel length 2: step 1 cannot go two levels back (index -1), steps 2 and 3 travel
        (["sampler.steps=5", "sampler.tt_length=2", "sampler.tt_repeats_main=2"], {"main": 5 + 2, "pano": 5}),
        (["sampler.steps=4", "method=no_pano"], {"main": 4 + 3, "pano": 0}),  # window [0.8, 3.2): 1, 2, 3
        # repaint: each step of the window run 3 times on the main view, every run a model call
        (["sampler.steps=5", "sampler.tt_mode=repaint"], {"main": 5 + 2 * 3, "pano": 5}),
        (
            ["sampler.steps=5", "sampler.tt_mode=repaint", "sampler.tt_length=2", "sampler.tt_repeats_main=2"],
            {"main": 1 + 2 * 2 * 2, "pano": 5},
        ),
    ],
)
def test_recorded_model_calls_are_the_generators_calls(overrides, expect):
    """The sampler's count against the calls the generator receives (per image in each batch)."""
    from snell_bench import pipeline
    from snell_bench.pipeline.cell import node_key
    from snell_bench.pipeline.methods import generator_scope

    base = ["preset=tiny_base", "warps.cache_dir=null", "reference.enabled=false", "reference.true_render=false"]
    cfg = pipeline.apply_method(compose([*base, *overrides, "output_dir=/tmp/x"]))
    inputs = pipeline.prepare_inputs(cfg, references=False)
    gen = pipeline.build_generator(cfg.model, inputs)
    seen = {"main": 0, "pano": 0}
    velocity = gen.velocity

    def counting(z, sigma, cond):
        for prompt in cond.prompts:
            seen["pano" if prompt == cfg.scene.pano_prompt else "main"] += 1
        return velocity(z, sigma, cond)

    gen.velocity = counting
    inputs.pool.put("generator", node_key(cfg.model), gen, scope=generator_scope(inputs))
    res = pipeline.run_method(cfg, inputs)
    assert res.stats["model_calls"] == seen == expect


# ---------------------------------------------------------------------------- the sweep
def test_every_run_recorded_with_its_knobs(sweep):
    tmp, cfg, summary = sweep
    assert summary["ok"] == len(SCENES) * len(SETTINGS) and summary["failed"] == 0, summary
    res = results(tmp / "runs" / "tradeoff")
    assert sorted(res) == sorted(f"{s}-0/{x.replace(':', '-')}" for s in SCENES for x in SETTINGS)
    base_knobs = {
        "steps": 5,
        "tt_repeats_main": 3,
        "tt_repeats_pano": 1,
        "levels": 2,
        "max_bounces": 8,
        "width": 112,
        "height": 64,
        "supersample": 1,
        "pano_height": 32,
        "spp": 1,
    }
    from snell_bench.experiment.sweep import KNOBS

    by_key = {v: k for k, v in KNOBS.items()}
    tiny_knobs = {
        "steps": 4,
        "tt_repeats_main": 1,
        "tt_repeats_pano": 1,
        "levels": 1,
        "max_bounces": 4,
        "width": 112,
        "height": 64,
        "supersample": 1,
        "pano_height": 32,
        "spp": 1,
    }
    for where, r in res.items():
        assert r["status"] == "ok" and r["scene"] == where.split("/")[0].rsplit("-", 1)[0]
        if r["axis"] == "preset":
            expect = tiny_knobs
        else:
            expect = dict(base_knobs, **{by_key[k]: v for k, v in r["overrides"].items()})
        assert r["knobs"] == expect, where
        t = r["timings_s"]
        assert t["total"] == pytest.approx(t["warps"] + t["sampling"] + t["reference"] + t["metrics"], abs=2e-4)
        assert all(t[k] >= 0 for k in ("scene", "warps", "reference", "true_render", "sampling", "metrics"))
        assert set(r["sampler_timings_s"]) >= {"model", "codec", "warp_blend"}
        folder = tmp / "runs" / "tradeoff" / where.split("/")[0] / "sphere" / f"snellcaster@{where.split('/')[1]}"
        assert (folder / "image.png").is_file() and r["method"] == folder.name and r["method_name"] == "snellcaster"
    pre = res["kitchen-0/preset-tiny"]
    assert pre["axis"] == "preset" and pre["value"] == "tiny"
    assert pre["overrides"] == {"preset": "tiny"}
    assert res["living_room-0/steps=3"]["axis"] == "steps" and res["living_room-0/steps=3"]["value"] == 3


def test_model_calls_follow_the_steps_axis(sweep):
    tmp, cfg, _ = sweep
    res = results(tmp / "runs" / "tradeoff")
    for scene in SCENES:
        base = res[f"{scene}-0/baseline"]["model_calls"]
        # T = 5: the time-travel window [0.2 T, 0.8 T) holds steps 1, 2, 3, each re-predicted once after travelling
        assert base == {"main": 5 + 3, "pano": 5}
        assert res[f"{scene}-0/steps=3"]["model_calls"] == {"main": 3 + 2, "pano": 3}  # window [0.6, 2.4)
        assert res[f"{scene}-0/steps=5"]["model_calls"] == base
        assert res[f"{scene}-0/preset-tiny"]["model_calls"] == {"main": 4, "pano": 4}  # no extra repeats


def test_shared_stages_are_reused_with_identical_times(sweep):
    tmp, _, _ = sweep
    res = results(tmp / "runs" / "tradeoff")
    shared = ("scene", "warps", "reference", "true_render")
    for scene in SCENES:
        base = res[f"{scene}-0/baseline"]
        assert base["inputs_dir"] == "_inputs"  # the group's, as in every grid
        for s in ("steps=3", "steps=5", "spp=1"):  # same scene/object/warps/reference subtrees
            r = res[f"{scene}-0/{s}"]
            assert r["inputs_key"] == base["inputs_key"] and r["inputs_dir"] == "_inputs"
            assert {k: r["timings_s"][k] for k in shared} == {k: base["timings_s"][k] for k in shared}
        for s in ("spp=2", "preset-tiny"):
            r = res[f"{scene}-0/{s}"]
            assert r["inputs_key"] != base["inputs_key"] and r["inputs_dir"] == f"_shared/{r['inputs_key']}/_inputs"
        # a value equal to the base is the baseline again (deterministic for the seed)
        assert res[f"{scene}-0/steps=5"]["metrics"] == base["metrics"]
        assert res[f"{scene}-0/spp=1"]["metrics"] == base["metrics"]


def test_lpips_missing_with_reason_and_reference_convergence(sweep):
    from snell_bench.reports import collect_tradeoff

    tmp, _, _ = sweep
    res = results(tmp / "runs" / "tradeoff")
    for where, r in res.items():
        assert r["metrics"]["lpips"] is None and "lpips_weights" in r["missing"]["lpips"], where
        assert set(r["metrics"]) >= {
            "psnr",
            "mae",
            "lpips",
            "psnr_true",
            "psnr_converged",
            "mae_converged",
            "lpips_converged",
        }
        assert math.isfinite(r["metrics"]["psnr_converged"]) and r["converged_reference"]["spp"] == 3
        assert math.isfinite(r["metrics"]["psnr"]) and math.isfinite(r["metrics"]["psnr_true"])
    df = collect_tradeoff(tmp / "runs" / "tradeoff").set_index(["scene", "setting"])
    for scene in SCENES:
        low, high = df.loc[(scene, "spp=1")], df.loc[(scene, "spp=2")]
        assert np.isnan(high["reference_psnr_vs_max_spp"])  # the comparison reference itself
        assert 5 < low["reference_psnr_vs_max_spp"] < 80
        assert np.isnan(df.loc[(scene, "baseline"), "reference_psnr_vs_max_spp"])


def test_report_tables_and_pareto_flags(sweep):
    from snell_bench.reports import build_reports, pareto_front

    tmp, _, _ = sweep
    out = tmp / "reports" / "tradeoff"
    for name in ("tradeoff.csv", "tradeoff.md", "pareto.png", "tradeoff.html", "index.html", "plotly.min.js"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    df = pd.read_csv(out / "tradeoff.csv")
    assert len(df) == len(SCENES) * len(SETTINGS)
    assert sorted(zip(df["scene"], df["setting"])) == sorted((s, x) for s in SCENES for x in SETTINGS)
    means = df[df["status"] == "ok"].groupby("setting", sort=False)[["timings_s.total", "psnr_converged"]].mean()
    expect = dict(zip(means.index, pareto_front(means["timings_s.total"], means["psnr_converged"])))
    md = (out / "tradeoff.md").read_text()
    rows = {}
    for line in md.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        name = cells[0].strip("*")
        if name in SETTINGS and len(cells) == 16:
            rows[name] = cells
    assert sorted(rows) == sorted(SETTINGS)
    assert {k: "★" in v[-1] for k, v in rows.items()} == expect
    assert any(expect.values())
    assert rows["preset:tiny"][0] == "**preset:tiny**" and rows["baseline"][0] == "baseline"
    assert all("missing" in v[12] for v in rows.values())  # LPIPS column
    # the reference's self-noise (two halves): a number wherever the tiny preset renders spp >= 2
    own = df.groupby("setting")["reference_self_noise_db"].mean()
    for name, cells in rows.items():
        assert cells[13].strip("*") == ("—" if np.isnan(own[name]) else f"{own[name]:.2f}"), (name, cells[13])
    assert own.notna().any()
    assert "lpips_weights" in md and "Reference convergence" in md
    # a pure function of the run folder: rebuilding elsewhere gives the same table
    again = build_reports(tmp / "runs" / "tradeoff", tmp / "rebuilt", "tradeoff")
    assert {"tradeoff.csv", "tradeoff.md", "pareto.png", "tradeoff.html", "index.html"} <= {p.name for p in again}
    assert (tmp / "rebuilt" / "tradeoff.csv").read_text() == (out / "tradeoff.csv").read_text()
    assert "tradeoff.html" in (out / "index.html").read_text() and "tradeoff.md" in (out / "README.md").read_text()
    # job=report rebuilds the same report (one report path)
    from snell_bench.experiment import run_job

    cfg = make_cfg(tmp, [f"reports_dir={tmp / 'via_job'}", "job=report"])
    run_job(cfg)
    assert (tmp / "via_job" / "tradeoff" / "tradeoff.csv").read_text() == (out / "tradeoff.csv").read_text()


def test_resume_skips_and_recompute_redoes(sweep):
    tmp, _, _ = sweep
    root = tmp / "runs" / "tradeoff"
    files = sorted(root.glob("*/sphere/*/metrics.json"))
    before = {p: p.stat().st_mtime_ns for p in files}
    metrics = {p: json.loads(p.read_text())["metrics"] for p in files}
    again = run(make_cfg(tmp))
    assert again["cached"] == len(files) and again["ok"] == 0
    assert {p: p.stat().st_mtime_ns for p in files} == before
    redo = run(make_cfg(tmp, ["grid.recompute=true"], scenes=["living_room"]))
    assert redo["ok"] == len(SETTINGS) and redo["cached"] == 0
    for p in files:
        changed = p.stat().st_mtime_ns != before[p]
        assert changed == (p.parent.parent.parent.name == "living_room-0"), p
        assert json.loads(p.read_text())["metrics"] == metrics[p]  # deterministic for the seed


def test_a_failing_setting_does_not_stop_the_sweep(tmp_path):
    cfg = make_cfg(
        tmp_path,
        ["reference.true_render=false"],
        axes=["+grid.axes.size='object.size=0.0001'", "grid.only=[size]"],  # too small to see: fails placing it
        presets=(),
        scenes=["living_room"],
    )
    summary = run(cfg)
    res = results(tmp_path / "runs" / "tradeoff")
    assert summary["ok"] == 1 and summary["failed"] == 1
    assert summary["exit_status"] == 3  # python -m snell_bench exits 3 after the report (grid.allow_failures)
    (label,) = [k for k, r in res.items() if r["status"] == "failed"]
    assert "object.size" in res[label]["reason"] and "too few to trace" in res[label]["reason"]
    ok = res["living_room-0/baseline"]
    assert ok["status"] == "ok" and ok["metrics"]["psnr_true"] is None  # no true render: no value, and why
    assert ok["missing"]["psnr_true"] == "no true render (reference.true_render=false)"
    md = (tmp_path / "reports" / "tradeoff" / "tradeoff.md").read_text()
    assert f"failed: living_room / {label.split('/')[1]}" in md


def test_an_unusable_setting_stops_the_sweep_before_any_work(tmp_path):
    cfg = make_cfg(
        tmp_path,
        [],
        axes=["grid.axes.levels='sampler.levels=0'", "grid.only=[levels]"],
        presets=(),
        scenes=["living_room"],
    )
    with pytest.raises(ValueError, match=r"sampler.levels=0: sampler.levels must be an integer >= 1, got 0"):
        run(cfg)
    assert not (tmp_path / "runs").exists()


def test_converged_reference_is_shared_and_independent_of_the_settings_spp(sweep):
    """Settings that differ only in reference.spp are scored against one converged reference: their
    PSNR against it is identical (same image), while PSNR against their own reference is not."""
    tmp, _, _ = sweep
    res = results(tmp / "runs" / "tradeoff")
    for scene in SCENES:
        a, b = res[f"{scene}-0/spp=1"], res[f"{scene}-0/spp=2"]
        assert a["converged_reference"] == b["converged_reference"]
        assert a["metrics"]["psnr_converged"] == b["metrics"]["psnr_converged"]
        assert a["metrics"]["psnr"] != b["metrics"]["psnr"]
    keys = {p.name for p in (tmp / "runs" / "tradeoff" / "living_room-0" / "sphere" / "_shared").iterdir()}
    assert sum(k.startswith("converged-") for k in keys) == 1  # one resolution, one object


def test_figure_keeps_the_bulk_and_points_at_isolated_outliers():
    from matplotlib.figure import Figure

    from snell_bench.reports import clip_outliers

    x = np.array([4.0, 8.0, 10.0, 12.0, 15.0, 17.0])
    y = np.array([26.1, 28.4, 27.4, 27.5, 27.4, 13.3])  # one isolated low point (one bounce)
    ax = Figure().add_subplot()
    ax.scatter(x, y)
    clip_outliers(ax, [f"s{i}" for i in range(6)], x, y)
    lo = ax.get_ylim()[0]
    assert 13.3 < lo < 26.1
    assert any("s5: 13.30 dB" in t.get_text() for t in ax.texts)
    ax2 = Figure().add_subplot()
    ax2.scatter(x[:5], y[:5])
    before = ax2.get_ylim()
    clip_outliers(ax2, [f"s{i}" for i in range(5)], x[:5], y[:5])  # a spread, no isolated cluster
    assert ax2.get_ylim() == before and not ax2.texts


def test_report_skips_files_that_are_not_records_and_shows_non_finite_metrics_as_missing(tmp_path, caplog):
    from snell_bench.reports import build_reports, collect_tradeoff, skipped_files
    from tests.reports.test_html_report import make_tradeoff_runs

    root = make_tradeoff_runs(tmp_path / "runs" / "tradeoff")
    d = root / "office-0" / "sphere" / "snellcaster@baseline"
    rec = json.loads((d / "metrics.json").read_text())
    (d / "metrics.json").write_text(json.dumps({**rec, "metrics": {**rec["metrics"], "psnr": float("-inf")}}))
    bad = {
        "office-0/sphere/snellcaster@steps=4/metrics.json": (
            b'{"status": "ok"}',
            "missing the keys scene, variation, object, method, metrics",
        ),
        "kitchen-0/sphere/snellcaster@res=large/metrics.json": (
            b"\xff\xfe",
            "not UTF-8 text (byte 0xff at position 0)",
        ),
    }
    for rel, (raw, _) in bad.items():
        (root / rel).write_bytes(raw)
    df = collect_tradeoff(root)
    assert dict(skipped_files(df)) == {rel: why for rel, (_, why) in bad.items()}
    assert all(f"{root / rel} is not a cell's record" in caplog.text for rel in bad)
    row = df[df["dir"] == "office-0/sphere/snellcaster@baseline"].iloc[0]
    assert math.isnan(row["psnr"]) and row["missing.psnr"] == "not finite in the record (-inf)"
    assert f"metric psnr is -inf in {d / 'metrics.json'}" in caplog.text
    out = tmp_path / "r"
    build_reports(root, out, "tradeoff")
    md = (out / "tradeoff.md").read_text()
    assert "; 2 files skipped (not cell records)" in md and "## Files skipped" in md
    assert (
        "- `office-0/sphere/snellcaster@steps=4/metrics.json`: missing the keys scene, variation, object, method, metrics"
        in md
    )
    assert "psnr: missing in 1 of" in md and "not finite in the record (-inf)" in md
    html = (out / "tradeoff.html").read_text()
    assert html.split('<section id="skipped">', 1)[1].split("</section>", 1)[0].count("<li>") == 2


def test_shards_keep_a_groups_settings_together(tmp_path):
    """A group's settings share its converged references (and most of them its inputs): one job
    computes them all, whatever inputs folder each uses."""
    from snell_bench.experiment.runner import plan_grid, shard_cells

    cells = plan_grid(make_cfg(tmp_path))
    assert len({c.shares for c in cells}) > len(SCENES)  # settings with inputs of their own
    parts = [shard_cells(cells, 2, k) for k in range(2)]
    assert sorted(c.name for p in parts for c in p) == sorted(c.name for c in cells)
    assert [{c.extra["id"].group for c in p} for p in parts] == [{"living_room-0/sphere"}, {"kitchen-0/sphere"}]
    assert not (tmp_path / "runs").exists()


def test_a_setting_at_the_configs_default_is_still_its_own(tmp_path):
    """``steps=20`` is the schema's default but not the run's (5): the report's same-settings check
    compares the cell with its run's baseline, so the sweep is reported, not refused."""
    cfg = make_cfg(
        tmp_path, axes=["grid.axes.steps='sampler.steps=20'", "grid.only=[steps]"], presets=(), scenes=["living_room"]
    )
    summary = run(cfg)
    assert summary["ok"] == 2 and summary["reports"]
    assert "steps=20" in (tmp_path / "reports" / "tradeoff" / "tradeoff.md").read_text()


def test_a_changed_converged_spp_changes_the_cells_settings(tmp_path):
    """``grid.converged_spp`` adds the ``*_converged`` scores: a finished cell run with another count
    (or none) is a changed cell, under ``grid.on_change`` like any result setting; a grid without it
    has the settings it had before the key existed."""
    from snell_bench.experiment.plan import result_settings

    def cfg(*extra):
        return make_cfg(
            tmp_path, ["reference.true_render=false", *extra], axes=["grid.only=[]"], presets=(), scenes=["living_room"]
        )

    assert result_settings(cfg())["grid.converged_spp"] == 3
    assert not any(k.startswith("grid.") for k in result_settings(cfg("grid.converged_spp=null")))
    assert run(cfg())["ok"] == 1
    with pytest.raises(ValueError, match=r"grid.converged_spp"):
        run(cfg("grid.converged_spp=4"))  # grid.on_change=error (the default): names the changed key
    redo = run(cfg("grid.converged_spp=4", "grid.on_change=recompute"))
    assert redo["ok"] == 1 and redo["cached"] == 0
    (path,) = (tmp_path / "runs" / "tradeoff").glob("*/sphere/*/metrics.json")
    assert json.loads(path.read_text())["converged_reference"]["spp"] == 4
