"""Reports from a fake run directory: means, counts, marks, provenance, notes, figure, files."""

import json
import math
import re

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from snell_bench.metrics import METRIC_NAMES
from snell_bench.reports import (
    METRICS,
    ablation_table,
    build_reports,
    collect,
    method_table,
    pipe_table,
    provenance_line,
    qualitative_figure,
    scene_table,
    skipped_files,
    summary_line,
    to_csv,
    to_latex,
    to_markdown,
)

W, H = 32, 24
LPIPS_REASON = "no VGG weights: set metrics.lpips_weights"
OOM = "CUDA out of memory"
OOM_RAW = "CUDA out of\n   memory"  # multi-line reasons are reported on one line
SKIP = "panorama branch disabled for this scene"

# (scene, method, label, status, reason, metrics); every cell has variation 0 and object sphere
CELLS = [
    (
        "kitchen",
        "snellcaster",
        "Snellcaster",
        "ok",
        None,
        dict(psnr=18.0, mae=0.12, lpips=0.30, clip=28.0, image_reward=0.3),
    ),
    (
        "living_room",
        "snellcaster",
        "Snellcaster",
        "ok",
        None,
        dict(psnr=20.0, mae=0.10, lpips=0.20, clip=30.0, image_reward=0.5),
    ),
    ("kitchen", "flux", "FLUX-dev", "ok", None, dict(psnr=14.0, mae=0.3, lpips=None, clip=27.0, image_reward=0.2)),
    ("living_room", "flux", "FLUX-dev", "ok", None, dict(psnr=12.0, mae=0.2, lpips=None, clip=31.0, image_reward=0.1)),
    (
        "kitchen",
        "inpaint",
        "FLUX Fill",
        "failed",
        OOM_RAW,
        dict(psnr=None, mae=None, lpips=None, clip=None, image_reward=None),
    ),
    (
        "living_room",
        "inpaint",
        "FLUX Fill",
        "ok",
        None,
        dict(psnr=16.0, mae=0.2, lpips=0.4, clip=25.0, image_reward=-0.1),
    ),
    (
        "living_room",
        "no_tt",
        "Snellcaster w/o TT",
        "ok",
        None,
        dict(psnr=17.0, mae=0.15, lpips=0.28, clip=29.5, image_reward=0.45),
    ),
    (
        "living_room",
        "no_dpa",
        "Snellcaster w/o DPA",
        "ok",
        None,
        dict(psnr=18.5, mae=0.11, lpips=0.26, clip=29.0, image_reward=0.4),
    ),
    (
        "living_room",
        "no_pano",
        "Snellcaster w/o panorama",
        "skipped",
        SKIP,
        dict(psnr=None, mae=None, lpips=None, clip=None, image_reward=None),
    ),
]
PROVENANCE = "model: analytic (CPU stand-in for FLUX) · scenes: procedural · 9 cells (7 ok, 1 failed, 1 skipped)"


def _png(path, rgb):
    Image.fromarray(np.asarray(rgb, np.uint8)).save(path)


def make_runs(root):
    """A run directory with the cells of ``CELLS`` (images only for ok cells)."""
    rng = np.random.default_rng(0)
    for scene, method, label, status, reason, metrics in CELLS:
        d = root / f"{scene}-0" / "sphere" / method
        d.mkdir(parents=True)
        missing = {"image_reward": None, "clip": None}
        if metrics["lpips"] is None:
            missing["lpips"] = LPIPS_REASON if status == "ok" else reason
        rec = {
            "experiment": "ablation",
            "scene": scene,
            "variation": 0,
            "object": "sphere",
            "method": method,
            "method_label": label,
            "status": status,
            "reason": reason,
            "model": "analytic",
            "scene_source": "procedural",
            "metrics": {**metrics, "psnr_true": None},
            "missing": missing,
            "timings_s": {"warps": 2.0, "sampling": 60.0, "reference": 5.0, "metrics": 0.5},
        }
        (d / "metrics.json").write_text(json.dumps(rec))
        (d / "config.yaml").write_text(f"method: {method}\n")
        if status != "ok":
            continue
        _png(d / "image.png", rng.integers(0, 255, (H, W, 3)))
        _png(d / "reference.png", rng.integers(0, 255, (H, W, 3)))
        _png(d / "I_minus.png", rng.integers(0, 255, (H, W, 3)))
        mask = np.zeros((H, W, 3), np.uint8)
        mask[8:16, 10:20] = 255
        _png(d / "mask.png", mask)
    return root


@pytest.fixture
def runs(tmp_path):
    return make_runs(tmp_path / "runs" / "ablation")


@pytest.fixture
def df(runs):
    return collect(runs)


def md_rows(md: str) -> list[list[str]]:
    """The cells of every pipe-table line of a Markdown text, without their padding (an escaped
    ``\\|`` stays in its cell)."""
    return [
        [c.strip() for c in re.split(r"(?<!\\)\|", line.strip()[1:-1])]
        for line in md.splitlines()
        if line.startswith("|")
    ]


def has_row(md: str, row: str) -> bool:
    """Whether a pipe table of ``md`` holds ``row`` (one pipe-table line), whatever the padding."""
    return md_rows(row)[0] in md_rows(md)


def _latex_rows(tex):
    """{row label: [cell texts]} of a LaTeX tabular body."""
    body = tex.split(r"\midrule")[1].split(r"\bottomrule")[0]
    rows = {}
    for line in body.strip().splitlines():
        cells = [c.strip() for c in line.rstrip().removesuffix(r"\\").split(" & ")]
        rows[cells[0]] = cells[1:]
    return rows


def _latex_header(tex):
    return [c.strip() for c in tex.split(r"\toprule")[1].split(r"\midrule")[0].strip().removesuffix(r"\\").split(" & ")]


def test_collect_one_row_per_cell_with_flat_columns(df):
    assert len(df) == len(CELLS)
    for col in (
        "status",
        "reason",
        "method",
        "method_label",
        "scene",
        "variation",
        "object",
        "model",
        "scene_source",
        "psnr",
        "mae",
        "lpips",
        "clip",
        "image_reward",
        "psnr_true",
        "missing.lpips",
        "timings_s.sampling",
        "cell_dir",
    ):
        assert col in df.columns, col
    assert list(df["scene"]) == sorted(df["scene"])  # sorted rows
    r = df[(df.scene == "kitchen") & (df.method == "inpaint")].iloc[0]
    assert r.status == "failed" and r.reason == OOM_RAW and math.isnan(r.psnr)
    assert r.cell_dir == "kitchen-0/sphere/inpaint"
    assert df["timings_s.sampling"].eq(60.0).all()
    assert set(df.loc[df.method == "flux", "missing.lpips"]) == {LPIPS_REASON}


def test_collect_skips_broken_records_and_keeps_unfinished_cells_as_failed(runs, caplog):
    bad = runs / "office-3" / "cylinder" / "snellcaster"
    bad.mkdir(parents=True)
    (bad / "metrics.json").write_text("{not json")
    (bad / "config.yaml").write_text("x: 1\n")  # a folder whose record is broken is not "incomplete" too
    unfinished = runs / "office-3" / "cylinder" / "flux"
    unfinished.mkdir(parents=True)
    (unfinished / "config.yaml").write_text("x: 1\n")
    shared = runs / "office-3" / "cylinder" / "_inputs"
    shared.mkdir(parents=True)
    (shared / "config.yaml").write_text("x: 1\n")
    df = collect(runs)
    assert len(df) == len(CELLS) + 1
    office = df[df.scene == "office"].set_index("method")
    assert list(office.index) == ["flux"] and (office.variation == 3).all()
    assert office.loc["flux", "status"] == "failed"
    assert office.loc["flux", "reason"] == "incomplete cell: config.yaml but no metrics.json"
    assert skipped_files(df) == [
        ("office-3/cylinder/snellcaster/metrics.json", skipped_files(df)[0][1]),
    ]
    assert skipped_files(df)[0][1].startswith("not valid JSON: Expecting property name")
    assert str(bad / "metrics.json") in caplog.text and "not valid JSON" in caplog.text


def test_method_table_means_and_counts(df):
    t = method_table(df, metrics=("clip", "image_reward", "psnr", "lpips", "mae"))
    assert list(t.index) == [
        "FLUX-dev",
        "FLUX Fill",
        "Snellcaster w/o DPA",
        "Snellcaster w/o panorama",
        "Snellcaster w/o TT",
        "Snellcaster",
    ]  # sorted by method name
    assert list(t.columns) == ["clip", "image_reward", "psnr", "lpips", "mae", "n"]
    assert t.loc["Snellcaster"].to_dict() == pytest.approx(
        dict(clip=29.0, image_reward=0.4, psnr=19.0, lpips=0.25, mae=0.11, n=2)
    )
    flux = t.loc["FLUX-dev"]
    assert flux["psnr"] == pytest.approx(13.0) and flux["clip"] == pytest.approx(29.0) and flux["n"] == 2
    assert math.isnan(flux["lpips"])
    fill = t.loc["FLUX Fill"]  # the failed kitchen cell is not averaged
    assert fill["n"] == 1 and fill["psnr"] == pytest.approx(16.0)
    skipped = t.loc["Snellcaster w/o panorama"]
    assert skipped["n"] == 0 and skipped[["clip", "psnr", "lpips"]].isna().all()
    assert t["n"].dtype.kind == "i"

    ordered = method_table(df, order=["snellcaster", "flux"])
    assert list(ordered.index[:3]) == ["Snellcaster", "FLUX-dev", "FLUX Fill"]


def test_latex_marks_best_and_second_best_with_ties(df):
    t = method_table(df, metrics=("clip", "image_reward", "psnr", "lpips", "mae"))
    tex = to_latex(t, "Methods")
    assert _latex_header(tex) == [
        "Method",
        r"CLIP $\uparrow$",
        r"ImageReward $\uparrow$",
        r"PSNR $\uparrow$",
        r"LPIPS $\downarrow$",
        r"MAE $\downarrow$",
        "$n$",
    ]
    rows = _latex_rows(tex)
    snell, flux, fill = rows["Snellcaster"], rows["FLUX-dev"], rows["FLUX Fill"]
    tt, dpa, pano = rows["Snellcaster w/o TT"], rows["Snellcaster w/o DPA"], rows["Snellcaster w/o panorama"]
    # CLIP (higher is better): 29.50 best; 29.00 shared by three methods is second
    assert tt[0] == r"\textbf{29.50}"
    assert snell[0] == flux[0] == dpa[0] == r"\underline{29.00}"
    assert fill[0] == "25.00"
    # ImageReward: 0.450 best, 0.400 (tie) second
    assert tt[1] == r"\textbf{0.450}" and snell[1] == dpa[1] == r"\underline{0.400}" and flux[1] == "0.150"
    # PSNR: 19.00 best, 18.50 second
    assert snell[2] == r"\textbf{19.00}" and dpa[2] == r"\underline{18.50}" and tt[2] == "17.00"
    # LPIPS (lower is better): 0.250 best, 0.260 second, missing everywhere for FLUX-dev
    assert snell[3] == r"\textbf{0.250}" and dpa[3] == r"\underline{0.260}" and fill[3] == "0.400"
    assert flux[3] == "—"
    # MAE (lower is better): 0.1100 tie for best, 0.1500 second
    assert snell[4] == dpa[4] == r"\textbf{0.1100}" and tt[4] == r"\underline{0.1500}" and flux[4] == "0.2500"
    # counts are never marked; a method without ok cells is all dashes
    assert snell[5] == "2" and fill[5] == "1" and pano == ["—"] * 5 + ["0"]
    assert r"\caption{Methods. " + PROVENANCE.replace("·", r"$\cdot$") + ".}" in tex
    assert "failed: kitchen-0 / sphere / inpaint — CUDA out of memory" in tex


def test_ranking_ties_all_equal_and_single_value():
    t = pd.DataFrame(
        {"psnr": [10.0, 10.0, 10.004], "lpips": [0.5, float("nan"), float("nan")], "n": [1, 1, 1]},
        index=pd.Index(["a", "b", "c"], name="Method"),
    )
    rows = _latex_rows(to_latex(t, "T", provenance=""))
    # 10.004 prints as 10.00: all tie for best, nothing second; one LPIPS value: no mark
    assert [rows[k][0] for k in "abc"] == [r"\textbf{10.00}"] * 3
    assert rows["a"][1] == "0.500" and rows["b"][1] == "—"


def test_markdown_provenance_missing_and_notes(df):
    t = method_table(df)
    md = to_markdown(t, "Table 1")
    lines = md.splitlines()
    assert lines[0] == "## Table 1"
    assert f"_{PROVENANCE}_" in lines
    assert has_row(md, "| Method | CLIP ↑ | ImageReward ↑ | PSNR ↑ | LPIPS ↓ | n |")
    assert has_row(md, "| FLUX-dev | _29.00_ | 0.150 | 13.00 | — | 2 |")
    assert has_row(md, "| Snellcaster | _29.00_ | _0.400_ | **19.00** | **0.250** | 2 |")
    notes = md.split("### Notes")[1]
    assert "- failed: kitchen-0 / sphere / inpaint — CUDA out of memory" in notes
    assert f"- skipped: living_room-0 / sphere / no_pano — {SKIP}" in notes
    assert f"- LPIPS: no value in 2 of 7 ok cells (flux ×2) — {LPIPS_REASON}" in notes
    assert "nan" not in md.lower()
    # explicit provenance wins over the stored one
    assert "_custom source_" in to_markdown(t, "T", provenance="custom source")


def test_pipe_table_writes_cells_as_given_with_their_alignment():
    cells = [["1e5", "0010", "a\\|b", "True"], ["", "2.50", "—", "x y"]]
    lines = pipe_table(["a", "b", "c", "d"], cells, ["left", "right", "center", None])
    head, rule, *body = md_rows("\n".join(lines))
    assert head == ["a", "b", "c", "d"] and body == cells  # no number parsed or reformatted
    assert [re.sub("-+", "-", c) for c in rule] == [":-", "-:", ":-:", "-"]
    with pytest.raises(KeyError):
        pipe_table(["a"], [], ["middle"])


def test_scene_table_marks_best_per_scene(df):
    t = scene_table(df, "psnr")
    assert list(t.index) == ["kitchen", "living_room"]
    assert t.loc["kitchen", "Snellcaster"] == pytest.approx(18.0)
    assert t.loc["living_room", "FLUX Fill"] == pytest.approx(16.0)
    assert math.isnan(t.loc["kitchen", "FLUX Fill"])  # its only kitchen cell failed
    rows = _latex_rows(to_latex(t, "PSNR per scene"))
    cols = list(t.columns)
    k, lr = rows["kitchen"], rows["living\\_room"]
    assert k[cols.index("Snellcaster")] == r"\textbf{18.00}" and k[cols.index("FLUX-dev")] == r"\underline{14.00}"
    assert lr[cols.index("Snellcaster")] == r"\textbf{20.00}"
    assert lr[cols.index("Snellcaster w/o DPA")] == r"\underline{18.50}"
    assert k[cols.index("FLUX Fill")] == "—"


def test_ablation_rows_in_paper_order(df):
    t = ablation_table(df)
    assert list(t.index) == ["Full", "w/o panorama", "w/o DPA", "w/o time travel"]
    assert list(t.columns) == ["mae", "psnr", "lpips", "clip", "image_reward", "n"]
    assert t.loc["Full", "psnr"] == pytest.approx(19.0) and t.loc["w/o time travel", "mae"] == pytest.approx(0.15)
    assert list(t["n"]) == [2, 0, 1, 1]
    md = to_markdown(t, "Ablation")
    # provenance counts only the ablation cells; baselines are not part of it
    assert "_model: analytic (CPU stand-in for FLUX) · scenes: procedural · 5 cells (4 ok, 1 skipped)_" in md
    assert "inpaint" not in md


def test_csv_round_trips(df, tmp_path):
    for t in (method_table(df), scene_table(df), ablation_table(df)):
        path = tmp_path / "t.csv"
        to_csv(t, path)
        back = pd.read_csv(path, index_col=0)
        pd.testing.assert_frame_equal(back, t, check_exact=False, rtol=1e-12, check_flags=False)


def test_qualitative_figure_size(runs, tmp_path):
    out = qualitative_figure(runs, tmp_path / "fig.png", methods=["snellcaster", "flux", "inpaint"], dpi=100)
    with Image.open(out) as im:
        w, h = im.size
    # 4 columns (reference + 3 methods) of 2.4 in, 2 rows of 2.4 * 24/32 in, 0.3 in margins
    assert abs(w - 100 * (0.3 + 4 * 2.4)) <= 2 and abs(h - 100 * (0.3 + 2 * 1.8)) <= 2
    arr = np.asarray(Image.open(out).convert("RGB"))
    assert arr.std() > 10  # not blank
    no_inset = qualitative_figure(runs, tmp_path / "plain.png", cells=[("living_room", 0, "sphere")], inset=False)
    with Image.open(no_inset) as im:
        assert abs(im.size[0] - 100 * (0.3 + 7 * 2.4)) <= 2 and abs(im.size[1] - 100 * (0.3 + 1.8)) <= 2


def test_build_reports_writes_everything_deterministically(runs, tmp_path):
    out = tmp_path / "reports"
    paths = build_reports(runs, out, "ablation")
    names = sorted(p.name for p in paths)
    expected = sorted(
        f"{s}.{e}"
        for s in ("method_table", "scene_table", "ablation_table", "ablation_table_all")
        for e in ("md", "tex", "csv")
    )
    images = sorted(p.name for p in (out / "images").iterdir())
    assert names == sorted(expected + ["qualitative_1.png", "README.md", "index.html"] + images)  # two rows: one page
    assert all(p.is_file() and p.parent in (out, out / "images") for p in paths)
    readme = (out / "README.md").read_text()
    for n in expected + ["qualitative_1.png", "index.html"]:
        assert f"({n})" in readme
    assert PROVENANCE in readme and "CUDA out of memory" in readme
    method_md = (out / "method_table.md").read_text()
    assert "MAE ↓" in method_md and "PSNR (true)" not in method_md  # psnr_true is null in every cell
    first = {p.name: p.read_bytes() for p in paths}
    build_reports(runs, out, "ablation")
    assert {p.name: p.read_bytes() for p in paths} == first


RECORDED_METRICS = METRIC_NAMES + ("psnr_true",)  # what a cell's metrics.json holds


def _marks(tex, rows):
    """The mark ("best", "second" or None) of the first value cell of each row."""
    cells = _latex_rows(tex)
    return [
        ("best" if c[0].startswith(r"\textbf{") else "second" if c[0].startswith(r"\underline{") else None)
        for c in (cells[r] for r in rows)
    ]


@pytest.mark.parametrize("name", RECORDED_METRICS)
def test_every_recorded_metric_is_ranked_in_its_direction(name):
    assert name in METRICS, f"{name} is recorded by the runner but has no spec"
    spec = METRICS[name]
    t = pd.DataFrame({name: [1.0, 2.0, 3.0], "n": [1, 1, 1]}, index=pd.Index(["low", "mid", "high"], name="Method"))
    tex = to_latex(t, "T", provenance="")
    expect = [None, "second", "best"] if spec.higher_is_better else ["best", "second", None]
    assert _marks(tex, ["low", "mid", "high"]) == expect
    assert _latex_header(tex)[1] == f"{spec.label} " + (r"$\uparrow$" if spec.higher_is_better else r"$\downarrow$")
    md = to_markdown(t, "T", provenance="")
    best = "high" if spec.higher_is_better else "low"
    assert has_row(md, f"| {best} | **{spec.fmt(t.loc[best, name])}** | 1 |")
    assert has_row(md, f"| mid | _{spec.fmt(2.0)}_ | 1 |")
    assert has_row(md, f"| Method | {spec.label} {spec.arrow} | n |")


@pytest.mark.parametrize("name", RECORDED_METRICS)
def test_values_equal_as_printed_share_the_mark(name):
    spec = METRICS[name]
    decimals = len(spec.fmt(1.0).split(".")[1])
    tiny = 0.4 * 10.0**-decimals  # below the printed precision
    t = pd.DataFrame({name: [5.0, 5.0 + tiny, 9.0, 1.0]}, index=pd.Index(["a", "b", "c", "d"], name="Method"))
    assert spec.fmt(5.0) == spec.fmt(5.0 + tiny)
    marks = _marks(to_latex(t, "T", provenance=""), ["a", "b", "c", "d"])
    assert marks[0] == marks[1] == "second"  # 5.0 is second in either direction
    assert (marks[2], marks[3]) == (("best", None) if spec.higher_is_better else (None, "best"))


def test_the_better_image_is_marked_best():
    """The direction of PSNR and MAE matches what the metrics compute: of three images, the one
    closest to the reference is marked best and the farthest is not marked."""
    from snell_bench.metrics import masked_mae, masked_psnr

    rng = np.random.default_rng(3)
    ref = rng.random((24, 32, 3))
    mask = np.zeros((24, 32), bool)
    mask[4:20, 6:26] = True
    noise = rng.standard_normal(ref.shape)
    images = {f"s{k}": np.clip(ref + sigma * noise, 0, 1) for k, sigma in enumerate((0.02, 0.08, 0.3))}
    t = pd.DataFrame(
        {
            "psnr": [masked_psnr(im, ref, mask) for im in images.values()],
            "mae": [masked_mae(im, ref, mask) for im in images.values()],
        },
        index=pd.Index(list(images), name="Method"),
    )
    rows = _latex_rows(to_latex(t, "T", provenance=""))
    for j, col in enumerate(t.columns):
        assert rows["s0"][j].startswith(r"\textbf{"), col
        assert rows["s1"][j].startswith(r"\underline{"), col
        assert not rows["s2"][j].startswith("\\"), col


def test_cells_with_random_weights_are_in_no_table(runs, tmp_path):
    """A cell of ``model.random_init=true`` (real cost, meaningless pixels) is collected with the
    status ``random_weights`` and its reason: no mean, table or figure takes it."""
    d = runs / "kitchen-0" / "sphere" / "snellcaster"
    rec = json.loads((d / "metrics.json").read_text())
    (d / "metrics.json").write_text(
        json.dumps({**rec, "random_weights": True, "metrics": {**rec["metrics"], "psnr": 99.0}})
    )
    df = collect(runs)
    row = df[df["cell_dir"] == "kitchen-0/sphere/snellcaster"].iloc[0]
    assert row["status"] == "random_weights" and "model.random_init" in row["reason"]
    table = method_table(df, ["psnr"])
    assert table.loc["Snellcaster", "psnr"] == 20.0 and table.loc["Snellcaster", "n"] == 1  # the living room alone
    paths = build_reports(runs, tmp_path / "reports", "ablation")
    readme = next(p for p in paths if p.name == "README.md").read_text()
    assert "1 random_weights" in readme and "model.random_init" in readme


# ---------------------------------------------------------------------------- record files that are not cells
GOOD = {
    "experiment": "ablation",
    "scene": "office",
    "variation": 2,
    "object": "sphere",
    "method": "flux",
    "status": "ok",
    "reason": None,
    "metrics": {"psnr": 10.0},
}
#: name -> (the bytes of its metrics.json, what the report says is wrong with it)
NOT_CELLS = {
    "array": (b"[1, 2]", "a JSON array, not an object"),
    "handmade": (b'{"status": "ok"}', "missing the keys scene, variation, object, method, metrics"),
    "types": (
        json.dumps({**GOOD, "variation": "2", "metrics": {"psnr": "high"}}).encode(),
        "metrics.psnr: 'high' is not of type 'number', 'null'; variation: '2' is not of type 'integer'",
    ),
    "no_reason": (json.dumps({**GOOD, "status": "failed"}).encode(), "reason: None is not of type 'string'"),
    "status": (
        json.dumps({**GOOD, "status": "done"}).encode(),
        "status: 'done' is not one of ['ok', 'failed', 'skipped', 'degenerate']",
    ),
    "truncated": (b'{"status": "ok", "scene"', "not valid JSON: Expecting ':' delimiter: line 1 column 25 (char 24)"),
    "latin1": ('{"scene": "caf\xe9"}'.encode("latin-1"), "not UTF-8 text (byte 0xe9 at position 14)"),
}


def _add_not_cells(runs):
    for name, (raw, _) in NOT_CELLS.items():
        d = runs / "office-2" / "sphere" / name
        d.mkdir(parents=True)
        (d / "metrics.json").write_bytes(raw)
        (d / "config.yaml").write_text("x: 1\n")
    return {f"office-2/sphere/{name}/metrics.json": why for name, (_, why) in NOT_CELLS.items()}


def test_record_files_that_are_not_cells_are_skipped_named_and_counted(runs, tmp_path, caplog):
    expected = _add_not_cells(runs)
    df = collect(runs)
    assert len(df) == len(CELLS) and "office" not in set(df["scene"])  # not a cell, not an incomplete one
    assert dict(skipped_files(df)) == expected
    for rel, why in expected.items():
        assert f"{runs / rel} is not a cell record, left out of the report: {why}" in caplog.text
    assert provenance_line(df) == PROVENANCE + " · 7 files skipped (not cell records)"

    out = tmp_path / "reports"
    paths = build_reports(runs, out, "ablation")
    assert summary_line(out, paths) == (
        f"reports: {out} ({len(paths)} files); open {out / 'index.html'}; 7 record files skipped "
        f"(not cell records): see {out / 'README.md'}"
    )
    readme = (out / "README.md").read_text()
    section = readme.split("## Files skipped\n", 1)[1].split("\n## ", 1)[0]
    items = [line for line in section.splitlines() if line.startswith("- ")]
    assert len(items) == len(expected)
    for rel in expected:
        assert any(item.startswith(f"- `{rel}`: ") for item in items), rel
    assert "7 files skipped (not cell records)" in (out / "method_table.md").read_text()  # every table's provenance
    html = (out / "index.html").read_text()
    skipped = html.split('<section id="skipped">', 1)[1].split("</section>", 1)[0]
    assert skipped.count("<li>") == len(expected) and 'href="#skipped"' in html
    assert "metrics.psnr: &#39;high&#39; is not of type" in skipped  # the page escapes the problem too


def test_a_report_without_a_single_cell_record_names_the_files(tmp_path):
    from snell_bench.reports import NoCells

    runs = tmp_path / "runs" / "x"
    _add_not_cells(runs)
    with pytest.raises(NoCells, match=r"no metrics.json below .* that is a cell record: 7 skipped, e.g. office-2/"):
        build_reports(runs, tmp_path / "r", "x")
    with pytest.raises(NoCells, match=r"nothing/x does not exist"):
        build_reports(tmp_path / "nothing" / "x", tmp_path / "r", "x")
    assert not (tmp_path / "r").exists()


def test_non_finite_metrics_are_missing_with_their_reason(runs, tmp_path, caplog):
    d = runs / "kitchen-0" / "sphere" / "flux"
    rec = json.loads((d / "metrics.json").read_text())
    rec["metrics"] = {**rec["metrics"], "psnr": float("inf"), "mae": float("nan")}
    (d / "metrics.json").write_text(json.dumps(rec))  # JSON's Infinity and NaN, as Python writes them
    assert "Infinity" in (d / "metrics.json").read_text()
    df = collect(runs)
    row = df[df["cell_dir"] == "kitchen-0/sphere/flux"].iloc[0]
    assert math.isnan(row["psnr"]) and math.isnan(row["mae"])
    assert row["missing.psnr"] == "not finite in the record (inf)"
    assert row["missing.mae"] == "not finite in the record (nan)"
    for metric, value in (("psnr", "inf"), ("mae", "nan")):
        assert f"cell kitchen-0/sphere/flux: metric {metric} is {value} in {d / 'metrics.json'}" in caplog.text
    t = method_table(df, ["psnr", "mae"])
    assert t.loc["FLUX-dev", "psnr"] == 12.0 and t.loc["FLUX-dev", "mae"] == 0.2  # the living room's cell alone
    note = "PSNR: no value in 1 of 7 ok cells (flux ×1) — not finite in the record (inf)"
    assert note in t.attrs["notes"]
    out = tmp_path / "reports"
    build_reports(runs, out, "ablation")
    missing = (out / "index.html").read_text().split('<section id="missing">', 1)[1].split("</section>", 1)[0]
    assert note in missing and "not finite in the record (nan)" in missing


# ---------------------------------------------------------------------------- escaping
HOSTILE_MD = "a|b `c` <i>x</i> *y* [z](u) _w_ &amp; ~~v~~ \\*\nnext"


def _md_inline(md: str) -> dict[str, list]:
    """{"cells": [[inline tokens] per table cell], "items": [inline tokens per list item]} of the
    Markdown as a CommonMark + GFM-tables renderer reads it (HTML allowed)."""
    markdown_it = pytest.importorskip("markdown_it")
    tokens = markdown_it.MarkdownIt("commonmark", {"html": True}).enable(["table", "strikethrough"]).parse(md)
    out: dict[str, list] = {"cells": [], "items": []}
    where = None
    for t in tokens:
        if t.type in ("td_open", "th_open"):
            where = "cells"
        elif t.type == "list_item_open":
            where = "items"
        elif t.type == "inline" and where:
            out[where].append(t.children)
            where = None
    return out


def _plain_text(children) -> str | None:
    """The text of inline tokens, or None where any is markup (emphasis, code, link, HTML...)."""
    if any(c.type != "text" for c in children):
        return None
    return "".join(c.content for c in children)


def test_strings_from_cells_are_literal_in_markdown(runs):
    for d in (runs / "kitchen-0" / "sphere" / "flux", runs / "living_room-0" / "sphere" / "flux"):
        rec = json.loads((d / "metrics.json").read_text())
        (d / "metrics.json").write_text(json.dumps({**rec, "method_label": HOSTILE_MD}))
    d = runs / "kitchen-0" / "sphere" / "inpaint"
    rec = json.loads((d / "metrics.json").read_text())
    (d / "metrics.json").write_text(json.dumps({**rec, "reason": HOSTILE_MD}))
    one_line = " ".join(HOSTILE_MD.split())
    t = method_table(collect(runs), ["psnr", "lpips"])
    md = to_markdown(t, "Table 1")
    parsed = _md_inline(md)
    n_cols = 1 + len(t.columns)
    assert len(parsed["cells"]) == n_cols * (1 + len(t))  # every row kept its cells
    labels = [_plain_text(parsed["cells"][n_cols * (1 + i)]) for i in range(len(t))]
    assert labels == [" ".join(str(k).split()) for k in t.index] and one_line in labels  # as written, no markup
    items = [_plain_text(c) for c in parsed["items"]]
    assert f"failed: kitchen-0 / sphere / inpaint — {one_line}" in items


HOSTILE_TEX = "R&D 50% $x$ #1 a_b {c} ~d ^e \\f <g> |h|\n\ni"
#: LaTeX's text for each character that needs one (the independent reading of tex_escape's output).
TEX_TEXT = {
    r"\&": "&",
    r"\%": "%",
    r"\$": "$",
    r"\#": "#",
    r"\_": "_",
    r"\{": "{",
    r"\}": "}",
    r"\textasciitilde{}": "~",
    r"\textasciicircum{}": "^",
    r"\textbackslash{}": "\\",
    r"\textless{}": "<",
    r"\textgreater{}": ">",
    r"\textbar{}": "|",
}


def _tex_text(tex: str) -> str:
    out, i = [], 0
    while i < len(tex):
        for k, v in TEX_TEXT.items():
            if tex.startswith(k, i):
                out.append(v)
                i += len(k)
                break
        else:
            assert tex[i] not in "&%$#_{}~^\\<>|", (tex, i)  # an unescaped special character
            out.append(tex[i])
            i += 1
    return "".join(out)


def test_strings_from_cells_are_literal_in_latex(runs):
    for d in (runs / "kitchen-0" / "sphere" / "flux", runs / "living_room-0" / "sphere" / "flux"):
        rec = json.loads((d / "metrics.json").read_text())
        (d / "metrics.json").write_text(json.dumps({**rec, "method_label": HOSTILE_TEX, "model": HOSTILE_TEX}))
    t = method_table(collect(runs), ["psnr", "lpips"])
    tex = to_latex(t, "Table 1")
    one_line = " ".join(HOSTILE_TEX.split())
    body = tex.split(r"\midrule")[1].split(r"\bottomrule")[0].strip().splitlines()
    rows = [re.split(r"(?<!\\)&", line.rstrip().removesuffix(r"\\")) for line in body]
    assert all(len(r) == 1 + len(t.columns) for r in rows)  # no cell split by an & from a label
    assert one_line in [_tex_text(r[0].strip()) for r in rows]
    caption = tex.split(r"\caption{", 1)[1].split("}\n", 1)[0]
    assert "\n" not in caption and f"models: {one_line} ×2" in _tex_text(
        caption.replace(r"$\times$", "×").replace(r"$\cdot$", "·")
    )
    notes = tex.split(r"{\footnotesize", 1)[1]
    assert "\n\n" not in notes


def test_plots_of_cell_labels_stay_inside_their_script(tmp_path):
    from tests.reports.test_paper_reports import _cell

    evil = '</script><script>alert("x")</script> & <b>'
    root = tmp_path / "runs"
    for ior in ("1.5", "2"):
        for method in ("snellcaster", "t2i"):
            _cell(root, "kitchen", 0, f"sphere-ior{ior}", method, {"psnr": 20.0 + float(ior)}, {}, label=evil)
    out = tmp_path / "r"
    build_reports(root, out, "evil")
    html = (out / "index.html").read_text()
    assert "<script>alert" not in html and html.count("</script>") == html.count("<script")
    specs = re.findall(r'<script type="application/json" id="([^"]+)">(.*?)</script>', html, flags=re.S)
    assert specs and all("<" not in s and ">" not in s for _, s in specs)
    fig = json.loads(specs[0][1])
    shown = '&lt;/script&gt;&lt;script&gt;alert("x")&lt;/script&gt; &amp; &lt;b&gt;'  # Plotly's text is HTML
    assert {t["name"] for t in fig["data"]} == {f"{shown} (snellcaster)", f"{shown} (t2i)"}
