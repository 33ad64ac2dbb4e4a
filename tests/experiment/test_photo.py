"""A user's photo or RGB-D frame as the scene: the bundled real frame, bad inputs, the experiment."""

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from snell_bench import pipeline
from snell_bench.config import ConfigError, compose

REPO = Path(__file__).resolve().parents[2]
FRAME = REPO / "snell_bench" / "datasets" / "rgbd" / "tum_fr3_office"
CHEAP = ["warps.pano_height=64", "warps.cache_dir=null", "sampler.steps=4", "reference.spp=2"]


@pytest.fixture(scope="module")
def desk():
    cfg = compose(["scene=tum_office", *CHEAP, "output_dir=/tmp/x"])
    return cfg, pipeline.prepare_inputs(cfg, references=False)


def test_the_real_frame_loads_at_its_native_size_with_its_holes(desk):
    cfg, inputs = desk
    sc = inputs.scene
    assert sc.image.shape == (480, 640, 3) and sc.depth.shape == (480, 640)  # 640 x 480: a multiple of 16
    raw = np.asarray(Image.open(FRAME / "depth.png"), np.float64)
    np.testing.assert_allclose(sc.depth[raw > 0], raw[raw > 0] / 5000.0, rtol=1e-6)
    assert np.isnan(sc.depth[raw == 0]).all() and 0.15 < np.isnan(sc.depth).mean() < 0.25
    np.testing.assert_allclose(sc.camera.K[[0, 1, 0, 1], [0, 1, 2, 2]], [525.0, 525.0, 319.5, 239.5])


def test_the_sphere_stands_on_the_desk_top(desk):
    """Its lowest point lies within 1 cm of the plane fitted to the desk (independently, RANSAC with
    another seed), which is about 0.7 m above the floor."""
    from snell_bench.scene.placement import find_support_plane

    cfg, inputs = desk
    obj, sc = inputs.obj, inputs.scene
    up = obj.up / np.linalg.norm(obj.up)
    desk = find_support_plane(sc.depth, sc.camera, up_hint=np.asarray(cfg.scene.up), seed=3)
    lowest = float((obj.vertices @ up).min() - desk.point @ up)
    assert abs(lowest) < 0.01, lowest
    assert np.degrees(np.arccos(min(1.0, abs(float(up @ desk.normal))))) < 2.0  # upright on it
    floor = find_support_plane(sc.depth, sc.camera, up_hint=np.asarray(cfg.scene.up), prefer="largest", seed=0)
    assert 0.6 < float((desk.point - floor.point) @ floor.normal) < 0.8  # the desk, not the floor
    assert inputs.warps.object_mask.sum() > 1000


def test_the_panorama_prior_comes_from_the_photo_alone(desk):
    """For a photo the analytic stand-in's panorama is I⁻ seen through π, smoothly filled: where π
    sees I⁻ it equals the remapped photo."""
    import torch

    from snell_bench.imaging.remap import remap

    cfg, inputs = desk
    from snell_bench.scene.sources import panorama_prior

    pano = panorama_prior(inputs.scene, inputs.warps, inputs.i_minus)
    ws = inputs.warps
    assert pano.shape == (64, 128, 3) and np.isfinite(pano).all()
    seen, _ = remap(inputs.i_minus, ws.pano_to_persp)
    known = ws.pano_to_persp_valid & np.isfinite(ws.pano_to_persp).all(-1)
    np.testing.assert_allclose(pano[known], seen[0].permute(1, 2, 0).numpy()[known].clip(0, 1), atol=1e-6)
    assert 0.05 < known.mean() < 0.95 and not torch.isnan(torch.from_numpy(pano)).any()


def _frame_files(tmp_path, depth):
    Image.open(FRAME / "color.png").save(tmp_path / "color.png")
    Image.fromarray(depth.astype(np.uint16)).save(tmp_path / "depth.png")
    return [f"scene.image={tmp_path / 'color.png'}", f"scene.depth={tmp_path / 'depth.png'}"]


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda t: ["scene.image=/nonexistent/photo.jpg"], "scene.image"),
        (lambda t: ["scene.depth=/nonexistent/depth.png"], "scene.depth"),
        (lambda t: ["scene.depth_scale=0"], "scene.depth_scale"),
        (lambda t: ["scene.depth_scale=-5000"], "scene.depth_scale"),
        (lambda t: _frame_files(t, np.full((240, 320), 10000)), "scene.depth"),  # another size than the image
        (lambda t: _frame_files(t, np.zeros((480, 640))), "scene.depth"),  # no valid pixel
        (lambda t: _frame_files(t, np.pad(np.full((480, 100), 10000), ((0, 0), (0, 540)))), "scene.depth"),
        (lambda t: ["scene.intrinsics=[525.0,525.0,319.5]"], "scene.intrinsics"),
    ],
)
def test_bad_inputs_name_the_key(tmp_path, make, match):
    """Each one is an error naming the key (the last depth has no valid pixel on any surface near the
    image centre)."""
    cfg = compose(["scene=tum_office", *CHEAP, *make(tmp_path), "output_dir=/tmp/x"])
    with pytest.raises((ValueError, FileNotFoundError), match=match):
        pipeline.prepare_inputs(cfg, references=False)


def _frame_cfg(tmp_path, depth):
    return compose(
        [
            "+experiment=smoke",
            "scene.width=160",
            "scene.height=96",
            *CHEAP,
            "reference.enabled=false",
            "reference.true_render=false",
            "grid.scenes=[living_room,tum_office]",
            "grid.methods=[t2i]",
            f"scene.depth={depth}",
            "grid.report=false",
            f"runs_dir={tmp_path / 'runs'}",
            f"output_dir={tmp_path}",
        ]
    )


def test_a_bad_frame_fails_its_cell_and_the_others_finish(tmp_path):
    from snell_bench.experiment.runner import run_grid

    damaged = tmp_path / "depth.png"
    damaged.write_bytes(b"\x89PNG\r\n\x1a\n not a png any more")  # there, but unreadable: fails when read
    summary = run_grid(_frame_cfg(tmp_path, damaged))
    assert summary["ok"] == 1 and summary["failed"] == 1
    bad = json.loads((tmp_path / "runs/smoke/tum_office-0/sphere/t2i/metrics.json").read_text())
    assert bad["status"] == "failed" and str(damaged) in bad["reason"], bad["reason"]


def test_a_missing_frame_fails_before_any_work(tmp_path):
    from snell_bench.experiment.runner import run_grid

    with pytest.raises(
        ValueError, match=r"scene=tum_office .*scene.depth='/nonexistent/depth.png': no such depth file"
    ):
        run_grid(_frame_cfg(tmp_path, "/nonexistent/depth.png"))
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
def test_photo_experiment_end_to_end(tmp_path):
    """+experiment=photo at reduced cost: both cells ok, Snellcaster above the text-to-image baseline
    inside the mask, a report."""
    from snell_bench.experiment.runner import run_grid

    cfg = compose(
        [
            "+experiment=photo",
            *CHEAP,
            f"runs_dir={tmp_path / 'runs'}",
            f"reports_dir={tmp_path / 'reports'}",
            f"output_dir={tmp_path}",
        ]
    )
    summary = run_grid(cfg)
    assert summary["ok"] == 2 and summary["failed"] == 0, summary
    m = {
        x: json.loads((tmp_path / f"runs/photo/tum_office-0/sphere/{x}/metrics.json").read_text())
        for x in ("snellcaster", "t2i")
    }
    assert m["snellcaster"]["metrics"]["psnr"] > m["t2i"]["metrics"]["psnr"] + 3
    assert m["snellcaster"]["scene_source"] == "image" and "psnr_true" not in m["snellcaster"]["metrics"]
    assert (tmp_path / "reports/photo/method_table.md").is_file()


def test_a_prompt_without_an_object_phrase_fails_before_any_work_naming_the_key(tmp_path):
    from snell_bench.experiment.runner import run_grid

    cfg = compose(
        [
            "+experiment=smoke",
            "scene.width=160",
            "scene.height=96",
            *CHEAP,
            "reference.enabled=false",
            "reference.true_render=false",
            "grid.scenes=[living_room]",
            "grid.methods=[t2i,snellcaster]",
            "scene.text='A bare room with a table.'",
            "grid.report=false",
            f"runs_dir={tmp_path}",
            f"output_dir={tmp_path}",
        ]
    )
    with pytest.raises(ConfigError) as e:
        run_grid(cfg)
    assert "scene.text" in str(e.value) and "[[" in str(e.value)
    assert not (tmp_path / "smoke").exists()  # nothing was run


def test_a_photo_without_depth_gets_it_from_the_depth_estimator(monkeypatch):
    """scene.depth unset: the depth estimator gives metric depth; the configured intrinsics win over
    the estimator's (random weights: the supporting plane is fixed here)."""
    from snell_bench.scene import placement

    plane = placement.SupportPlane(
        point=np.array([0.0, 0.4, 2.0]), normal=np.array([0.0, -1.0, 0.0]), inliers=1, pixel=np.array([320.0, 300.0])
    )
    monkeypatch.setattr(placement, "find_support_plane", lambda *a, **k: plane)
    cfg = compose(["scene=tum_office", "scene.depth=null", "depth=tiny_depth_pro", *CHEAP, "output_dir=/tmp/x"])
    inputs = pipeline.prepare_inputs(cfg, references=False)
    d = inputs.scene.depth
    assert d.shape == (480, 640) and np.isfinite(d).mean() > 0.99 and np.nanmin(d) > 0
    np.testing.assert_allclose(inputs.scene.camera.K[[0, 1, 0, 1], [0, 1, 2, 2]], [525.0, 525.0, 319.5, 239.5])
    no_k = compose(
        [
            "scene=tum_office",
            "scene.depth=null",
            "scene.intrinsics=null",
            "depth=tiny_depth_pro",
            *CHEAP,
            "output_dir=/tmp/x",
        ]
    )
    cam = pipeline.load_scene(no_k).camera  # the estimator's own focal length and centred principal point
    assert cam.K[0, 0] == cam.K[1, 1] and cam.K[0, 2] == pytest.approx(319.5)
    with pytest.raises(ValueError, match="depth estimator"):
        pipeline.load_scene(compose(["scene=tum_office", "scene.depth=null", "output_dir=/tmp/x"]))


@pytest.mark.parametrize("obj", ["sphere", "cylinder", "pyramid", "fox", "dog", "sculpture"])
def test_the_papers_six_objects_stand_upright_on_the_desk(obj):
    """Each at its configured size (a quarter of its distance), its lowest point on the desk plane
    (within 1 cm), its up axis the plane's normal."""
    from snell_bench.scene.placement import find_support_plane

    cfg = compose(["scene=tum_office", f"object={obj}", *CHEAP, "output_dir=/tmp/x"])
    sc = pipeline.load_scene(cfg)
    placed = pipeline.place(pipeline.build_object(cfg.object), sc, cfg.object, seed=0)
    desk = find_support_plane(sc.depth, sc.camera, up_hint=np.asarray(cfg.scene.up), seed=0)
    up = placed.up / np.linalg.norm(placed.up)
    assert abs(float((placed.vertices @ up).min() - desk.point @ up)) < 0.01
    assert abs(float(up @ desk.normal)) > np.cos(np.radians(0.5))
    extent = np.ptp(placed.vertices, axis=0).max()
    assert 0.9 * 0.25 * np.linalg.norm(desk.point) < extent < 1.8 * 0.25 * np.linalg.norm(desk.point)


def test_preview_of_a_photo(tmp_path):
    """job=preview on the real frame: the panorama is I⁻ through π, filled (a photo has no other)."""
    from snell_bench.experiment.preview import run_preview

    summary = run_preview(compose(["scene=tum_office", *CHEAP, f"output_dir={tmp_path}"]))
    pano = np.asarray(Image.open(tmp_path / "panorama.png"))
    assert pano.shape == (64, 128, 3) and summary["warps"]["object_pixels"] > 1000
    assert summary["scene"]["prompt"].startswith("An office")  # resolved, not the ${prompts:...} interpolation
