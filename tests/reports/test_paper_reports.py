"""The paper's Tables 1-4, the IOR and time-travel reports and the paged figures, from hand-made
cells with known means; the panorama of a Snellcaster cell from a tiny grid run; the experiment
configs."""

import hashlib
import json
import math

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from snell_bench.reports import (
    ABLATION_ROWS,
    TIME_TRAVEL_ROWS,
    block_table,
    build_reports,
    collect,
    figure_rows,
    method_table,
    object_ior,
    pages,
    panorama_pages,
    provenance_line,
    qualitative_pages,
    recipe_and_protocol,
    scene_table,
    time_travel_table,
    with_recorded_metrics,
)
from tests.reports.test_reports import has_row, md_rows

W, H = 32, 24
LPIPS_REASON = "no VGG weights: set metrics.lpips_weights"
CLIP_REASON = "no CLIP weights: set metrics.clip_weights"

# Hand-made scores, per (scene, method): the value of each of the two variations. LPIPS is missing
# in every cell; lpips_box only in the authors' protocol cells (every cell here).
SCORES = {
    ("kitchen", "snellcaster"): dict(
        psnr=(20.0, 22.0), mae=(0.10, 0.14), clip=(30.0, 32.0), ir=(0.2, 0.4), box=(0.3, 0.5)
    ),
    ("kitchen", "t2i"): dict(psnr=(12.0, 13.0), mae=(0.30, 0.20), clip=(31.0, 29.0), ir=(0.1, 0.3), box=(0.6, 0.8)),
    ("kitchen", "no_tt"): dict(psnr=(18.0, 19.0), mae=(0.12, 0.16), clip=(28.0, 30.0), ir=(0.0, 0.2), box=(0.4, 0.4)),
    ("office", "snellcaster"): dict(
        psnr=(24.0, 26.0), mae=(0.06, 0.08), clip=(27.0, 27.5), ir=(0.5, 0.7), box=(0.2, 0.3)
    ),
    ("office", "t2i"): dict(psnr=(10.0, 11.0), mae=(0.40, 0.42), clip=(26.0, 28.0), ir=(-0.1, 0.1), box=(0.9, 0.7)),
    ("office", "no_tt"): dict(psnr=(23.0, 21.0), mae=(0.09, 0.07), clip=(27.0, 26.0), ir=(0.4, 0.4), box=(0.3, 0.3)),
}
LABELS = {"snellcaster": "Snellcaster", "t2i": "Text-to-image", "no_tt": "w/o time travel"}


def _png(path, rgb):
    Image.fromarray(np.asarray(rgb, np.uint8)).save(path)


def _cell(root, scene, variation, obj, method, metrics, missing, *, label=None, status="ok", config=None, extra=None):
    d = root / f"{scene}-{variation}" / obj / method
    d.mkdir(parents=True)
    rec = {
        "experiment": "paper",
        "scene": scene,
        "variation": variation,
        "object": obj,
        "method": method,
        "method_label": label or LABELS.get(method, method),
        "status": status,
        "reason": None if status == "ok" else "CUDA out of memory",
        "model": "flux",
        "scene_source": "procedural",
        "metrics": metrics,
        "missing": missing,
        "timings_s": {"warps": 1.0, "sampling": 10.0},
        **(extra or {}),
    }
    (d / "metrics.json").write_text(json.dumps(rec))
    (d / "config.yaml").write_text(config if config is not None else f"method:\n  name: {method}\n")
    rng = np.random.default_rng(abs(hash((scene, variation, obj, method))) % 2**32)
    if status == "ok":
        for name in ("image.png", "reference.png"):
            _png(d / name, rng.integers(0, 255, (H, W, 3)))
        mask = np.zeros((H, W, 3), np.uint8)
        mask[8:16, 10:20] = 255
        _png(d / "mask.png", mask)
    return d


AUTHORS_CONFIG = "recipe: authors\nmetrics:\n  protocol: authors\n"


def make_paper_runs(root):
    """Two scenes x two variations x three methods, the scores of ``SCORES``."""
    for (scene, method), s in SCORES.items():
        for v in (0, 1):
            metrics = dict(
                psnr=s["psnr"][v],
                mae=s["mae"][v],
                lpips=None,
                lpips_box=s["box"][v],
                clip=s["clip"][v],
                image_reward=s["ir"][v],
                psnr_true=None,
            )
            _cell(root, scene, v, "sphere", method, metrics, {"lpips": LPIPS_REASON}, config=AUTHORS_CONFIG)
    return root


@pytest.fixture
def paper_runs(tmp_path):
    return make_paper_runs(tmp_path / "runs" / "paper")


def mean(*values):
    return sum(values) / len(values)


def test_table1_has_every_column_and_the_hand_computed_means(paper_runs):
    df = collect(paper_runs)
    cols = with_recorded_metrics(df, ("clip", "image_reward", "psnr", "lpips"))
    assert cols == ("clip", "image_reward", "psnr", "lpips", "lpips_box", "mae")  # psnr_true is null everywhere
    t = method_table(df, cols)
    snell = t.loc["Snellcaster"]
    assert snell["psnr"] == pytest.approx(mean(20, 22, 24, 26))
    assert snell["clip"] == pytest.approx(mean(30, 32, 27, 27.5))
    assert snell["image_reward"] == pytest.approx(mean(0.2, 0.4, 0.5, 0.7))
    assert snell["lpips_box"] == pytest.approx(mean(0.3, 0.5, 0.2, 0.3))
    assert snell["mae"] == pytest.approx(mean(0.10, 0.14, 0.06, 0.08))
    assert t.loc["Text-to-image", "psnr"] == pytest.approx(mean(12, 13, 10, 11))
    assert t["lpips"].isna().all() and list(t["n"]) == [4, 4, 4]


def test_reports_hold_tables_1_to_4_with_every_metric_and_footnotes(paper_runs, tmp_path):
    out = tmp_path / "reports"
    build_reports(paper_runs, out, "paper")
    md1 = (out / "method_table.md").read_text()
    assert has_row(md1, "| Method | CLIP ↑ | ImageReward ↑ | PSNR ↑ | LPIPS ↓ | LPIPS (box) ↓ | MAE ↓ | n |")
    # LPIPS missing in every cell: a column of dashes, the reason in a footnote
    assert has_row(md1, "| Snellcaster | **29.12** | **0.450** | **23.00** | — | **0.325** | **0.0950** | 4 |")
    assert has_row(md1, "| Text-to-image | _28.50_ | 0.100 | 11.50 | — | 0.750 | 0.3300 | 4 |")
    assert f"- LPIPS: no value in any of the 12 ok cells (no_tt ×4, snellcaster ×4, t2i ×4) — {LPIPS_REASON}" in md1
    # recipe and protocol from the cells' config.yaml
    assert "recipe: authors · metrics protocol: authors" in md1
    assert "recipe: authors" in (out / "README.md").read_text()

    # Table 2: the ablation's MAE, PSNR, LPIPS (LPIPS (box) where recorded); Table 4: every metric
    t2 = pd.read_csv(out / "ablation_table.csv", index_col=0)
    assert list(t2.columns) == ["mae", "psnr", "lpips", "lpips_box", "n"]
    t4 = pd.read_csv(out / "ablation_table_all.csv", index_col=0)
    assert list(t4.columns) == ["mae", "psnr", "lpips", "clip", "image_reward", "lpips_box", "n"]
    assert list(t4.index) == ["Full", "w/o time travel"]
    assert t4.loc["w/o time travel", "psnr"] == pytest.approx(mean(18, 19, 23, 21))
    assert t4.loc["w/o time travel", "clip"] == pytest.approx(mean(28, 30, 27, 26))
    assert t4["lpips"].isna().all()
    md4 = (out / "ablation_table_all.md").read_text()
    assert has_row(md4, "| Variant | MAE ↓ | PSNR ↑ | LPIPS ↓ | CLIP ↑ | ImageReward ↑ | LPIPS (box) ↓ | n |")
    assert "LPIPS: no value in any of the 8 ok cells" in md4

    # Table 3: a block per scene, a row per method, every metric
    t3 = pd.read_csv(out / "scene_table.csv", index_col=[0, 1])
    assert list(t3.columns) == ["clip", "image_reward", "psnr", "lpips", "lpips_box", "mae", "n"]
    for (scene, method), s in SCORES.items():
        row = t3.loc[(scene, LABELS[method])]
        assert row["psnr"] == pytest.approx(mean(*s["psnr"])), (scene, method)
        assert row["clip"] == pytest.approx(mean(*s["clip"])), (scene, method)
        assert row["image_reward"] == pytest.approx(mean(*s["ir"])), (scene, method)
        assert row["lpips_box"] == pytest.approx(mean(*s["box"])), (scene, method)
        assert math.isnan(row["lpips"]) and row["n"] == 2
    md3 = (out / "scene_table.md").read_text()
    assert has_row(md3, "| Scene | Method | CLIP ↑ | ImageReward ↑ | PSNR ↑ | LPIPS ↓ | LPIPS (box) ↓ | MAE ↓ | n |")
    # ranked within each scene: in the office Snellcaster is best in every column, CLIP 27.00
    # (text-to-image) second; the scene is named on the first row of its block only
    assert has_row(md3, "| office | w/o time travel | 26.50 | _0.400_ | _22.00_ | — | _0.300_ | _0.0800_ | 2 |")
    assert has_row(md3, "|  | Snellcaster | **27.25** | **0.600** | **25.00** | — | **0.250** | **0.0700** | 2 |")
    assert has_row(md3, "|  | Text-to-image | _27.00_ | 0.000 | 10.50 | — | 0.800 | 0.4100 | 2 |")
    tex3 = (out / "scene_table.tex").read_text()
    assert tex3.count(r"\midrule") == 2  # under the header and between the two scenes
    assert r"\begin{tabular}{llrrrrrrr}" in tex3


def test_block_table_ranks_within_each_scene(paper_runs):
    t = block_table(collect(paper_runs), ("psnr",))
    assert list(t.index.names) == ["Scene", "Method"]
    assert list(t.index) == [
        ("kitchen", "w/o time travel"),
        ("kitchen", "Snellcaster"),
        ("kitchen", "Text-to-image"),
        ("office", "w/o time travel"),
        ("office", "Snellcaster"),
        ("office", "Text-to-image"),
    ]
    from snell_bench.reports import rank_marks

    ranks = rank_marks(t)
    # kitchen: 21.0 best, 18.5 second; office: 25.0 best, 22.0 second
    assert ranks == {(1, 0): 1, (0, 0): 2, (4, 0): 1, (3, 0): 2}


def test_a_metric_not_recorded_anywhere_is_a_column_of_dashes_with_a_note(tmp_path):
    root = tmp_path / "runs"
    for v, psnr in enumerate((10.0, 14.0)):
        _cell(root, "kitchen", v, "sphere", "snellcaster", {"psnr": psnr}, {})
    md = tmp_path / "r" / "method_table.md"
    build_reports(root, tmp_path / "r", "x")
    text = md.read_text()
    assert has_row(text, "| Snellcaster | — | — | 12.00 | — | 2 |")
    for label in ("CLIP", "ImageReward", "LPIPS"):
        assert f"- {label}: not recorded in any of the 2 ok cells" in text
    assert "LPIPS (box)" not in text  # not recorded: the paper protocol's cells have no box LPIPS


def test_recipe_and_protocol_from_the_config_or_the_record():
    assert recipe_and_protocol({"recipe": "authors", "metrics": {"protocol": "authors"}}) == {
        "recipe": "authors",
        "protocol": "authors",
    }
    assert recipe_and_protocol({"recipe": {"name": "paper"}}) == {"recipe": "paper", "protocol": None}
    assert recipe_and_protocol({"overrides": ["+experiment=main", "recipe=authors"]})["recipe"] == "authors"
    assert recipe_and_protocol(None) == {"recipe": None, "protocol": None}


def test_provenance_names_the_recipe_and_protocol_of_each_cell(tmp_path):
    root = tmp_path / "runs"
    _cell(root, "kitchen", 0, "sphere", "snellcaster", {"psnr": 1.0}, {}, config=AUTHORS_CONFIG)
    # a record that states its own recipe wins over config.yaml
    _cell(
        root, "kitchen", 1, "sphere", "snellcaster", {"psnr": 1.0}, {}, extra={"recipe": "paper", "protocol": "paper"}
    )
    line = provenance_line(collect(root))
    assert "recipe: authors ×1, paper ×1" in line and "metrics protocol: authors ×1, paper ×1" in line
    # cells that record neither (no config.yaml): nothing is claimed
    bare = tmp_path / "bare"
    d = _cell(bare, "kitchen", 0, "sphere", "snellcaster", {"psnr": 1.0}, {})
    (d / "config.yaml").unlink()
    assert "recipe" not in provenance_line(collect(bare))


# ---------------------------------------------------------------------------- figures
@pytest.mark.parametrize("n, k", [(0, 4), (1, 4), (4, 4), (5, 4), (9, 4), (7, 1), (3, 10)])
def test_pages_hold_every_row_once(n, k):
    rows = list(range(n))
    got = pages(rows, k)
    assert len(got) == math.ceil(n / k)
    assert [r for p in got for r in p] == rows and all(1 <= len(p) <= k for p in got)
    with pytest.raises(ValueError, match="max_rows"):
        pages(rows, 0)


def _height_rows(path, tile_w=2.4, aspect=H / W, dpi=100):
    with Image.open(path) as im:
        h = im.size[1]
    return (h / dpi - 0.3) / (tile_w * aspect)


def test_qualitative_pages_draw_every_row(tmp_path):
    root = tmp_path / "runs"
    scenes = ["a", "b", "c", "d", "e", "f", "g"]  # 7 rows, 3 a page: pages of 3, 3, 1
    for s in scenes:
        _cell(root, s, 0, "sphere", "snellcaster", {"psnr": 1.0}, {})
    df = collect(root)
    assert figure_rows(df) == [(s, 0, "sphere") for s in scenes]
    out = qualitative_pages(root, tmp_path / "fig", max_rows=3)
    assert [p.name for p in out] == ["qualitative_1.png", "qualitative_2.png", "qualitative_3.png"]
    assert [round(_height_rows(p)) for p in out] == [3, 3, 1]
    # a rebuild with fewer pages leaves no stale page behind
    build_reports(root, tmp_path / "r", "x", max_rows=3)
    build_reports(root, tmp_path / "r", "x", max_rows=4)
    assert sorted(p.name for p in (tmp_path / "r").glob("qualitative_*.png")) == [
        "qualitative_1.png",
        "qualitative_2.png",
    ]


def test_panorama_pages_pair_each_image_with_its_panorama(tmp_path):
    root = tmp_path / "runs"
    rng = np.random.default_rng(0)
    for s in ("a", "b", "c"):
        d = _cell(root, s, 0, "sphere", "snellcaster", {"psnr": 1.0}, {})
        _png(d / "panorama.png", rng.integers(0, 255, (16, 32, 3)))
    _cell(root, "a", 0, "sphere", "t2i", {"psnr": 1.0}, {})  # no panorama: no row
    out = panorama_pages(root, tmp_path / "fig", max_rows=2, dpi=100)
    assert [p.name for p in out] == ["panorama_1.png", "panorama_2.png"]
    with Image.open(out[0]) as im:
        w, h = im.size
    tile_h = 2.4 * H / W
    # the image tile (2.4 in) and the panorama at the same height, twice as wide as high
    assert abs(w - 100 * (0.3 + 2.4 + 2 * tile_h)) <= 2 and abs(h - 100 * (0.3 + 2 * tile_h)) <= 2
    assert round(_height_rows(out[1])) == 1


# ---------------------------------------------------------------------------- IOR and time travel
def test_ior_sweep_report_orders_by_ior_and_draws_every_row(tmp_path):
    root = tmp_path / "runs"
    iors = ["1", "1.333", "1.45", "1.5", "2.418"]
    for i, ior in enumerate(iors):
        for method, psnr in (("snellcaster", 20.0 + i), ("t2i", 10.0 + i)):
            _cell(
                root,
                "living_room",
                0,
                f"sphere-ior{ior}",
                method,
                {"psnr": psnr, "lpips": None},
                {"lpips": LPIPS_REASON},
            )
    assert object_ior("sphere-ior2.418") == ("sphere", 2.418) and math.isnan(object_ior("sphere")[1])
    out = tmp_path / "r"
    paths = {p.name for p in build_reports(root, out, "ior_sweep", max_rows=2)}
    assert {"ior_table.md", "ior_table.tex", "ior_table.csv", "ior.png"} <= paths
    t = pd.read_csv(out / "ior_table.csv", index_col=[0, 1])
    assert list(dict.fromkeys(t.index.get_level_values(0))) == [f"sphere-ior{x}" for x in iors]
    assert t.loc[("sphere-ior2.418", "Snellcaster"), "psnr"] == pytest.approx(24.0)
    assert round(_height_rows(out / "ior.png")) == len(iors)  # every row, although max_rows is 2


def test_tables_never_average_the_swept_ior(tmp_path):
    """Cells of one object at several IORs: every table that groups cells keeps the IOR apart (a
    block per IOR), so each value is the mean at one IOR, never across IORs."""
    root = tmp_path / "runs"
    psnr = {}
    for s, scene in enumerate(("kitchen", "office")):
        for i, ior in enumerate(("1", "1.5", "2.418")):
            for method, base in (("snellcaster", 20.0), ("t2i", 10.0)):
                psnr[(scene, ior, method)] = base + 3 * i + s
                _cell(root, scene, 0, f"sphere-ior{ior}", method, {"psnr": psnr[(scene, ior, method)]}, {})
    out = tmp_path / "r"
    build_reports(root, out, "ior_sweep")
    scene = pd.read_csv(out / "scene_table.csv", index_col=[0, 1, 2])
    assert list(scene.index.names) == ["IOR", "Scene", "Method"]
    assert len(scene) == len(psnr)
    for (sc, ior, method), v in psnr.items():
        assert (
            scene.loc[(float(ior), sc, LABELS[method]), "psnr"] == v
            and scene.loc[(float(ior), sc, LABELS[method]), "n"] == 1
        )
    methods = pd.read_csv(out / "method_table.csv", index_col=[0, 1])
    assert list(methods.index.names) == ["IOR", "Method"]
    for ior in ("1", "1.5", "2.418"):
        for method in ("snellcaster", "t2i"):
            expect = mean(psnr[("kitchen", ior, method)], psnr[("office", ior, method)])
            assert methods.loc[(float(ior), LABELS[method]), "psnr"] == pytest.approx(expect)
    # ranked within each IOR (and scene): Snellcaster is best in every block
    md = (out / "scene_table.md").read_text()
    blocks_best = [r for r in md_rows(md) if r[2:5] == ["Snellcaster", "—", "—"] and r[5].startswith("**")]
    assert len(blocks_best) == 6 and "best per column within each IOR and scene" in md
    # the scene table of one metric, too; an IOR table grouped by object has no IOR level (one per object)
    t = scene_table(collect(root))
    assert list(t.index.names) == ["IOR", "Scene"] and t.loc[("2.418", "office"), "Snellcaster"] == 27.0
    assert list(pd.read_csv(out / "ior_table.csv", index_col=[0, 1]).index.names) == ["Object", "Method"]


TT_PSNR = {"tt_r1": 20.0, "tt_joint_r3": 21.0, "tt_joint_r5": 21.5, "tt_joint_r8": 21.2}
TT_PSNR.update({"tt_main_r3": 20.5, "tt_main_r5": 20.7, "tt_main_r8": 20.6})


def test_time_travel_table_and_figure(tmp_path):
    root = tmp_path / "runs"
    for scene, offset in (("kitchen", 0.0), ("office", 1.0)):
        for method, psnr in TT_PSNR.items():
            _cell(
                root,
                scene,
                0,
                "sphere",
                method,
                {"psnr": psnr + offset, "lpips": 0.5 - psnr / 100, "mae": 0.1},
                {},
                label=method,
                extra={"model_calls": {"main": 20 + len(method), "pano": 20}},
            )
    t = time_travel_table(collect(root))
    assert list(t.index.names) == ["Variant", "R_main"]
    joint, main = "joint (R_pano = R_main)", "main only (R_pano = 1)"
    assert list(t.index) == [(joint, 1), (joint, 3), (joint, 5), (joint, 8), (main, 1), (main, 3), (main, 5), (main, 8)]
    for (variant, r), row in t.iterrows():
        name = "tt_r1" if r == 1 else f"tt_{'joint' if variant == joint else 'main'}_r{r}"
        assert row["psnr"] == pytest.approx(TT_PSNR[name] + 0.5), (variant, r)
        assert row["lpips"] == pytest.approx(0.5 - TT_PSNR[name] / 100), (variant, r)
        assert row["n"] == 2 and row["timings_s.sampling"] == pytest.approx(10.0)
        assert row["model_calls.main"] == 20 + len(name)
    out = tmp_path / "r"
    paths = {p.name for p in build_reports(root, out, "time_travel")}
    assert {"time_travel_table.md", "time_travel_table.csv", "time_travel.png"} <= paths
    md = (out / "time_travel_table.md").read_text()
    head = "| Variant | R_main | PSNR ↑ | LPIPS ↓ | MAE ↓ | CLIP ↑ | ImageReward ↑ | model calls | sampling (s) | n |"
    assert has_row(md, head)
    assert ["", "5", "**22.00**"] in [r[:3] for r in md_rows(md)]  # best PSNR of the joint variant
    with Image.open(out / "time_travel.png") as im:
        assert np.asarray(im.convert("RGB")).std() > 5
    assert len(TIME_TRAVEL_ROWS) == 7 and {m for m, _, _ in TIME_TRAVEL_ROWS} == set(TT_PSNR)


# ---------------------------------------------------------------------------- configs
def test_time_travel_experiment_composes_with_seven_methods():
    from snell_bench.config import compose
    from snell_bench.pipeline import apply_method

    cfg = compose(["+experiment=time_travel"])
    assert list(cfg.grid.methods) == [m for m, _, _ in TIME_TRAVEL_ROWS]
    assert list(cfg.grid.objects) == ["sphere"] and len(cfg.grid.scenes) == 6
    for method, variants, r in TIME_TRAVEL_ROWS:
        c = apply_method(compose(["+experiment=time_travel", f"method={method}"]))
        assert c.sampler.time_travel is True
        assert c.sampler.tt_repeats_main == r, method
        assert c.sampler.tt_repeats_pano == (r if "joint" in variants and r > 1 else 1), method


def test_ior_sweep_and_ablation_experiments_compose():
    from snell_bench.config import compose

    cfg = compose(["+experiment=ior_sweep"])
    iors = [float(o.split(":")[1]) for o in cfg.grid.objects]
    assert {1.333, 1.45, 1.5, 2.418} <= set(iors) and iors == sorted(iors)
    ab = compose(["+experiment=ablation"])
    assert list(ab.grid.methods) == [m for m, _ in ABLATION_ROWS]
    assert list(ab.grid.objects) == ["sphere"] and len(ab.grid.scenes) == 6


# ---------------------------------------------------------------------------- the panorama of a cell


def test_a_snellcaster_cell_saves_and_lists_its_panorama(tmp_path):
    from tiny_runs import smoke_cfg

    from snell_bench.experiment.runner import run_grid

    cfg = smoke_cfg(tmp_path, "grid.scenes=[living_room]", "grid.methods=[snellcaster,t2i]")
    summary = run_grid(cfg)
    assert summary["ok"] == 2, summary
    cell = tmp_path / "runs" / "smoke" / "living_room-0" / "sphere"
    pano = cell / "snellcaster" / "panorama.png"
    with Image.open(pano) as im:
        assert im.size == (64, 32)  # (2 h, h), h = warps.pano_height
    rec = json.loads((cell / "snellcaster" / "metrics.json").read_text())
    assert rec["files"]["panorama.png"]["sha256"] == hashlib.sha256(pano.read_bytes()).hexdigest()
    assert rec["recipe"] == str(cfg.get("recipe")) and rec["protocol"] == str(cfg.metrics.protocol)
    assert not (cell / "t2i" / "panorama.png").exists()  # no panorama branch
    reports = tmp_path / "reports" / "smoke"
    assert (reports / "panorama_1.png").is_file() and (reports / "qualitative_1.png").is_file()
    # a deleted panorama makes the cell unfinished: resume computes it again
    pano.unlink()
    again = run_grid(cfg.copy())
    assert again["ok"] == 1 and again["cached"] == 1 and pano.is_file()
