"""The HTML report opened from disk in a headless Chromium (Selenium): no console error, every image
loaded, sorting by a column header, filtering by scene and method, the plots drawn, a screenshot that
is not blank. Skipped, saying why, where Chromium or its WebDriver is missing (`make test-slow`
installs both)."""

import io
import json
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from snell_bench.reports import build_reports
from tests.reports.test_html_report import IORS, make_ior_runs

pytestmark = pytest.mark.slow

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"


def _missing_browser() -> str | None:
    for path in (CHROMIUM, CHROMEDRIVER):
        if not Path(path).is_file() and shutil.which(Path(path).name) is None:
            return f"{path} not found: install Debian's chromium and chromium-driver (make system-deps-browser)"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed: pip install -e '.[test]'"
    return None


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """An IOR sweep (two scenes, three IORs, two methods, panoramas) with a failed cell."""
    tmp = tmp_path_factory.mktemp("html")
    runs = make_ior_runs(tmp / "runs" / "ior_sweep")
    from tests.reports.test_paper_reports import _cell

    _cell(runs, "office", 0, "sphere-ior1", "inpaint", {"psnr": None}, {}, status="failed")
    out = tmp / "reports" / "ior_sweep"
    build_reports(runs, out, "ior_sweep")
    return out


@pytest.fixture(scope="module")
def driver():
    why = _missing_browser()
    if why:
        pytest.skip(why)
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM if Path(CHROMIUM).is_file() else shutil.which("chromium")
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1400,1000"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    service = Service(CHROMEDRIVER if Path(CHROMEDRIVER).is_file() else shutil.which("chromedriver"))
    d = webdriver.Chrome(service=service, options=options)
    try:
        yield d
    finally:
        d.quit()


def _visible(driver, css):
    return [e for e in driver.find_elements("css selector", css) if e.is_displayed()]


def _column(driver, table_id, col):
    rows = driver.find_elements("css selector", f"#{table_id} tbody tr")
    return [r.find_elements("css selector", "th, td")[col].get_attribute("data-value") for r in rows]


def test_report_in_a_browser(report, driver):
    t0 = time.monotonic()
    driver.get((report / "index.html").resolve().as_uri())
    driver.execute_script("return document.readyState")
    # the plots are drawn after DOMContentLoaded: wait for their SVG (Plotly from plotly.min.js)
    deadline = time.monotonic() + 20
    while not driver.find_elements("css selector", "#plot-ior .main-svg") and time.monotonic() < deadline:
        time.sleep(0.1)
    assert driver.find_elements("css selector", "#plot-ior .main-svg"), "the IOR plot was not drawn"
    points = driver.find_elements("css selector", "#plot-ior .scatterlayer .trace")
    assert points  # one trace per method and metric

    # every image loaded
    images = driver.find_elements("css selector", "img")
    assert len(images) > 10
    broken = driver.execute_script(
        "return Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.src)"
    )
    assert broken == []

    # sorting: the method table's PSNR column, ascending then descending, missing values last
    header = driver.find_elements("css selector", "#table-method_table thead th")
    names = [h.text for h in header]
    col = names.index("PSNR ↑")
    before = _column(driver, "table-method_table", col)
    header[col].click()
    asc = _column(driver, "table-method_table", col)
    header[col].click()
    desc = _column(driver, "table-method_table", col)
    numbers = sorted(float(v) for v in before if v)
    assert [float(v) for v in asc if v] == numbers and [float(v) for v in desc if v] == numbers[::-1]
    assert all(v == "" for v in asc[len(numbers) :]) and all(v == "" for v in desc[len(numbers) :])
    assert header[col].get_attribute("aria-sort") == "descending"
    header[col].click()  # a third click restores the table's order
    assert _column(driver, "table-method_table", col) == before

    # filters: unchecking a scene hides its gallery rows; unchecking a method hides its column
    rows = _visible(driver, "table.gallery tbody tr")
    assert len(rows) == 2 * len(IORS)
    driver.find_element("css selector", '#filters input[data-filter="scenes"][value="office"]').click()
    shown = _visible(driver, "table.gallery tbody tr")
    assert len(shown) == len(IORS)
    assert all(json.loads(r.get_attribute("data-scenes")) == ["kitchen"] for r in shown)
    assert "3 of 6 gallery rows shown" in driver.find_element("id", "filter-status").text
    tiles = len(_visible(driver, "td.method-cell[data-methods='[\"t2i\"]']"))
    assert tiles == len(IORS)
    driver.find_element("css selector", '#filters input[data-filter="methods"][value="t2i"]').click()
    assert not _visible(driver, "td.method-cell[data-methods='[\"t2i\"]']")
    assert not _visible(driver, "table.gallery th[data-methods='[\"t2i\"]']")
    assert len(_visible(driver, "td.method-cell[data-methods='[\"snellcaster\"]']")) == len(IORS)
    # table rows whose cells are all filtered out are hidden too
    method_rows = _visible(driver, "#table-method_table tbody tr")
    assert method_rows and all("Text-to-image" not in r.text for r in method_rows)
    driver.find_element("css selector", '#filters button[data-for="scenes"][data-all="true"]').click()
    driver.find_element("css selector", '#filters button[data-for="methods"][data-all="true"]').click()
    assert len(_visible(driver, "table.gallery tbody tr")) == 2 * len(IORS)

    # a screenshot that shows something: varied pixels, many colours
    png = driver.get_screenshot_as_png()
    shot = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    assert shot.shape[0] > 500 and shot.shape[1] > 1000
    assert shot.std() > 20
    assert len(np.unique(shot.reshape(-1, 3), axis=0)) > 500
    driver.execute_script("document.getElementById('gallery').scrollIntoView()")
    shot = np.asarray(Image.open(io.BytesIO(driver.get_screenshot_as_png())).convert("RGB"))
    assert len(np.unique(shot.reshape(-1, 3), axis=0)) > 2000  # the thumbnails

    # no error in the console (a missing file, a script error)
    severe = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
    assert severe == []
    assert time.monotonic() - t0 < 60
