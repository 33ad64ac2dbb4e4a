"""The HTML report (index.html) from hand-made cells: its tables against the CSV files, its images on
disk, the gallery's rows, tiles and captions against the cells' metrics.json, the |error| maps against
an independent histogram matching, escaping, the plots of swept axes, the reasons of missing values,
and the speed/accuracy sweep's page."""

import json
import math
import re
import time
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from snell_bench.reports import build_reports, collect, method_table
from snell_bench.reports.gallery import ERROR_LEVELS, ERROR_SCALES
from tests.reports.test_paper_reports import AUTHORS_CONFIG, _cell
from tests.reports.test_reports import CELLS, LPIPS_REASON, OOM, SKIP, make_runs, md_rows

# ---------------------------------------------------------------------------- a small DOM

VOID = {"img", "br", "meta", "input", "link", "hr", "source", "wbr", "col", "area", "base", "embed", "track"}


class Node:
    """An element: tag, attributes, children (nodes and text strings)."""

    def __init__(self, tag, attrs, parent=None):
        self.tag, self.attrs, self.parent, self.children = tag, dict(attrs), parent, []

    def text(self) -> str:
        return "".join(c if isinstance(c, str) else c.text() for c in self.children)

    def iter(self, tag=None):
        for c in self.children:
            if isinstance(c, Node):
                if tag is None or c.tag == tag:
                    yield c
                yield from c.iter(tag)

    def find_all(self, tag=None, **attrs):
        def match(n):
            for k, v in attrs.items():
                k = k.rstrip("_").replace("_", "-")
                have = n.attrs.get(k)
                if k == "class":
                    if have is None or v not in have.split():
                        return False
                elif have != v:
                    return False
            return True

        return [n for n in self.iter(tag) if match(n)]

    def find(self, tag=None, **attrs):
        found = self.find_all(tag, **attrs)
        return found[0] if found else None


class TreeBuilder(HTMLParser):
    """html.parser into :class:`Node` trees (entities decoded, void elements closed)."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.root = Node("#document", {})
        self.cur = self.root

    def handle_starttag(self, tag, attrs):
        node = Node(tag, attrs, self.cur)
        self.cur.children.append(node)
        if tag not in VOID:
            self.cur = node

    def handle_startendtag(self, tag, attrs):
        self.cur.children.append(Node(tag, attrs, self.cur))

    def handle_endtag(self, tag):
        n = self.cur
        while n is not self.root and n.tag != tag:
            n = n.parent
        if n is not self.root:
            self.cur = n.parent

    def handle_data(self, data):
        self.cur.children.append(data)


def parse(path) -> Node:
    b = TreeBuilder()
    b.feed(Path(path).read_text(encoding="utf-8"))
    b.close()
    return b.root


def table_rows(doc, table_id):
    """(header texts, [[cell nodes] per body row]) of the table with this id."""
    t = doc.find("table", id=table_id)
    assert t is not None, table_id
    header = [th.text().strip() for th in t.find("thead").find_all("th")]
    rows = [
        [c for c in tr.children if isinstance(c, Node) and c.tag in ("th", "td")]
        for tr in t.find("tbody").find_all("tr")
    ]
    return header, rows


# ---------------------------------------------------------------------------- fixtures
W, H = 32, 24


def _png(path, rgb):
    Image.fromarray(np.asarray(rgb, np.uint8)).save(path)


@pytest.fixture
def grid(tmp_path):
    """The ablation cells of test_reports (two scenes, failed and skipped cells, LPIPS missing in
    some) with their report."""
    runs = make_runs(tmp_path / "runs" / "ablation")
    out = tmp_path / "reports" / "ablation"
    paths = build_reports(runs, out, "ablation")
    return runs, out, paths


IORS = ["1", "1.333", "2.418"]


def make_ior_runs(root, scenes=("kitchen", "office"), protocol_config=None):
    """One sphere at three IORs, two methods, in two scenes: PSNR = 20 + IOR index (+1 in the
    office) for Snellcaster, 10 + ... for text-to-image; a panorama for Snellcaster."""
    rng = np.random.default_rng(5)
    for s, scene in enumerate(scenes):
        for i, ior in enumerate(IORS):
            for method, base in (("snellcaster", 20.0), ("t2i", 10.0)):
                d = _cell(
                    root,
                    scene,
                    0,
                    f"sphere-ior{ior}",
                    method,
                    {"psnr": base + i + s, "mae": 0.1 * (i + 1), "lpips": None, "psnr_true": None},
                    {"lpips": LPIPS_REASON, "psnr_true": "no true render"},
                    config=protocol_config,
                )
                _png(d / "I_minus.png", rng.integers(0, 255, (H, W, 3)))
                if method == "snellcaster":
                    _png(d / "panorama.png", rng.integers(0, 255, (16, 32, 3)))
    return root


@pytest.fixture
def ior(tmp_path):
    runs = make_ior_runs(tmp_path / "runs" / "ior_sweep")
    out = tmp_path / "reports" / "ior_sweep"
    paths = build_reports(runs, out, "ior_sweep")
    return runs, out, paths


# ---------------------------------------------------------------------------- tables
def _csv(out, stem, header_levels):
    return pd.read_csv(out / f"{stem}.csv", index_col=list(range(header_levels)))


@pytest.mark.parametrize("fixture", ["grid", "ior"])
def test_every_table_holds_the_csv_numbers_with_the_markdown_marks(fixture, request):
    runs, out, paths = request.getfixturevalue(fixture)
    doc = parse(out / "index.html")
    stems = [p.stem for p in paths if p.suffix == ".csv" and p.stem not in ("savings", "savings_per_cell")]
    assert stems and all(doc.find("table", id=f"table-{s}") is not None for s in stems)
    for stem in stems:
        header, rows = table_rows(doc, f"table-{stem}")
        nidx = sum(1 for c in rows[0] if c.tag == "th")
        csv = _csv(out, stem, nidx)
        assert len(rows) == len(csv), stem
        assert header[:nidx] == list(csv.index.names), stem
        body = md_rows((out / f"{stem}.md").read_text())[2:]  # after the header and alignment lines
        assert len(body) == len(csv), stem
        for i, (cells, (key, values), md) in enumerate(zip(rows, csv.iterrows(), body)):
            key = key if isinstance(key, tuple) else (key,)
            labels = [c.text() for c in cells[:nidx]]
            assert [str(k) for k in labels] == [_label(k) for k in key], (stem, i)
            for j, (col, expect) in enumerate(values.items()):
                cell = cells[nidx + j]
                got = cell.attrs["data-value"]
                if pd.isna(expect):
                    assert got == "" and cell.text() == "—", (stem, i, col)
                else:
                    assert float(got) == float(expect), (stem, i, col)  # both full precision
                # the text and the best / second-best marks are the Markdown table's
                shown = md[nidx + j]
                cls = cell.attrs["class"].split()
                mark = "best" if shown.startswith("**") else "second" if shown.startswith("_") else None
                assert cell.text() == shown.strip("*_"), (stem, i, col)
                assert ("best" in cls, "second" in cls) == (mark == "best", mark == "second"), (stem, i, col)


def _label(k) -> str:
    if isinstance(k, float) and k.is_integer():
        return str(int(k))  # the IOR "1" read back as 1.0
    return str(k)


def test_every_image_and_link_is_relative_and_on_disk(ior):
    _, out, paths = ior
    doc = parse(out / "index.html")
    imgs = doc.find_all("img")
    assert imgs
    for n in imgs:
        src = n.attrs["src"]
        assert not re.match(r"^[a-z]+:|^/", src), src
        assert (out / src).is_file(), src
    for a in doc.find_all("a"):
        href = a.attrs["href"]
        if href.startswith("#"):
            assert doc.find(id=href[1:]) is not None, href
            continue
        assert not re.match(r"^[a-z]+:|^/", href), href
        assert (out / href).is_file(), href
    for s in doc.find_all("script"):
        if "src" in s.attrs:
            assert s.attrs["src"] == "plotly.min.js" and (out / "plotly.min.js").is_file()
    # every image the page shows is a copy: deleting the run folder keeps the page whole
    assert {p.name for p in (out / "images").iterdir()} == {Path(n.attrs["src"]).name for n in imgs} | {
        Path(a.attrs["href"]).name for a in doc.find_all("a") if a.attrs["href"].startswith("images/")
    }
    assert {out / "index.html", out / "plotly.min.js"} <= set(paths)
    assert all(p in paths for p in (out / "images").iterdir())


def test_gallery_has_a_row_per_group_and_a_tile_per_method_with_its_numbers(grid):
    runs, out, _ = grid
    doc = parse(out / "index.html")
    rows = doc.find("table", class_="gallery").find("tbody").find_all("tr")
    groups = sorted({(s, "sphere") for s, *_ in CELLS})
    assert (
        sorted((json.loads(r.attrs["data-scenes"])[0], json.loads(r.attrs["data-objects"])[0]) for r in rows) == groups
    )
    methods = ["snellcaster"] + sorted({m for _, m, *_ in CELLS} - {"snellcaster"})
    head = doc.find("table", class_="gallery").find("thead").find_all("th")
    assert [json.loads(th.attrs["data-methods"])[0] for th in head if "data-methods" in th.attrs] == methods
    for r in rows:
        scene = json.loads(r.attrs["data-scenes"])[0]
        tds = r.find_all("td", class_="method-cell")
        assert [json.loads(td.attrs["data-methods"])[0] for td in tds] == methods
        for td, method in zip(tds, methods):
            folder = runs / f"{scene}-0" / "sphere" / method
            if not folder.is_dir():
                assert "not run" in td.text()
                continue
            rec = json.loads((folder / "metrics.json").read_text())
            assert td.attrs["data-cell"] == f"{scene}-0/sphere/{method}"
            if rec["status"] != "ok":
                assert rec["status"] in td.text() and " ".join(rec["reason"].split()) in td.text()
                assert td.find("img") is None
                continue
            assert td.find("figure", class_="tile-image").find("img") is not None
            shown = {d.attrs["data-metric"]: d for d in td.find_all("div", class_="metric")}
            assert set(shown) >= {"psnr", "mae", "lpips", "clip", "psnr_true"}
            for name, node in shown.items():
                v = rec["metrics"].get(name)
                if v is None:
                    assert node.attrs["data-value"] == "" and node.find("dd").text() == "—"
                    assert node.find("dd").attrs["title"]  # the reason
                else:
                    assert float(node.attrs["data-value"]) == v
                    digits = {"psnr": 2, "mae": 4, "lpips": 3, "clip": 2, "image_reward": 3, "psnr_true": 2}[name]
                    assert node.find("dd").text() == f"{v:.{digits}f}"
            kinds = [f.attrs["class"].split()[1] for f in td.find_all("figure")]
            assert kinds == ["tile-image", "tile-error"]


# ---------------------------------------------------------------------------- |error| maps
def _magma():
    import matplotlib

    return np.round(matplotlib.colormaps["magma"](np.linspace(0, 1, ERROR_LEVELS))[:, :3] * 255).astype(int)


def _decode(rgb, scale):
    """Values of an |error| map PNG from its colours: the nearest colour of the 256-entry magma map."""
    lut = _magma()
    flat = rgb.reshape(-1, 3).astype(int)
    idx = np.argmin(((flat[:, None, :] - lut[None, :, :]) ** 2).sum(-1), axis=1)
    dist = ((flat - lut[idx]) ** 2).sum(-1)
    return (idx / (ERROR_LEVELS - 1) * scale).reshape(rgb.shape[:2]), dist.reshape(rgb.shape[:2])


def _error_map_of(doc, out, cell_dir):
    td = doc.find("td", class_="method-cell", data_cell=cell_dir)
    fig = td.find("figure", class_="tile-error")
    large = out / fig.find("a").attrs["href"]
    with Image.open(large) as im:
        return np.asarray(im.convert("RGB")), fig


def test_error_map_equals_an_independent_histogram_matching(grid):
    """The |error| map's colours decode to |match_histograms(gen, ref) - ref| of the gray PNG values
    inside the mask, computed here with skimage directly. The map stores 256 colour levels over
    [0, scale], so a value is drawn at the nearest level: within scale / 510 (half a level)."""
    from skimage.exposure import match_histograms

    runs, out, _ = grid
    doc = parse(out / "index.html")
    scale = float(doc.find("section", id="gallery").attrs["data-error-scale"])
    assert scale in ERROR_SCALES
    checked = 0
    for cell_dir in collect(runs).query("status == 'ok'")["cell_dir"]:
        d = runs / cell_dir
        gray = [
            np.asarray(Image.open(d / n).convert("RGB"), float) / 255 @ [0.299, 0.587, 0.114]
            for n in ("image.png", "reference.png")
        ]
        mask = np.asarray(Image.open(d / "mask.png").convert("L")) >= 128
        expect = np.abs(match_histograms(gray[0][mask], gray[1][mask]) - gray[1][mask])
        rgb, fig = _error_map_of(doc, out, cell_dir)
        assert rgb.shape[:2] == mask.shape  # the larger copy is the full resolution
        values, dist = _decode(rgb, scale)
        assert (dist[mask] == 0).all()  # every scored pixel is a colour of the map (lossless PNG)
        np.testing.assert_allclose(
            values[mask], np.minimum(expect, scale), rtol=0, atol=scale / (2 * (ERROR_LEVELS - 1)) + 1e-12
        )
        outside = rgb[~mask]
        assert (outside[:, 0] == outside[:, 1]).all() and (outside[:, 1] == outside[:, 2]).all()  # gray context
        assert f"mean {expect.mean():.4f}" in fig.text()
        checked += 1
    assert checked == sum(1 for c in CELLS if c[3] == "ok")


def test_error_map_of_the_authors_protocol_has_their_mae_as_mean(tmp_path):
    """Cells scored under metrics.protocol=authors: the map's mean over the mask is the authors'
    MAE of the PNG files (their 256-bin matching, float32): equal up to float32 summation order and
    the 8-bit colour levels (half a level per pixel at most)."""
    from snell_bench.metrics import authors_metrics

    runs = make_ior_runs(tmp_path / "runs", scenes=("kitchen",), protocol_config=AUTHORS_CONFIG)
    out = tmp_path / "r"
    build_reports(runs, out, "authors")
    doc = parse(out / "index.html")
    scale = float(doc.find("section", id="gallery").attrs["data-error-scale"])
    for cell_dir in collect(runs)["cell_dir"]:
        d = runs / cell_dir
        img, ref = (np.asarray(Image.open(d / n).convert("RGB")) for n in ("image.png", "reference.png"))
        mask = np.asarray(Image.open(d / "mask.png").convert("L")) >= 128
        mae = authors_metrics(img, ref, mask).mae
        rgb, fig = _error_map_of(doc, out, cell_dir)
        assert "authors protocol" in fig.text()
        values, _ = _decode(rgb, scale)
        half_level = scale / (2 * (ERROR_LEVELS - 1))
        if (values[mask] < scale).all():  # nothing saturated: the map's mean is the MAE
            assert values[mask].mean() == pytest.approx(mae, abs=half_level + 1e-6)
        else:  # values above the scale are drawn at the scale
            assert values[mask].mean() < mae + half_level
        assert float(re.search(r"mean (\d\.\d{4})", fig.text())[1]) == pytest.approx(mae, abs=5e-5 + 1e-6)


# ---------------------------------------------------------------------------- escaping
HOSTILE_SCENE = '<script>alert("scene")</script>'
HOSTILE_REASON = "<img src=x onerror=alert(1)> & 'quotes' \"too\""
HOSTILE_LABEL = "</td><b>bold</b>"


def test_strings_from_cell_files_are_escaped(tmp_path):
    root = tmp_path / "runs"
    d = _cell(root, "evil", 0, "sphere", "snellcaster", {"psnr": 20.0, "lpips": None}, {"lpips": HOSTILE_REASON})
    rec = json.loads((d / "metrics.json").read_text())
    (d / "metrics.json").write_text(json.dumps({**rec, "scene": HOSTILE_SCENE, "method_label": HOSTILE_LABEL}))
    f = _cell(root, "evil", 0, "sphere", "t2i", {"psnr": None}, {}, status="failed")
    rec = json.loads((f / "metrics.json").read_text())
    (f / "metrics.json").write_text(json.dumps({**rec, "scene": HOSTILE_SCENE, "reason": HOSTILE_REASON}))
    out = tmp_path / "r"
    build_reports(root, out, "evil")
    text = (out / "index.html").read_text()
    for s in (HOSTILE_SCENE, HOSTILE_REASON, HOSTILE_LABEL, "<img src=x", "<b>bold</b>"):
        assert s not in text
    doc = parse(out / "index.html")
    # the only elements are the page's own: no script but the inlined one, no image without a copy
    assert [s.attrs.get("type") for s in doc.find_all("script")] == [None]
    assert all(Path(i.attrs["src"]).parent.name == "images" for i in doc.find_all("img"))
    assert not doc.find_all("b")
    # and the strings read back as they were written
    page = doc.text()
    assert HOSTILE_SCENE in page and HOSTILE_LABEL in page and HOSTILE_REASON in page
    titles = [n.attrs.get("title", "") for n in doc.iter()]
    assert any(HOSTILE_REASON in t for t in titles)
    values = [json.loads(n.attrs["data-scenes"]) for n in doc.iter() if "data-scenes" in n.attrs]
    assert [HOSTILE_SCENE] in values
    boxes = [n.attrs["value"] for n in doc.find_all("input", data_filter="scenes")]
    assert boxes == [HOSTILE_SCENE]


# ---------------------------------------------------------------------------- plots of swept axes
def _plots(doc):
    return {
        s.attrs["id"].removesuffix("-spec"): json.loads(s.text())
        for s in doc.find_all("script", type="application/json")
    }


def test_ior_plot_has_one_point_per_ior_for_every_method(ior):
    runs, out, _ = ior
    doc = parse(out / "index.html")
    plots = _plots(doc)
    assert list(plots) == ["plot-ior"] and doc.find("div", id="plot-ior") is not None
    table = pd.read_csv(out / "method_table.csv", index_col=[0, 1])
    fig = plots["plot-ior"]
    psnr = [t for t in fig["data"] if t.get("xaxis", "x") == "x"]
    assert sorted(t["name"] for t in psnr) == ["Snellcaster", "Text-to-image"]
    for t in psnr:
        assert t["x"] == [float(x) for x in IORS]  # one point per IOR, in order
        expect = [table.loc[(float(x), t["name"]), "psnr"] for x in IORS]
        assert t["y"] == pytest.approx(expect, rel=1e-15)
        # the mean over the two scenes at that IOR: 20 + i + 0.5 (Snellcaster), 10 + i + 0.5
        base = 20.0 if t["name"] == "Snellcaster" else 10.0
        assert t["y"] == pytest.approx([base + i + 0.5 for i in range(len(IORS))])
    # every metric with a value has its subplot; LPIPS has none anywhere: no subplot
    titles = [a["text"] for a in fig["layout"]["annotations"]]
    assert titles == ["PSNR ↑ against IOR", "MAE ↓ against IOR"]


def test_no_plot_and_no_plotly_without_a_swept_axis(grid):
    _, out, paths = grid
    doc = parse(out / "index.html")
    assert not _plots(doc) and doc.find("section", id="sweeps") is None
    assert not (out / "plotly.min.js").exists() and all("src" not in s.attrs for s in doc.find_all("script"))


def test_time_travel_plot_against_r_main(tmp_path):
    from tests.reports.test_paper_reports import TT_PSNR

    root = tmp_path / "runs"
    for method, psnr in TT_PSNR.items():
        _cell(root, "kitchen", 0, "sphere", method, {"psnr": psnr}, {}, label=method)
    build_reports(root, tmp_path / "r", "time_travel")
    plots = _plots(parse(tmp_path / "r" / "index.html"))
    assert list(plots) == ["plot-r-main"]
    traces = {t["name"]: t for t in plots["plot-r-main"]["data"] if t.get("xaxis", "x") == "x"}
    joint = traces["joint (R_pano = R_main)"]
    assert joint["x"] == [1, 3, 5, 8] and joint["y"] == [
        TT_PSNR[m] for m in ("tt_r1", "tt_joint_r3", "tt_joint_r5", "tt_joint_r8")
    ]
    main = traces["main only (R_pano = 1)"]
    assert main["y"] == [TT_PSNR[m] for m in ("tt_r1", "tt_main_r3", "tt_main_r5", "tt_main_r8")]


# ---------------------------------------------------------------------------- missing values
def test_missing_metrics_carry_their_reasons(grid):
    _, out, _ = grid
    doc = parse(out / "index.html")
    header, rows = table_rows(doc, "table-method_table")
    lp = header.index("LPIPS ↓")
    flux = next(r for r in rows if r[0].text() == "FLUX-dev")
    assert flux[lp].text() == "—" and flux[lp].attrs["title"] == f"{LPIPS_REASON} (×2)"
    pano = next(r for r in rows if r[0].text() == "Snellcaster w/o panorama")  # no ok cell
    assert pano[header.index("PSNR ↑")].attrs["title"] == f"skipped: {SKIP}"
    # the failed kitchen cell of FLUX Fill: its reason in the per-scene table and the gallery
    _, scene_rows = table_rows(doc, "table-scene_table")
    fill = next(r for r in scene_rows if [c.text() for c in r[:2]] == ["kitchen", "FLUX Fill"])
    assert fill[2].attrs["title"] == f"failed: {OOM}"
    missing = doc.find("section", id="missing").text()
    assert f"LPIPS: no value in 2 of 7 ok cells (flux ×2) — {LPIPS_REASON}" in missing
    assert f"failed: kitchen-0 / sphere / inpaint — {OOM}" in missing
    assert f"skipped: living_room-0 / sphere / no_pano — {SKIP}" in missing
    gallery = doc.find("section", id="gallery")
    lpips = [n.find("dd") for n in gallery.find_all("div", data_metric="lpips")]
    assert any(dd.attrs.get("title") == LPIPS_REASON for dd in lpips)


# ---------------------------------------------------------------------------- the sweep's page
def make_tradeoff_runs(root):
    """A sweep (a grid of named override sets: ``<scene>-0/sphere/snellcaster@<setting>/metrics.json``)
    with a baseline, a steps axis (4, 8, 16), a resolution axis of labels and a preset, in two
    scenes; the 8-step setting fails in the kitchen."""
    settings = [("baseline", None, None), ("steps=4", "steps", 4), ("steps=8", "steps", 8), ("steps=16", "steps", 16)]
    settings += [("res=small", "res", "small"), ("res=large", "res", "large"), ("preset:fast", "preset", "fast")]
    for s, scene in enumerate(("kitchen", "office")):
        for order, (label, axis, value) in enumerate(settings):
            d = root / f"{scene}-0" / "sphere" / f"snellcaster@{label.replace(':', '-')}"
            d.mkdir(parents=True)
            failed = scene == "kitchen" and label == "steps=8"
            steps = value if axis == "steps" else 8
            rec = {
                "scene": scene,
                "variation": 0,
                "object": "sphere",
                "method": d.name,
                "method_name": "snellcaster",
                "setting": label,
                "setting_overrides": [f"sampler.steps={value}"] if axis == "steps" else [],
                "slug": d.name.split("@", 1)[1],
                "order": order,
                "axis": axis,
                "value": value,
                "overrides": {"sampler.steps": value} if axis == "steps" else {},
                "status": "failed" if failed else "ok",
                "reason": "sampler diverged <here>" if failed else None,
                "model": "mixture",
                "timings_s": {
                    "warps": 1.0,
                    "sampling": steps * 0.5 + s,
                    "reference": 2.0,
                    "metrics": 0.1,
                    "total": 3.1 + steps * 0.5 + s,
                },
                "metrics": {
                    "psnr": 20.0 + steps / 4 + s,
                    "psnr_converged": 19.0 + steps / 4 + s,
                    "psnr_true": 15.0 + s,
                    "lpips": None,
                },
                "missing": {"lpips": LPIPS_REASON},
            }
            (d / "metrics.json").write_text(json.dumps(rec))
    return root


def test_tradeoff_page_table_and_plots(tmp_path):
    from snell_bench.reports import collect_tradeoff, tradeoff_table

    root = make_tradeoff_runs(tmp_path / "runs" / "tradeoff")
    out = tmp_path / "r"
    paths = build_reports(root, out, "tradeoff")
    assert {"tradeoff.csv", "tradeoff.md", "pareto.png", "tradeoff.html", "index.html"} <= {p.name for p in paths}
    table = tradeoff_table(collect_tradeoff(root))
    doc = parse(out / "tradeoff.html")
    header, rows = table_rows(doc, "table-tradeoff")
    assert [r[0].text() for r in rows] == list(table.index)
    total, conv, lp = header.index("total"), header.index("PSNR (conv.)"), header.index("LPIPS")
    for r, (_, t) in zip(rows, table.iterrows()):
        assert float(r[total].attrs["data-value"]) == t["timings_s.total"]
        assert float(r[conv].attrs["data-value"]) == t["psnr_converged"]
        assert r[lp].text() == "—" and r[lp].attrs["title"] == LPIPS_REASON
        assert r[-1].text() == ("★" if t["pareto"] else "")
    assert "sampler diverged <here>" in doc.find("section", id="missing").text()
    plots = _plots(doc)
    assert list(plots) == ["plot-settings", "plot-pareto"]
    by_axis = {}
    for t in plots["plot-settings"]["data"]:
        by_axis.setdefault(t.get("xaxis", "x"), []).append(t)
    steps, res = by_axis["x"], by_axis["x2"]
    fid = next(t for t in steps if t["name"].startswith("PSNR vs converged"))
    assert fid["x"] == [4, 8, 16]  # numeric values on a numeric axis
    assert fid["y"] == pytest.approx([table.loc[s, "psnr_converged"] for s in ("steps=4", "steps=8", "steps=16")])
    assert next(t for t in res if t["name"].startswith("PSNR vs converged"))["x"] == ["small", "large"]
    pareto = plots["plot-pareto"]["data"]
    front = next(t for t in pareto if t["name"] == "Pareto front")
    assert sorted(front["text"]) == sorted(table.index[table["pareto"]])
    assert sum(len(t["x"]) for t in pareto if t["name"] != "Pareto front") == len(table)


def test_method_table_of_an_ior_sweep_has_a_block_per_ior(ior):
    runs, out, _ = ior
    df = collect(runs)
    t = method_table(df, ["psnr"])
    assert list(t.index.names) == ["IOR", "Method"]
    assert [k[0] for k in t.index] == [x for x in IORS for _ in range(2)]
    assert not math.isnan(t.loc[("1.333", "Snellcaster"), "psnr"])


def test_savings_table_holds_the_csv_numbers(tmp_path):
    root = tmp_path / "runs"
    for scene, sampling in (("kitchen", 4.0), ("office", 6.0)):
        _cell(root, scene, 0, "sphere", "snellcaster", {"psnr": 20.0}, {})
        decisions = {"panorama": {"used": scene == "office"}, "reflection": {"kept": True, "share_kept": 0.5}}
        extra = {"timings_s": {"warps": 1.0, "sampling": sampling}, "decisions": decisions}
        _cell(root, scene, 0, "sphere", "adaptive", {"psnr": 19.5}, {}, label="Adaptive", extra=extra)
    out = tmp_path / "r"
    build_reports(root, out, "adaptive")
    header, rows = table_rows(parse(out / "index.html"), "table-savings")
    csv = pd.read_csv(out / "savings.csv")
    assert header == list(csv.columns) and len(rows) == len(csv) == 1
    for cell, (col, v) in zip(rows[0], csv.iloc[0].items()):
        if isinstance(v, str):
            assert cell.text() == v, col
        elif pd.isna(v):
            assert cell.attrs["data-value"] == "" and cell.text() == "—", col
        else:
            assert float(cell.attrs["data-value"]) == float(v), col
    # time saved: 1 - (1 + 5) / (1 + 10); one cell of two without the panorama
    assert float(rows[0][header.index("time saved")].attrs["data-value"]) == pytest.approx(1 - 6 / 11)
    assert rows[0][header.index("panorama skipped")].text() == "1"
    tr = parse(out / "index.html").find("table", id="table-savings").find("tbody").find("tr")
    assert json.loads(tr.attrs["data-methods"]) == ["adaptive"]


def test_labels_in_plots_cannot_close_their_script(tmp_path):
    """A method label in a plot's JSON: escaped for the <script> element (``\\u003c``) and for
    Plotly's labels (``&lt;``), and read back as written."""
    root = make_ior_runs(tmp_path / "runs", scenes=("kitchen",))
    label = '</script><script>alert("x")</script> & more'
    for d in root.glob("*/*/t2i"):
        rec = json.loads((d / "metrics.json").read_text())
        (d / "metrics.json").write_text(json.dumps({**rec, "method_label": label}))
    out = tmp_path / "r"
    build_reports(root, out, "evil")
    text = (out / "index.html").read_text()
    assert label not in text and "<script>alert" not in text
    doc = parse(out / "index.html")
    assert [s.attrs.get("type") for s in doc.find_all("script") if "src" not in s.attrs] == [None, "application/json"]
    names = {t["name"] for t in _plots(doc)["plot-ior"]["data"]}
    assert names == {"Snellcaster", label.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")}


def test_reports_built_at_once_into_one_folder_take_turns(ior, monkeypatch):
    """Two shards of a grid that finish together both build the report: the builds take turns on
    the folder (one build's clean-up of ``images/`` would otherwise delete the other's
    temporaries), so both succeed and the report is the one a single build writes."""
    import threading

    from snell_bench.reports import build as build_module

    runs, out, _ = ior
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    inside, most = [0], [0]
    lock = threading.Lock()
    real = build_module._write_reports

    def counted(*args, **kwargs):
        with lock:
            inside[0] += 1
            most[0] = max(most[0], inside[0])
        try:
            time.sleep(0.2)  # widen the window the two builds would overlap in
            return real(*args, **kwargs)
        finally:
            with lock:
                inside[0] -= 1

    monkeypatch.setattr(build_module, "_write_reports", counted)
    errors = []

    def build():
        try:
            build_reports(runs, out, "ior_sweep")
        except Exception as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=build) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert errors == [] and most[0] == 1
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
