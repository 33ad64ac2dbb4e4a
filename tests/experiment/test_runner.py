"""The grid runner: the smoke experiment end to end, resume, failures, skips, parallel launchers."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from snell_bench.config import compose

REPO = Path(__file__).resolve().parents[2]

TINY = [
    "scene.width=160",
    "scene.height=96",
    "warps.pano_height=64",
    "warps.cache_dir=null",
    "sampler.steps=8",
    "reference.spp=4",
    "reference.true_spp=1",
]


def make_cfg(tmp_path, overrides):
    return compose(
        [
            "+experiment=smoke",
            *TINY,
            f"runs_dir={tmp_path / 'runs'}",
            f"reports_dir={tmp_path / 'reports'}",
            f"output_dir={tmp_path}",
            *overrides,
        ]
    )


def metrics_of(root: Path) -> dict:
    return {str(p.parent.relative_to(root)): json.loads(p.read_text()) for p in sorted(root.rglob("metrics.json"))}


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    from snell_bench.experiment.runner import run_grid

    tmp = tmp_path_factory.mktemp("smoke")
    summary = run_grid(make_cfg(tmp, []))
    return tmp, summary


def test_smoke_runs_and_snellcaster_beats_t2i(smoke):
    tmp, summary = smoke
    assert summary["ok"] == 4 and summary["failed"] == 0 and summary["exit_status"] == 0, summary
    m = metrics_of(tmp / "runs" / "smoke")
    for scene in ("living_room-0", "kitchen-0"):
        snell, t2i = m[f"{scene}/sphere/snellcaster"], m[f"{scene}/sphere/t2i"]
        assert snell["status"] == t2i["status"] == "ok"
        assert snell["metrics"]["psnr"] > t2i["metrics"]["psnr"], (scene, snell["metrics"], t2i["metrics"])
        assert snell["model"] == "analytic" and snell["scene_source"] == "procedural"


def test_cells_hold_everything_to_rescore(smoke):
    tmp, _ = smoke
    cell = tmp / "runs" / "smoke" / "living_room-0" / "sphere" / "snellcaster"
    for name in (
        "image.png",
        "reference.png",
        "mask.png",
        "metrics.json",
        "config.yaml",
        "I_minus.png",
        "depth.npy",
        "camera.json",
        "object.ply",
    ):
        assert (cell / name).is_file(), name
    from omegaconf import OmegaConf

    resolved = OmegaConf.load(cell / "config.yaml")  # fully resolved: no interpolation left
    assert resolved.scene.name == "living_room" and resolved.method.name == "snellcaster"
    assert resolved.output_dir == str(cell) and "${" not in (cell / "config.yaml").read_text()
    cam = json.loads((cell / "camera.json").read_text())
    assert cam["width"] == 160 and cam["height"] == 96 and cam["ior"] == 1.5 and len(cam["K"]) == 3
    assert np.load(cell / "depth.npy").shape == (96, 160)
    import trimesh

    assert trimesh.load(cell / "object.ply").is_watertight


def test_missing_weights_are_reported_not_faked(smoke):
    tmp, _ = smoke
    rec = json.loads((tmp / "runs" / "smoke" / "kitchen-0" / "sphere" / "t2i" / "metrics.json").read_text())
    assert rec["metrics"]["lpips"] is None and "lpips_weights" in rec["missing"]["lpips"]
    assert rec["metrics"]["clip"] is None and "clip_weights" in rec["missing"]["clip"]
    assert rec["metrics"]["image_reward"] is None and rec["missing"]["image_reward"]


def test_reports_written(smoke):
    tmp, _ = smoke
    out = tmp / "reports" / "smoke"
    for name in ("method_table.md", "method_table.tex", "method_table.csv", "qualitative_1.png"):
        assert (out / name).is_file(), name
    assert "analytic" in (out / "method_table.md").read_text()


def test_rerun_skips_finished_cells_and_recompute_is_deterministic(smoke):
    from snell_bench.experiment.runner import run_grid

    tmp, _ = smoke
    again = run_grid(make_cfg(tmp, ["grid.report=false"]))
    assert again["cached"] == 4 and again["ok"] == 0
    # an interrupted cell has no metrics.json: only it is redone
    root = tmp / "runs" / "smoke"
    before = metrics_of(root)
    (root / "kitchen-0" / "sphere" / "t2i" / "metrics.json").unlink()
    redo = run_grid(make_cfg(tmp, ["grid.report=false"]))
    assert redo["cached"] == 3 and redo["ok"] == 1
    after = metrics_of(root)
    assert after["kitchen-0/sphere/t2i"]["metrics"] == before["kitchen-0/sphere/t2i"]["metrics"]


def test_failures_and_skips_are_recorded_and_the_sweep_goes_on(tmp_path):
    import trimesh

    from snell_bench.experiment.runner import run_grid

    open_mesh = tmp_path / "open_box.ply"  # a box without its lid: fails when the fox cell builds it
    box = trimesh.creation.box()
    box.update_faces(box.face_normals[:, 2] < 0.5)
    box.export(open_mesh)
    cfg = make_cfg(
        tmp_path,
        [
            "grid.scenes=[living_room]",
            "grid.objects=[sphere,fox]",
            f"object.path={open_mesh}",  # kept by the fox cell (value overrides win over object=fox)
            "grid.methods=[t2i,flux2_dev]",
            "reference.enabled=false",
            "reference.true_render=false",
        ],
    )
    summary = run_grid(cfg)
    m = metrics_of(tmp_path / "runs" / "smoke")
    assert m["living_room-0/sphere/t2i"]["status"] == "ok"
    assert m["living_room-0/sphere/flux2_dev"]["status"] == "skipped"
    assert "GPU" in m["living_room-0/sphere/flux2_dev"]["reason"]
    fox = m["living_room-0/fox/t2i"]
    assert fox["status"] == "failed" and "not watertight" in fox["reason"] and "object.repair=true" in fox["reason"]
    assert "object.allow_open=true" in fox["reason"] and str(open_mesh) in fox["reason"]
    assert summary["failed"] == 2 and any("fox" in c for c, _ in summary["failures"])
    assert summary["exit_status"] == 3  # skipped cells do not count; failed ones do (grid.allow_failures)


def test_a_missing_mesh_file_fails_before_any_work_naming_the_cell(tmp_path):
    from snell_bench.experiment.runner import run_grid

    cfg = make_cfg(tmp_path, ["grid.objects=[sphere,fox]", "object.path=/nonexistent/fox.ply"])
    with pytest.raises(ValueError, match=r"object=fox.*object.path='/nonexistent/fox.ply'"):
        run_grid(cfg)
    assert not (tmp_path / "runs").exists()


def test_unknown_names_fail_before_any_work(tmp_path):
    from snell_bench.experiment.runner import run_grid

    with pytest.raises(ValueError, match="unknown method"):
        run_grid(make_cfg(tmp_path, ["grid.methods=[snellcaster,magic]"]))


@pytest.mark.parametrize(
    "override, key",
    [
        ("grid.methods=[t2i,t2i]", "grid.methods"),
        ("grid.scenes=[living_room,living_room]", "grid.scenes"),
        ("grid.variations=[0,0]", "grid.variations"),
        ("grid.objects=[sphere:1.5,sphere:1.5]", "grid.objects"),
    ],
)
def test_repeated_grid_entries_fail_before_any_work(tmp_path, override, key):
    from snell_bench.experiment.runner import run_grid

    with pytest.raises(ValueError, match=rf"{key} lists .* more than once"):
        run_grid(make_cfg(tmp_path, [override]))
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").rglob("metrics.json"))


def test_ior_spec_and_cell_config():
    from omegaconf import OmegaConf

    from snell_bench.config.grid import CellId
    from snell_bench.config.sampler import SamplerSettings
    from snell_bench.experiment.plan import compose_cell, object_dir_name, parse_object_spec

    assert (
        parse_object_spec("sphere:1.333") == ("sphere", 1.333) and object_dir_name("sphere:1.333") == "sphere-ior1.333"
    )
    assert (
        parse_object_spec("sphere:water") == ("sphere", "water")
        and object_dir_name("sphere:water") == "sphere-iorwater"
    )
    cfg = compose(["+experiment=ablation", "sampler.lam=0.3", "output_dir=/tmp/x"])
    c = compose_cell(cfg, CellId("office", 2, "cylinder:1.333", "no_dpa").overrides())
    assert c.scene.name == "office" and c.scene.variation == 2 and c.scene.width == 640  # the preset's size
    assert c.object.factory._target_.endswith("GlassObject.cylinder") and c.object.ior == 1.333
    assert c.sampler.dpa is False and c.sampler.lpw is True and c.method.label == "w/o DPA"
    assert c.sampler.lam == 0.3  # the run's own overrides are kept
    settings = OmegaConf.to_object(c.sampler)  # the structured schema survives composition and the switches
    assert isinstance(settings, SamplerSettings) and settings.dpa is False


def test_a_config_changed_after_composition_is_refused(tmp_path):
    """Cells are composed from the run's overrides: a change made to the object afterwards would be
    lost, so the grid refuses it and names the key."""
    from snell_bench.experiment.runner import run_grid

    cfg = make_cfg(tmp_path, [])
    cfg.scene.width = 320
    with pytest.raises(ValueError, match="scene.width"):
        run_grid(cfg)
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
@pytest.mark.parametrize("launcher", ["submitit_local", "local_processes"])
def test_parallel_launchers(tmp_path, launcher):
    """Two scene subsets in two processes through Hydra's submitit_local (the Slurm launcher's local
    twin) and joblib launchers: each process writes its own, disjoint cells."""
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
        f"runs_dir={tmp_path / 'runs'}",
        "grid.scenes=[living_room],[kitchen]",
        f"hydra/launcher={launcher}",
        f"hydra.sweep.dir={tmp_path / 'multirun'}",
    ]
    subprocess.run(cmd, cwd=REPO, check=True, timeout=600, env={**os.environ, "HF_HUB_OFFLINE": "1"})
    m = metrics_of(tmp_path / "runs" / "smoke")
    assert sorted(m) == ["kitchen-0/sphere/t2i", "living_room-0/sphere/t2i"]
    assert all(r["status"] == "ok" for r in m.values())


def test_adaptive_methods_log_decisions_and_savings(tmp_path):
    """full_frame gives Snellcaster's image; adaptive records what it modelled, with its own warps;
    the savings report pairs both with Snellcaster."""
    import pandas as pd
    from omegaconf import OmegaConf

    from snell_bench.experiment.runner import run_grid

    cfg = make_cfg(
        tmp_path,
        ["grid.scenes=[living_room]", "grid.objects=[sphere:1.05]", "grid.methods=[snellcaster,full_frame,adaptive]"],
    )
    run_grid(cfg)
    cells = metrics_of(tmp_path / "runs" / "smoke")
    snell = cells["living_room-0/sphere-ior1.05/snellcaster"]
    full = cells["living_room-0/sphere-ior1.05/full_frame"]
    adap = cells["living_room-0/sphere-ior1.05/adaptive"]
    assert all(c["status"] == "ok" for c in (snell, full, adap))
    assert abs(full["metrics"]["psnr"] - snell["metrics"]["psnr"]) < 1e-3
    assert snell["decisions"]["roi"] is True and full["decisions"]["roi"] is False
    assert snell["warps"]["traced_primary_rays"] < full["warps"]["traced_primary_rays"]
    # IOR 1.05: Fresnel below 1 % except near the rim, so most pixels drop their reflection
    assert adap["decisions"]["reflection"]["share_kept"] < 0.5
    assert adap["decisions"]["panorama"]["observed_share"] > 0.5
    assert adap["warps"]["far_background"]["far_fraction"] == 0.0  # a room has no far background
    a_cfg = OmegaConf.load(tmp_path / "runs/smoke/living_room-0/sphere-ior1.05/adaptive/config.yaml")
    s_cfg = OmegaConf.load(tmp_path / "runs/smoke/living_room-0/sphere-ior1.05/snellcaster/config.yaml")
    assert a_cfg.warps.infinity_tolerance_px == 1.0 and s_cfg.warps.infinity_tolerance_px is None
    savings = pd.read_csv(tmp_path / "reports/smoke/savings.csv")
    assert list(savings["method"]) == ["Snellcaster (full frame)", "Snellcaster (adaptive)"]
    per_cell = pd.read_csv(tmp_path / "reports/smoke/savings_per_cell.csv")
    assert len(per_cell) == 2
    row = per_cell[per_cell["method"] == "adaptive"].iloc[0]
    assert row["delta_psnr"] == pytest.approx(adap["metrics"]["psnr"] - snell["metrics"]["psnr"])
    assert "savings.md" in (tmp_path / "reports/smoke/README.md").read_text()


def test_resume_with_changed_settings_stops_naming_the_keys(tmp_path):
    from snell_bench.experiment.cells import SettingsChanged
    from snell_bench.experiment.runner import run_grid

    one = ["grid.scenes=[living_room]", "grid.methods=[t2i]", "reference.enabled=false", "grid.report=false"]
    first = run_grid(make_cfg(tmp_path, [*one, "sampler.steps=4"]))
    assert first["ok"] == 1
    record = metrics_of(tmp_path / "runs" / "smoke")["living_room-0/sphere/t2i"]
    for change, key in (("sampler.steps=6", "sampler.steps: 4 -> 6"), ("scene.width=168", "scene.width: 160 -> 168")):
        with pytest.raises(SettingsChanged, match="grid.on_change=recompute") as e:
            run_grid(make_cfg(tmp_path, [*one, "sampler.steps=4", change]))
        assert key in str(e.value)
    # output paths, the grid's lists and progress bars are not settings of a cell
    again = run_grid(make_cfg(tmp_path, [*one, "sampler.steps=4", "sampler.progress=false", "grid.methods=[t2i]"]))
    assert again["cached"] == 1 and again["ok"] == 0
    redo = run_grid(make_cfg(tmp_path, [*one, "sampler.steps=6", "grid.on_change=recompute"]))
    assert redo["ok"] == 1
    after = metrics_of(tmp_path / "runs" / "smoke")["living_room-0/sphere/t2i"]
    assert after["settings_hash"] != record["settings_hash"]
    assert run_grid(make_cfg(tmp_path, [*one, "sampler.steps=6"]))["cached"] == 1


def test_a_deleted_image_makes_its_cell_unfinished(tmp_path):
    from snell_bench.experiment.runner import run_grid

    one = ["grid.scenes=[living_room]", "grid.methods=[t2i]", "reference.enabled=false", "grid.report=false"]
    run_grid(make_cfg(tmp_path, one))
    cell = tmp_path / "runs" / "smoke" / "living_room-0" / "sphere" / "t2i"
    files = json.loads((cell / "metrics.json").read_text())["files"]
    assert {"image.png", "config.yaml", "I_minus.png", "depth.npy", "camera.json", "object.ply"} <= set(files)
    (cell / "image.png").unlink()
    assert run_grid(make_cfg(tmp_path, one))["ok"] == 1 and (cell / "image.png").is_file()


def test_a_report_never_averages_cells_of_different_settings(tmp_path):
    from snell_bench.experiment.runner import check_same_settings, run_grid

    base = ["grid.methods=[t2i]", "reference.enabled=false", "sampler.steps=4"]
    run_grid(make_cfg(tmp_path, [*base, "grid.scenes=[living_room]"]))  # a report of one cell
    root = tmp_path / "runs" / "smoke"
    check_same_settings(root)
    # another part of the grid, the way parallel sweeps split it: the same settings, one report
    run_grid(make_cfg(tmp_path, [*base, "grid.scenes=[kitchen]"]))
    check_same_settings(root)
    # a part computed with other settings: the report refuses to average them
    run_grid(
        make_cfg(
            tmp_path, [*base, "grid.scenes=[kitchen]", "grid.variations=[1]", "sampler.steps=6", "grid.report=false"]
        )
    )
    with pytest.raises(ValueError, match=r"sampler.steps: 4 in 2 cells .*; 6 in 1 cell \(kitchen-1/sphere/t2i\)"):
        check_same_settings(root)
    with pytest.raises(ValueError, match="different settings"):
        run_grid(make_cfg(tmp_path, [*base, "grid.scenes=[kitchen]"]))


@pytest.mark.parametrize(
    "identity",
    [
        ("living_room", 0, "sphere", "snellcaster"),
        ("kitchen", 2, "sphere:1.333", "no_dpa"),
        ("cafe", 1, "fox", "no_lpw"),
    ],
)
def test_identity_defaults_equal_composing_the_cell(identity):
    from snell_bench.config.grid import CellId
    from snell_bench.experiment.plan import result_settings
    from snell_bench.experiment.runner import identity_defaults
    from snell_bench.pipeline import apply_method

    assert identity_defaults()(*identity) == result_settings(apply_method(compose(CellId(*identity).overrides())))
