"""The exported study page in a real browser: headless Chromium loads it from disk and a participant answers by key.

Needs Chromium and its driver (Debian: ``apt-get install chromium chromium-driver``; ``scripts/install.sh`` does it
when run as root) and selenium; skipped with the reason otherwise.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Callable, Dict, Iterator, List
from urllib.parse import parse_qs

import pytest
import typer
from study_fixtures import make_study_db
from typer.testing import CliRunner

from meshadv.commands import study as study_cmd
from meshadv.study.export import export_study

selenium = pytest.importorskip("selenium", reason="selenium is not installed (pip install -r requirements.txt)")

from selenium import webdriver  # noqa: E402
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402

EXPOSURE_MS = 2000.0


def _browser_paths() -> tuple:
    binary = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)
    driver = shutil.which("chromedriver")
    if binary is None or driver is None:
        pytest.skip("no headless browser: install Chromium and its driver (apt-get install chromium "
                    "chromium-driver; scripts/install.sh does it when run as root)")
    return binary, driver


@pytest.fixture()
def browser(tmp_path: Path) -> Iterator[Any]:
    binary, driver_path = _browser_paths()
    options = webdriver.ChromeOptions()
    options.binary_location = binary
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1000,800",
                "--disable-gpu", "--no-first-run"):
        options.add_argument(arg)
    downloads = tmp_path / "downloads"
    downloads.mkdir()
    options.add_experimental_option("prefs", {"download.default_directory": str(downloads),
                                              "download.prompt_for_download": False})
    driver = webdriver.Chrome(service=webdriver.ChromeService(executable_path=driver_path), options=options)
    driver.execute_cdp_cmd("Browser.setDownloadBehavior", {"behavior": "allow", "downloadPath": str(downloads)})
    driver.downloads = downloads
    try:
        yield driver
    finally:
        driver.quit()


class _Collector(BaseHTTPRequestHandler):
    """Records POSTed bodies (what a crowdsourcing site's endpoint would receive)."""

    bodies: List[bytes] = []

    def do_POST(self) -> None:  # noqa: N802 - http.server's naming
        self.bodies.append(self.rfile.read(int(self.headers.get("Content-Length", 0))))
        self.send_response(200)
        self.send_header("Access-Control-Allow-Origin", "*")
        self.end_headers()

    def log_message(self, *args: Any) -> None:
        pass


@contextlib.contextmanager
def _serving(handler: type) -> Iterator[str]:
    """A local HTTP server with ``handler`` in a background thread; yields its base URL, shut down on exit."""
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


def _wait(driver: Any, what: Callable[[Any], Any], timeout: float = 15.0) -> Any:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = what(driver)
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout} s waiting in the page (phase "
                         f"{driver.execute_script('return window.STUDY_STATE && window.STUDY_STATE.phase')})")


def _phase(driver: Any) -> str:
    return driver.execute_script("return window.STUDY_STATE.phase")


# Watches the stimulus' `hidden` attribute independently of the page's own bookkeeping: frame-aligned times at which
# the image was shown and hidden.
_WATCH = """
window.WATCHED = [];
new MutationObserver(function () {
  var hidden = document.getElementById('stimulus').hidden;
  requestAnimationFrame(function (t) { window.WATCHED.push([hidden ? 'off' : 'on', t]); });
}).observe(document.getElementById('stimulus'), {attributes: true, attributeFilter: ['hidden']});
"""


def test_page_runs_the_2afc_protocol_in_chromium(browser: Any, tmp_path: Path) -> None:
    with _serving(_Collector) as base_url:
        db = make_study_db(tmp_path / "sweep")
        url = f"{base_url}/submit"
        study = export_study(db, tmp_path / "study", per_image=1, max_trials=6, controls=1, attention_checks=1,
                             seed=3, post_url=url, exposure_ms=EXPOSURE_MS, fixation_ms=300)
        plan = json.loads((tmp_path / "study" / "plan.json").read_text())
        trials = plan["participants"][0]["trials"]
        assert len(trials) == 6
        browser.get((tmp_path / "study" / "index.html").as_uri() + "?participant=0&workerId=w7")
        _wait(browser, lambda d: _phase(d) == "ready")
        assert "Participant 0:" in browser.find_element(By.ID, "participant-line").text
        browser.execute_script(_WATCH)
        keys = ["j", "f", "1", "2", "j"]
        ActionChains(browser).send_keys(" ").perform()
        for i, trial in enumerate(trials):
            stim = plan["stimuli"][trial["image_id"]]
            if i == 0:  # a key pressed while the image is on screen is not an answer
                _wait(browser, lambda d: _phase(d) == "exposure")
                ActionChains(browser).send_keys("f").perform()
            _wait(browser, lambda d: _phase(d) == "choice")
            left = browser.find_element(By.ID, "choice-left").text
            right = browser.find_element(By.ID, "choice-right").text
            expected = [stim["true_class"], stim["target"]]
            assert [left, right] == (expected if trial["true_first"] else expected[::-1])
            assert f"Trial {i + 1} of 6" in browser.find_element(By.ID, "progress-text").text
            assert not browser.find_element(By.ID, "stimulus").is_displayed()
            if stim["kind"] == "attention":  # an attentive participant: the written word
                keys[i] = "f" if trial["true_first"] else "j"
            if i < len(keys):
                ActionChains(browser).send_keys(keys[i]).perform()
            else:  # the last answer by mouse, on the true class
                browser.find_element(By.ID, "choice-left" if trial["true_first"] else "choice-right").click()
        _wait(browser, lambda d: _phase(d) == "done")
        answers = browser.execute_script("return window.STUDY_STATE.answers")
        watched = browser.execute_script("return window.WATCHED")
        assert len(answers) == 6
        assert [a["image_id"] for a in answers] == [t["image_id"] for t in trials]
        sides = [{"f": "left", "1": "left", "j": "right", "2": "right"}[k] for k in keys]
        assert [a["chosen_side"] for a in answers[:5]] == sides and answers[5]["input"] == "mouse"
        assert answers[5]["correct"] and answers[0]["input"] == f"key:{keys[0]}"
        assert {a["true_first"] for a in answers} == {True, False}  # both orders occur
        for a in answers:
            assert a["correct"] == (a["choice"] == a["true_class"])
            # stopped on the frame nearest 2 s: at most half a frame early; late by one slow frame at most
            assert EXPOSURE_MS - a["frame_ms"] / 2 - 1.0 <= a["exposure_ms"] <= EXPOSURE_MS + 50.0, a
            assert a["fixation_ms"] >= 290 and a["rt_ms"] > 0 and json.loads(a["query"])["workerId"] == "w7"
        # the observer's own frame times: the image was on screen 2 s each time
        ons = [t for e, t in watched if e == "on"]
        offs = [t for e, t in watched if e == "off"]
        assert len(ons) == len(offs) == 6
        for on, off in zip(ons, offs):
            assert abs((off - on) - EXPOSURE_MS) <= 50.0, (on, off)
        # the answers were POSTed to the configured URL
        _wait(browser, lambda d: "were sent" in d.find_element(By.ID, "post-status").text)
        posted = json.loads(_Collector.bodies[-1])
        assert posted["participant"] == 0 and len(posted["answers"]) == 6
    browser.find_element(By.ID, "download-csv").click()
    browser.find_element(By.ID, "download-json").click()
    stem = f"answers_{plan['settings']['study_id']}_p0"
    files = [browser.downloads / f"{stem}.csv", browser.downloads / f"{stem}.json"]
    _wait(browser, lambda d: all(f.is_file() for f in files))
    assert study.counts()["adversarial"] == 9
    app = typer.Typer()
    study_cmd.register(app)
    res = CliRunner().invoke(app, ["study", "analyze", *map(str, files), "-o", str(tmp_path / "analysis")])
    assert res.exit_code == 0, res.output
    summary = json.loads((tmp_path / "analysis" / "summary.json").read_text())
    adversarial = [a for a in answers if a["kind"] == "adversarial"]
    assert summary["answers_read"] == 6 and summary["sessions"] == 1  # the CSV and the JSON counted once
    assert summary["adversarial"][0]["answers"] == len(adversarial)
    assert summary["adversarial"][0]["mean"] == pytest.approx(sum(a["correct"] for a in adversarial) / len(adversarial))
    assert summary["dropped_attention"] == 0 and all(a["correct"] for a in answers if a["kind"] == "attention")
    assert abs(summary["exposure"]["mean_ms"] - EXPOSURE_MS) < 20.0


class _FormCollector(BaseHTTPRequestHandler):
    """Records form POSTs (a crowdsourcing site's external-submit URL) and answers with a small page."""

    forms: List[Dict[str, List[str]]] = []

    def do_POST(self) -> None:  # noqa: N802 - http.server's naming
        body = self.rfile.read(int(self.headers.get("Content-Length", 0))).decode()
        self.forms.append(parse_qs(body))
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.end_headers()
        self.wfile.write(b"<html><body id='received'>received</body></html>")

    def log_message(self, *args: Any) -> None:
        pass


def test_random_participant_form_post_and_inattentive_participant(browser: Any, tmp_path: Path) -> None:
    with _serving(_FormCollector) as base_url:
        db = make_study_db(tmp_path / "sweep")
        url = f"{base_url}/externalSubmit"
        export_study(db, tmp_path / "study", per_image=1, max_trials=4, attention_checks=1, seed=1, post_url=url,
                     post_mode="form", exposure_ms=200, fixation_ms=50)
        plan = json.loads((tmp_path / "study" / "plan.json").read_text())
        browser.get((tmp_path / "study" / "index.html").as_uri() + "?assignmentId=A1")
        _wait(browser, lambda d: _phase(d) == "ready")
        state = browser.execute_script("return window.STUDY_STATE")
        assert state["source"] == "random" and 0 <= state["participant"] < len(plan["participants"])
        assert "picked at random" in browser.find_element(By.ID, "participant-line").text
        trials = plan["participants"][state["participant"]]["trials"]
        browser.find_element(By.ID, "start").click()
        for trial in trials:
            _wait(browser, lambda d: _phase(d) == "choice")
            stim = plan["stimuli"][trial["image_id"]]
            wrong_left = not trial["true_first"]
            if stim["kind"] == "attention":  # this participant fails the attention check
                ActionChains(browser).send_keys("f" if wrong_left else "j").perform()
            else:
                ActionChains(browser).send_keys("1" if trial["true_first"] else "2").perform()
        _wait(browser, lambda d: d.find_elements(By.ID, "received"))  # the form left the page for the site
    form = _FormCollector.forms[-1]
    assert form["assignmentId"] == ["A1"]
    posted = json.loads(form["answers"][0])
    assert len(posted["answers"]) == len(trials) and posted["participant_source"] == "random"
    (tmp_path / "answers.json").write_text(json.dumps(posted))
    (tmp_path / "attentive.json").write_text(json.dumps([{**a, "session": "other", "correct": True}
                                                         for a in posted["answers"]]))
    app = typer.Typer()
    study_cmd.register(app)
    res = CliRunner().invoke(app, ["study", "analyze", str(tmp_path / "answers.json"), str(tmp_path / "attentive.json"),
                                   "-o", str(tmp_path / "analysis")])
    assert res.exit_code == 0, res.output
    assert "1 dropped for attention checks" in res.output
    summary = json.loads((tmp_path / "analysis" / "summary.json").read_text())
    assert summary["sessions"] == 2 and summary["adversarial"][0]["participants"] == 1
