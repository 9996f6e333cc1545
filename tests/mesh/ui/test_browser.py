"""The web page in headless Chromium (driven through chromedriver's W3C WebDriver HTTP API with httpx).

It loads the page from the UI agent of the real test mesh, sees the step counter and the plots
move with the plant, asks the chat a question and gets an answer with facts, switches the
controller with the token, and takes a screenshot (to ``$LCMESH_UI_SCREENSHOT`` when set, which
is how docs/img/ui.png is made). Skipped with the reason when Chromium or chromedriver is absent.
"""

from __future__ import annotations

import base64
import os
import shutil
import subprocess
from pathlib import Path

import httpx
import pytest

from tests.mesh.conftest import free_port, wait_until

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
DRIVER = shutil.which("chromedriver")
ELEMENT = "element-6066-11e4-a52e-4f735466cecf"

pytestmark = pytest.mark.skipif(CHROMIUM is None or DRIVER is None,
                                reason="headless browser test needs chromium and chromedriver on PATH")  # fmt: skip


class Browser:
    """A small W3C WebDriver client: navigate, find, type, click, run a script, screenshot."""

    def __init__(self, base: str, session: str):
        self.http = httpx.Client(base_url=f"{base}/session/{session}", timeout=30.0)

    def _value(self, response: httpx.Response):
        body = response.json()
        if response.status_code != 200:
            raise AssertionError(f"webdriver: {body.get('value', body)}")
        return body["value"]

    def go(self, url: str) -> None:
        self._value(self.http.post("/url", json={"url": url}))

    def find(self, css: str) -> str:
        return self._value(self.http.post("/element", json={"using": "css selector", "value": css}))[ELEMENT]

    def text(self, css: str) -> str:
        return self._value(self.http.get(f"/element/{self.find(css)}/text"))

    def type(self, css: str, text: str) -> None:
        self._value(self.http.post(f"/element/{self.find(css)}/value", json={"text": text}))

    def click(self, css: str) -> None:
        self._value(self.http.post(f"/element/{self.find(css)}/click", json={}))

    def js(self, script: str):
        return self._value(self.http.post("/execute/sync", json={"script": script, "args": []}))

    def screenshot(self, path: Path) -> None:
        path.write_bytes(base64.b64decode(self._value(self.http.get("/screenshot"))))


@pytest.fixture
def browser():
    port = free_port()
    driver = subprocess.Popen([DRIVER, f"--port={port}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    session = None
    try:
        assert wait_until(lambda: _ready(base), 20), "chromedriver did not start"
        caps = {"capabilities": {"alwaysMatch": {"browserName": "chrome", "goog:chromeOptions": {
            "binary": CHROMIUM,
            "args": ["--headless=new", "--no-sandbox", "--disable-background-networking", "--disable-gpu",
                     "--disable-dev-shm-usage", "--window-size=1400,1700"]}}}}  # fmt: skip
        r = httpx.post(f"{base}/session", json=caps, timeout=60.0)
        assert r.status_code == 200, r.text
        session = r.json()["value"]["sessionId"]
        yield Browser(base, session)
    finally:
        if session is not None:
            try:
                httpx.delete(f"{base}/session/{session}", timeout=20.0)
            except httpx.HTTPError:
                pass
        driver.terminate()
        try:
            driver.wait(10)
        except subprocess.TimeoutExpired:
            driver.kill()
            driver.wait(5)


def _ready(base: str) -> bool:
    try:
        return httpx.get(f"{base}/status", timeout=1.0).json()["value"]["ready"]
    except (httpx.HTTPError, ValueError, KeyError):
        return False


def _step(b: Browser) -> int | None:
    text = b.text("#step")
    return int(text) if text.isdigit() else None


def test_the_page_shows_live_values_answers_chat_and_switches_controller(browser, ui_mesh, tmp_path):
    b = browser
    b.go(ui_mesh.url + "/")
    first = wait_until(lambda: _step(b), 20)
    assert first is not None, "the step counter never filled"
    assert wait_until(lambda: (_step(b) or 0) > first + 3, 20), "the live page does not follow the plant"
    assert b.text("#conn") == "live"
    assert "°C (cabinet" in b.text("#hottest")
    assert wait_until(lambda: b.js("return document.querySelectorAll('#agents tbody tr').length") >= 5, 10)
    assert wait_until(lambda: b.js("return document.querySelectorAll('#decisions li').length") >= 3, 10)
    assert b.js("return series.blades.size") >= 5 and b.js("return series.power.get('tower fans').length") > 3

    b.type("#chat-input", "which cabinet runs hottest?")
    b.click("#chat-send")
    assert wait_until(lambda: b.js("return document.querySelectorAll('.chat-answer .answer-text').length") >= 1, 15)
    answer = b.js("return document.querySelector('.chat-answer .answer-text').textContent")
    assert "runs hottest" in answer, answer
    facts = b.js("return document.querySelectorAll('.chat-answer .facts li').length")
    assert facts >= 3 and "°C" in b.js("return document.querySelector('.chat-answer .facts').textContent")

    b.type("#chat-input", "what if I raise the dp setpoint 2 psi?")
    b.click("#chat-send")
    assert wait_until(lambda: b.js("return document.querySelectorAll('.chat-answer .answer-text').length") >= 2, 20)
    assert "Look-ahead on the live twin" in b.js("return document.querySelectorAll('.chat-answer .answer-text')[1]"
                                                 ".textContent")  # fmt: skip
    assert "/api/control/setpoints" in b.text(".command code"), "the what-if offers a command to confirm"

    b.type("#token", ui_mesh.token)
    b.js("document.getElementById('controller-select').value = 'g36'; "
         "document.getElementById('mode-select').value = 'auto';")  # fmt: skip
    b.click("#apply-mode")
    assert wait_until(lambda: "g36, auto" in b.text("#mode-result"), 10), b.text("#mode-result")

    shot = tmp_path / "ui.png"
    b.screenshot(shot)
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 20_000
    target = os.environ.get("LCMESH_UI_SCREENSHOT")
    if target:
        Path(target).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(shot, target)
