"""The benchmark kit end to end: export it, load it with datasets and pandas, score the grid's own
Snellcaster images through method=images and through score_image to the last bit, and refuse bad
submissions by name."""

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from snell_bench.config import ConfigError, compose
from snell_bench.kit import load_kit, score_image

TINY = [
    "scene.width=160",
    "scene.height=96",
    "warps.pano_height=64",
    "warps.cache_dir=null",
    "sampler.steps=8",
    "reference.spp=4",
    "reference.true_spp=1",
]
GROUPS = ("living_room-0/sphere", "kitchen-0/sphere")


def make_cfg(tmp: Path, *overrides):
    return compose(
        [
            "+experiment=smoke",
            *TINY,
            f"runs_dir={tmp / 'runs'}",
            f"reports_dir={tmp / 'reports'}",
            f"export.dir={tmp / 'kits'}",
            f"output_dir={tmp}",
            *overrides,
        ]
    )


def records(root: Path, method: str) -> dict:
    return {g: json.loads((root / g / method / "metrics.json").read_text()) for g in GROUPS}


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """The smoke grid, its kit (with warps), and the grid again with its own Snellcaster images
    submitted as method=images."""
    from snell_bench.experiment.export import run_export
    from snell_bench.experiment.runner import run_grid

    tmp = tmp_path_factory.mktemp("bench")
    run_grid(make_cfg(tmp, "grid.report=false"))
    export = run_export(make_cfg(tmp, "job=export", "export.warps=true"))
    mine = tmp / "mine"
    for g in GROUPS:
        (mine / g).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(tmp / "runs" / "smoke" / g / "snellcaster" / "image.png", mine / f"{g}.png")
    again = run_grid(make_cfg(tmp, "grid.methods=[snellcaster,t2i,images]", f"method.images={mine}"))
    return tmp, export, again


def test_the_kit_holds_every_group_and_file(bench):
    tmp, export, _ = bench
    kit = tmp / "kits" / "smoke"
    assert export["exit_status"] == 0 and export["groups"] == 2
    for name in ("README.md", "kit.json", "manifest.parquet", "manifest.jsonl"):
        assert (kit / name).is_file(), name
    rows = load_kit(kit).rows
    assert [r["id"] for r in rows] == list(GROUPS)
    for r in rows:
        for field, digest in r["checksums"].items():
            if r[field] is None:
                assert digest is None, field
            else:  # every file is there, with the SHA-256 the row says
                assert hashlib.sha256((kit / r[field]).read_bytes()).hexdigest() == digest, field


def test_the_kit_loads_with_datasets_and_with_pandas(bench, tmp_path):
    import datasets
    import pandas as pd

    kit = bench[0] / "kits" / "smoke"
    ds = datasets.load_dataset(
        "parquet", data_files=str(kit / "manifest.parquet"), split="train", cache_dir=str(tmp_path)
    )
    df = pd.read_parquet(kit / "manifest.parquet")
    jsonl = pd.read_json(kit / "manifest.jsonl", lines=True)
    assert ds.num_rows == len(df) == len(jsonl) == 2
    assert ds["id"] == df["id"].tolist() == list(GROUPS)
    assert df["reference_spp"].dtype == np.int64 and df["width"].tolist() == [160, 160]
    assert ds.features["object_pose"].feature.dtype == "float64"  # a list of floats, typed
    by_card = datasets.load_dataset(str(kit), cache_dir=str(tmp_path))  # the card's configs
    assert by_card["test"]["id"] == list(GROUPS)


def test_the_rows_describe_the_groups(bench):
    import trimesh

    kit = load_kit(bench[0] / "kits" / "smoke")
    for r in kit.rows:
        placed = trimesh.load(kit.path(r, "object_mesh"), process=False)
        canonical = trimesh.load(kit.path(r, "object_canonical"), process=False)
        pose = np.asarray(r["object_pose"]).reshape(4, 4)
        moved = canonical.vertices @ pose[:3, :3].T + pose[:3, 3]
        # PLY stores float32: each file rounds a coordinate by at most half an ulp, 2**-24 |v|
        bound = 2 * 2.0**-24 * np.abs(placed.vertices).max() * 1.01
        assert np.abs(moved - placed.vertices).max() <= bound
        assert "glass sphere" in r["prompt"] and "glass sphere" not in r["prompt_minus"]
        assert r["licence_object"].startswith("MIT") and r["licence_scene"].startswith("MIT")
        K = json.loads(kit.path(r, "camera").read_text())["K"]
        assert [r["fx"], r["fy"], r["cx"], r["cy"]] == [K[0][0], K[1][1], K[0][2], K[1][2]]
        mask, obj = kit.array(r, "metric_mask"), kit.array(r, "object_mask")
        unobserved = kit.array(r, "unobserved_mask")
        assert mask.any() and not (mask & unobserved).any() and (mask | unobserved).sum() <= obj.sum() + 50


def test_the_warps_in_the_kit_load(bench):
    from snell_bench.optics.warpset import WarpSet

    kit = load_kit(bench[0] / "kits" / "smoke")
    r = kit.rows[0]
    ws = WarpSet.load(kit.path(r, "warps"))
    assert np.array_equal(ws.object_mask, kit.array(r, "object_mask"))
    assert ws.refraction.shape == (96, 160, 2)


def test_the_grids_own_images_score_to_the_last_bit(bench):
    tmp, _, again = bench
    assert again["ok"] == 2 and again["cached"] == 4  # the first grid's cells stayed done
    root = tmp / "runs" / "smoke"
    own, submitted = records(root, "snellcaster"), records(root, "images")
    for g in GROUPS:
        assert submitted[g]["metrics"] == own[g]["metrics"], g
        assert submitted[g]["missing"] == own[g]["missing"], g
        assert submitted[g]["method_label"] == "Images: mine" and submitted[g]["method_kind"] == "images"
        assert submitted[g]["images"]["file"] == f"{g}.png"


def test_score_image_is_the_grids_record(bench):
    tmp = bench[0]
    kit = load_kit(tmp / "kits" / "smoke")
    own = records(tmp / "runs" / "smoke", "snellcaster")
    for g in GROUPS:
        image = tmp / "runs" / "smoke" / g / "snellcaster" / "image.png"
        scored = score_image(image, kit.row(g), kit)
        assert scored["metrics"] == own[g]["metrics"] and scored["missing"] == own[g]["missing"], g
        from PIL import Image

        as_array = score_image(np.asarray(Image.open(image)), kit.row(g), kit)
        assert as_array["metrics"] == own[g]["metrics"]


def test_the_report_has_a_row_for_the_images(bench):
    md = (bench[0] / "reports" / "smoke" / "method_table.md").read_text()
    rows = [line.split("|")[1].strip() for line in md.splitlines() if line.startswith("| ")]
    assert "Images: mine" in rows and "Snellcaster" in rows
    html = (bench[0] / "reports" / "smoke" / "index.html").read_text()
    assert "Images: mine" in html


def test_an_export_again_keeps_what_it_has(bench):
    from snell_bench.experiment.export import run_export

    tmp = bench[0]
    again = run_export(make_cfg(tmp, "job=export", "export.warps=true"))
    assert again["cached"] == 2 and again["ok"] == 0 and again["groups"] == 2


def test_plan_and_status_count_the_images(bench, capsys):
    from snell_bench.experiment.estimate import make_plan

    tmp = bench[0]
    plan = make_plan(make_cfg(tmp, "grid.methods=[snellcaster,t2i,images]", f"method.images={tmp / 'mine'}"))
    images = [c for c in plan.cells if c.method == "images"]
    assert [c.state for c in images] == ["done", "done"]
    t = next(t for t in plan.times if t.method == "images")
    assert t.kind == "images" and t.basis == "CPU"


def test_a_changed_image_makes_its_cell_unfinished(bench):
    from snell_bench.experiment.runner import run_grid

    tmp = bench[0]
    sub = tmp / "changed"
    shutil.copytree(tmp / "mine", sub)
    cfg = make_cfg(tmp, "experiment_name=changed", "grid.methods=[images]", f"method.images={sub}", "grid.report=false")
    first = run_grid(cfg)
    assert first["ok"] == 2
    from PIL import Image

    path = sub / "kitchen-0" / "sphere.png"
    px = np.asarray(Image.open(path)).copy()
    px[0, 0] = 255 - px[0, 0]
    Image.fromarray(px).save(path)
    (sub / "living_room-0" / "sphere.png").unlink()
    second = run_grid(cfg)
    assert second["ok"] == 1 and second["skipped"] == 1 and second["cached"] == 0
    rec = json.loads((tmp / "runs" / "changed" / "living_room-0" / "sphere" / "images" / "metrics.json").read_text())
    assert rec["status"] == "skipped" and "no image for living_room-0/sphere" in rec["reason"]
    assert run_grid(cfg)["cached"] == 2  # now current


def test_bad_submissions_are_refused_by_name(bench):
    from snell_bench.experiment.runner import run_grid

    tmp = bench[0]
    sub = tmp / "bad"
    (sub / "living_room-0").mkdir(parents=True)
    from PIL import Image

    Image.new("RGB", (161, 96)).save(sub / "living_room-0" / "sphere.png")  # kitchen-0 has none
    cfg = make_cfg(tmp, "experiment_name=bad", "grid.methods=[images]", f"method.images={sub}", "grid.report=false")
    summary = run_grid(cfg)
    assert summary["failed"] == 1 and summary["skipped"] == 1 and summary["exit_status"] == 3
    ((_, reason),) = summary["failures"]
    assert "sphere.png is 161 x 96 pixels; the group's camera is 160 x 96" in reason
    table = tmp / "outside.csv"
    table.write_text("id,image\nkitchen-0/sphere,../mine/kitchen-0/sphere.png\n")
    with pytest.raises(ConfigError, match=r"leads outside the folder"):
        run_grid(make_cfg(tmp, "experiment_name=outside", "grid.methods=[images]", f"method.images={table}"))


def test_images_made_from_another_kit_are_refused(bench):
    from snell_bench.experiment.runner import run_grid

    tmp = bench[0]
    cfg = make_cfg(
        tmp,
        "experiment_name=otherkit",
        "grid.methods=[images]",
        f"method.images={tmp / 'mine'}",
        f"method.kit={tmp / 'kits' / 'smoke'}",
        "object.size=0.3",  # another size of the object than the kit's
        "grid.report=false",
    )
    summary = run_grid(cfg)
    assert summary["failed"] == 2
    assert all("its object is another shape, size or placement" in reason for _, reason in summary["failures"])
