"""pbdyn evaluate --html: one self-contained page, loaded in a real headless Chromium (through its driver) that must
render every figure (non-zero natural size) and hold the tables; a screenshot is written as test output
(results/test-output/html_report.png)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

import pbdyn
from tests.conftest import ROOT, pbdyn_cmd
from tests.test_batch import small

def _browser():
    chromium = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
    driver = shutil.which("chromedriver") or ("/usr/bin/chromedriver" if Path("/usr/bin/chromedriver").exists()
                                              else None)
    if chromium is None or driver is None:   # make test installs them (tools/install_sysdeps.sh) where apt exists
        pytest.skip("no chromium / chromedriver on this machine (make test installs them with apt)")
    os.environ.setdefault("SE_OFFLINE", "true")   # never let Selenium fetch a driver: use the system's
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--disable-dev-shm-usage", "--window-size=1200,1600"):
        opts.add_argument(arg)
    return webdriver.Chrome(service=Service(driver), options=opts)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    d = tmp_path_factory.mktemp("html")
    out = d / "small.sqlite"
    pbdyn.run_batch(str(small(d)), out, workers=1, progress=False)
    return out


def test_the_html_report_renders_in_a_real_browser(store, tmp_path):
    page = tmp_path / "report.html"
    res = subprocess.run(pbdyn_cmd() + ["evaluate", str(store), "--bootstrap", "50", "--html", str(page)],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    text = page.read_text()
    assert not re.search(r'src="(?!data:)', text)                 # self-contained: no external file
    assert "pbdyn evaluation of batch_small" in text and pbdyn.__version__ in text
    driver = _browser()
    try:
        driver.get(page.absolute().as_uri())
        images = driver.execute_script(
            "return Array.from(document.images).map(i => [i.alt, i.complete, i.naturalWidth, i.naturalHeight])")
        tables = driver.execute_script(
            "return Array.from(document.querySelectorAll('table')).map(t => t.rows.length)")
        headings = driver.execute_script("return Array.from(document.querySelectorAll('h2')).map(h => h.textContent)")
        shot = ROOT / "results" / "test-output" / "html_report.png"
        shot.parent.mkdir(parents=True, exist_ok=True)
        assert driver.save_screenshot(str(shot))
    finally:
        driver.quit()
    assert len(images) >= 7 and all(ok and w > 0 and h > 0 for _, ok, w, h in images), images
    assert {"velocity_ratio", "survivability_trajectory", "metric_survivability"} <= {a for a, *_ in images}
    assert len(tables) >= 4 and all(n >= 2 for n in tables)
    assert "Success per planner pair" in headings and "Planner abilities (fitted difficulty)" in headings
    assert shot.stat().st_size > 20_000


def test_bad_html_paths_are_one_line_errors(store, tmp_path):
    (tmp_path / "afile").write_text("a file where a folder should be")
    for target in (tmp_path / "report.txt", tmp_path / "afile" / "report.html"):   # a missing folder is created
        res = subprocess.run(pbdyn_cmd() + ["evaluate", str(store), "--html", str(target)], capture_output=True,
                             text=True, timeout=300)
        assert res.returncode == 2 and "--html" in res.stderr and len(res.stderr.strip().splitlines()) == 1
        assert not target.exists()
