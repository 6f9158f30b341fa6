"""The Snakemake report and the study page of the quick run, opened in headless Chromium.

The report must show every result inside the page (the five tables, the findings, the time per
rule and the configuration as HTML tables and text in its frame, the figures as images, the
novel-view clips playing as WebM video), none of them as a download link, without a console error. The study
page must load its videos and save the choices as the CSV that ``study-ingest`` reads.

System tier (``pytest -m system``): Chromium is Debian's package, which .ci/run installs; without
it these tests fail, naming the command that installs it. They share the quick run of
tests/workflow_fixtures.py.
"""

import csv
import json
import time

import pandas as pd
import pytest
from chromium import BrowserUnavailable, Page, chromium_binary, report_frame, show_report_result
from workflow_fixtures import EXPERIMENT_CONFIGS, snakemake

RESULTS = "results/quick"  # results_dir of config/quick.yaml
TABLES = {1: "Table 1: method comparison", 2: "Table 2: versus DriveDreamer4D", 3: "Table 3: preference win rates",
          4: "Table 4: restorer backbones", 5: "Table 5: PDUS strides"}  # common.smk's TABLE_NAMES: the report's menu
SHOWN_INLINE = ("text/html", "image/png", "image/jpeg", "image/svg+xml")  # what the report displays; anything else is a download
ALL_IMAGES_LOADED = "document.images.length > 0 && [...document.images].every(image => image.complete && image.naturalWidth > 0)"


@pytest.fixture(scope="session")  # session: checked before the session's quick run is built, so a missing browser fails at once
def browser() -> str:
    try:
        return chromium_binary()
    except BrowserUnavailable as error:
        pytest.fail(str(error))


@pytest.fixture(scope="module")
def report(quick_experiment):
    root = quick_experiment.root
    run = snakemake(root, "--configfile", *EXPERIMENT_CONFIGS, "--report", "report-browser.html", timeout=600)
    assert run.returncode == 0, run.stderr[-5000:]
    return root / "report-browser.html"


def view(page: Page, *menu: str) -> None:
    """Back to the report's result categories, then through ``menu`` to the first result's view
    button, which must show the result in the page (a download link has a ``download`` attribute)."""
    page.click_text("Results")
    show_report_result(page, *menu)
    assert not page.evaluate("document.querySelector('a[iconname=eye]').hasAttribute('download')"), menu


def body_row_headers(page: Page, frame: str, table: str) -> list[str]:
    return page.evaluate(f"[...document.querySelectorAll('{table} tbody tr')].map(row => row.querySelector('th').textContent.trim())", frame)


@pytest.mark.system
@pytest.mark.timeout(1800)  # may build the quick run (tests/workflow_fixtures.py)
def test_report_shows_tables_findings_figures_clips_times_and_config_inline(browser, report, quick_experiment):
    results = quick_experiment.root / RESULTS
    with Page(browser) as page:
        page.open(report)
        page.wait_for("document.body.innerText.includes('1. Tables')", what="the report's menu")
        mime_types = page.evaluate("Object.fromEntries(Object.entries(results).map(([path, entry]) => [path, entry.mime_type]))")
        assert {path: mime for path, mime in mime_types.items() if mime not in SHOWN_INLINE} == {}
        expected_pages = {f"{RESULTS}/tables/table{n}.html" for n in TABLES} | {
            f"{RESULTS}/{name}" for name in ("findings.html", "benchmark_summary.html", "run_config.html", "clips/quick-01.html")}
        assert {path for path, mime in mime_types.items() if mime == "text/html"} == expected_pages

        for number, name in TABLES.items():
            view(page, "1. Tables", name)
            frame = report_frame(page, f"table{number}.html")
            assert page.evaluate("document.querySelector('h2').textContent", frame) == f"Table {number}"
            rows = pd.read_csv(results / "tables" / f"table{number}.csv", index_col="row", comment="#").index
            assert body_row_headers(page, frame, "table.results") == list(rows), number

        view(page, "0. Findings")
        frame = report_frame(page, "findings.html")
        verdicts = page.evaluate("[...document.querySelectorAll('table tr td:last-child b')].map(cell => cell.textContent)", frame)
        assert verdicts == list(pd.read_csv(results / "findings.csv")["verdict"])

        view(page, "3. Compute")
        frame = report_frame(page, "benchmark_summary.html")
        rules = body_row_headers(page, frame, "table")
        assert rules == list(pd.read_csv(results / "benchmark_summary.csv", index_col=0).index)
        assert {"evaluate", "novel_view_clip", "config_page"} <= set(rules)

        view(page, "4. Configuration")
        frame = report_frame(page, "run_config.html")
        assert page.evaluate("document.querySelector('pre').textContent", frame) == (results / "run_config.yaml").read_text()

        view(page, "2. Figures", "Novel-view clips")
        frame = report_frame(page, "quick-01.html")
        # The WebM video decodes (its first frame shown: readyState >= 2) and plays: its time advances.
        page.wait_for("(() => { const video = document.querySelector('video'); return video && video.readyState >= 2 && video.videoHeight; })()",
                      frame=frame, what="the clip's video decoded")
        assert page.evaluate("document.querySelector('video').src.startsWith('data:video/webm;base64,') && document.querySelector('video').videoHeight", frame) > 100
        page.wait_for("document.querySelector('video').currentTime > 0.3 && !document.querySelector('video').paused", frame=frame, what="the clip's video playing")
        assert page.evaluate("document.querySelector('video').error", frame) is None

        view(page, "2. Figures", "Metrics")
        page.wait_for(f"(() => {{ const image = document.querySelector('img[src^=\"data:image/png\"]'); return image && {ALL_IMAGES_LOADED}; }})()",
                      what="a metric figure shown as an image")

        assert page.errors() == []


@pytest.mark.system
@pytest.mark.timeout(1800)  # may build the quick run (tests/workflow_fixtures.py)
def test_study_page_loads_its_videos_and_saves_the_choices(browser, quick_experiment, tmp_path):
    study = quick_experiment.root / RESULTS / "study"
    clips = [clip["clip_id"] for clip in json.loads((study / "placement.json").read_text())["clips"]]
    with Page(browser) as page:
        page.send("Browser.setDownloadBehavior", behavior="allow", downloadPath=str(tmp_path))
        page.open(study / "index.html")
        page.wait_for(ALL_IMAGES_LOADED, what="the study videos loaded")
        assert page.evaluate("document.images.length") == 2 * len(clips)
        page.evaluate("document.getElementById('participant').value = 'tester 1'")
        page.evaluate("document.querySelectorAll('input[value=bottom]').forEach(choice => choice.click())")
        page.evaluate("document.getElementById('download').click()")
        saved = tmp_path / "study-tester_1.csv"
        deadline = time.monotonic() + 30
        while not saved.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert page.evaluate("document.getElementById('status').textContent") == f"{len(clips)} of {len(clips)} clips answered and saved."
        assert page.errors() == []
    with open(saved, newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [(row["participant"], row["clip_id"], row["choice"]) for row in rows] == [("tester 1", clip, "bottom") for clip in clips]
