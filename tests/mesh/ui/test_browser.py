"""The web page in headless Chromium (driven through chromedriver's W3C WebDriver HTTP API with httpx).

It loads the page from the UI agent of the real test mesh at common screen sizes and finds the
chat box on screen without scrolling, asks it a question and sees the answer, reads the "Now"
panel (cooling PUE, tower approach, the wet bulb's label) and each CDU's measured supply beside
its setpoint, checks the power axis never goes below 0 kW, holds the plant and sees the decision
feed count the unchanged steps on one row instead of adding a row per step (and show the LLM's
text of a step the row joined, labelled with its step), switches the
controller with the token, and takes a screenshot (to ``$LCMESH_UI_SCREENSHOT`` when set, which
is how docs/img/ui.png is made). Every wait polls the page; nothing is timed. Skipped with the
reason when Chromium or chromedriver is absent.
"""

from __future__ import annotations

import base64
import json
import os
import re
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

    def size(self, width: int, height: int) -> None:
        self._value(self.http.post("/window/rect", json={"width": width, "height": height}))

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


def _on_screen(b: Browser, css: str) -> bool:
    """`css` lies wholly inside the viewport as the page is, without scrolling."""
    return b.js(f"const r = document.querySelector({json.dumps(css)}).getBoundingClientRect(); "
                "return window.scrollX === 0 && window.scrollY === 0 && r.width > 0 && r.height > 0 && "
                "r.top >= 0 && r.left >= 0 && r.bottom <= window.innerHeight && r.right <= window.innerWidth;")


def _answers(b: Browser) -> list[str]:
    return b.js("return [...document.querySelectorAll('.chat-answer')].map((e) => e.className + '|' + e.textContent)")


def _ask(b: Browser, question: str) -> str:
    """Type `question` into the chat box, send it, and return the answer the page shows."""
    before = len(_answers(b))
    b.type("#chat-input", question)
    b.click("#chat-send")
    assert wait_until(lambda: len(_answers(b)) > before, 20), f"no answer on the page to {question!r}"
    kind, text = _answers(b)[before].split("|", 1)
    assert "error" not in kind and text.strip(), text
    return text


def _rows(b: Browser, css: str) -> list[list[str]]:
    return b.js(f"return [...document.querySelectorAll({json.dumps(css)})].map((tr) => [...tr.cells]"
                ".map((td) => td.textContent))")


def _shot(b: Browser, tmp_path: Path) -> None:
    shot = tmp_path / "ui.png"
    b.screenshot(shot)
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 20_000
    target = os.environ.get("LCMESH_UI_SCREENSHOT")
    if target:
        Path(target).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(shot, target)


def test_the_page_follows_the_plant_with_the_chat_on_screen(browser, ui_mesh, tmp_path):
    b = browser
    b.size(1366, 768)
    b.go(ui_mesh.url + "/")
    first = wait_until(lambda: _step(b), 20)
    assert first is not None, "the step counter never filled"
    assert wait_until(lambda: (_step(b) or 0) > first + 3, 20), "the live page does not follow the plant"
    assert b.text("#conn") == "live"
    for width, height in ((1366, 768), (1920, 1080)):
        b.size(width, height)
        assert wait_until(lambda: _on_screen(b, "#chat-input") and _on_screen(b, "#chat-send"), 5), (width, height)
    assert re.search(r"cabinet \d", _ask(b, "which cabinet runs hottest?"))
    _ask(b, "what if I raise the dp setpoint 2 psi?")
    assert wait_until(lambda: "/api/control/" in b.js("return document.querySelector('.command code')?.textContent "
                                                       "|| ''"), 5), "a what-if offers a command to confirm"
    assert _on_screen(b, "#chat-input"), "answers scroll inside the chat, the box stays put"
    why = _ask(b, "explain the last decision")  # the reasons read as sentences, not markdown
    assert "#" not in why and "**" not in why and "EXPLANATION" not in why, why
    assert re.search(r"“Cabinet \d\. ", why), why

    assert "°C (cabinet" in b.text("#hottest")
    assert wait_until(lambda: b.js("return document.querySelectorAll('#agents tbody tr').length") >= 5, 10)
    assert b.js("return series.blades.size") >= 5 and b.js("return series.power.get('tower fans').length") > 3
    assert float(b.js("return document.getElementById('plot-power').dataset.ymin")) >= 0, "power is never < 0 kW"

    # the live page fills the new "Now" rows and the supply table; then one known state, shown as it comes
    assert wait_until(lambda: re.fullmatch(r"1\.\d{3}", b.text("#pue")) and len(_rows(b, "#supply tbody tr")) == 5, 5)
    assert _rows(b, "#supply thead tr") == [["cabinet", "measured", "setpoint", "off (K)", "hottest blade"]]
    state = httpx.get(ui_mesh.url + "/api/state", timeout=10).json()
    shown = b.js(f"onState({json.dumps(state)}); const text = (id) => document.getElementById(id).textContent; "
                 "return [text('pue'), text('approach'), text('wet-bulb'), [...document.querySelectorAll("
                 "'#supply tbody tr')].map((tr) => [...tr.cells].map((td) => td.textContent))];")
    pue, approach, wet_bulb, supply = shown
    assert float(pue) == pytest.approx(state["totals"]["cooling_pue"], abs=6e-4) and 1.0 < float(pue) < 1.5
    towers = re.fullmatch(r"tower 1: (\d+\.\d) K · tower 2: (\d+\.\d) K", approach)
    assert towers and [float(v) for v in towers.groups()] == pytest.approx([t["approach_k"] for t in state["towers"]],
                                                                            abs=0.051)  # fmt: skip
    assert re.fullmatch(r"\d+\.\d °C", wet_bulb), "the recorded weather needs no label"
    assert [r[0] for r in supply] == [str(c["cabinet"]) for c in state["cabinets"]]
    shown_supply = [[float(r[1]), float(r[2])] for r in supply]
    assert shown_supply == [pytest.approx([c["supply_temp_measured_c"], c["supply_setpoint_c"]], abs=0.051)
                            for c in state["cabinets"]], "each measured supply beside its setpoint"  # fmt: skip
    _shot(b, tmp_path)
    shifted = {**state, "wet_bulb_c": 24.1, "wet_bulb_note": "recorded + 15 K, scenario lcopt"}
    label = b.js(f"onState({json.dumps(shifted)}); return document.getElementById('wet-bulb').textContent")
    assert label == "24.1 °C (recorded + 15 K, scenario lcopt)"


def test_the_decision_feed_says_what_changed_and_counts_unchanged_steps(browser, ui_mesh):
    b = browser
    b.go(ui_mesh.url + "/")
    assert wait_until(lambda: b.js("return decisionsSeen") >= 3, 20)
    said = b.js("return [...document.querySelectorAll('#decisions li .change')].map((e) => e.textContent)")
    words = r"(no change|supply setpoint|dp setpoint|leaving-water|cabinet [1-9]|tower [1-9]|\d+ more)"
    assert said and all(re.fullmatch(f"{words}.*", t) for t in said), said  # numbered from 1
    labels = "return [...document.querySelectorAll('#decisions li details summary')].map((e) => e.textContent)"
    assert wait_until(lambda: b.js(labels), 20)
    assert set(b.js(labels)) == {"explanation (rendered from the facts)"}, "each text says who wrote it"

    # hold the plant: every step applies the same action, so the feed has nothing new to say
    b.type("#token", ui_mesh.token)
    b.js("document.getElementById('mode-select').value = 'manual';")
    b.click("#apply-mode")
    try:
        assert wait_until(lambda: "manual" in b.text("#mode-result"), 10), b.text("#mode-result")
        top = "document.querySelector('#decisions li')"
        assert wait_until(lambda: b.js(f"return {top}?.dataset.count") not in (None, "1", "2"), 20)
        rows, seen = b.js("return document.querySelectorAll('#decisions li').length"), b.js("return decisionsSeen")
        assert wait_until(lambda: b.js("return decisionsSeen") >= seen + 12, 20)
        assert b.js("return document.querySelectorAll('#decisions li').length") == rows, "a row per unchanged step"
        tags = b.js(f"return [...{top}.querySelectorAll('.tag')].map((e) => e.textContent)")
        assert re.fullmatch(r"steps \d+–\d+", tags[0]) and re.fullmatch(r"×\d+", tags[1]), tags
        assert tags[2].startswith("manual"), tags
        assert b.js(f"return {top}.querySelector('.change').textContent") == "no change on these steps"
        assert b.js("const li = [...document.querySelectorAll('#decisions li.unchanged')]; return li.every((e, i) => "
                    "i === 0 || e.previousElementSibling !== li[i - 1] || e.dataset.key !== li[i - 1].dataset.key)")

        # A joined row of a controller's unchanged steps (the page's own functions, fed events as the stream sends
        # them, in one script so that no live event comes between): the LLM's text for an earlier step shows in
        # the row, labelled with its step, and the renderings of later steps that join the row do not hide it.
        def decision(i):
            return {"decision_id": f"joined-{i}", "step": 900000 + i, "source_controller": "tree",
                    "source_version": "test", "fallback": False, "fallback_reason": None, "clamps": [], "changes": []}

        def rendering(i):
            return {"decision_id": f"joined-{i}", "text": f"rendering {i}", "written_by": "renderer", "level": "short"}

        shown = "(() => { const li = document.querySelector('#decisions li[data-members~=\"joined-1\"]'); " \
                "return [li.dataset.count, li.querySelector('summary').textContent, li.querySelector('pre').textContent]; })()"
        by_llm = {"decision_id": "joined-1", "text": "## WHAT IF\nchecked", "written_by": "llm", "llm_part": "what-if"}
        add = [f"addDecision({json.dumps(decision(i))}); addExplanation({json.dumps(rendering(i))});" for i in range(4)]
        seen = b.js("".join(add[:3]) + f"const a = {shown}; addExplanation({json.dumps(by_llm)}); const b = {shown}; "
                    + add[3] + f"return [a, b, {shown}];")  # fmt: skip
        want = "explanation of step 900001 (rendered from the facts; WHAT IF written by the LLM, checked)"
        assert seen[0] == ["3", "explanation (rendered from the facts)", "rendering 2"]
        assert seen[1] == ["3", want, "## WHAT IF\nchecked"]
        assert seen[2] == ["4", want, "## WHAT IF\nchecked"], "a later step's rendering hides the LLM's text"
        stray = {**by_llm, "decision_id": "in-no-row"}
        assert b.js(f"addExplanation({json.dumps(stray)}); return 1") == 1, "a text for a row no longer shown"

        b.js("document.getElementById('controller-select').value = 'g36'; "
             "document.getElementById('mode-select').value = 'auto';")  # fmt: skip
        b.click("#apply-mode")
        assert wait_until(lambda: "g36, auto" in b.text("#mode-result"), 10), b.text("#mode-result")
    finally:  # the session's mesh goes on running G36 for the tests after this one, whatever happened here
        with ui_mesh.client() as http:
            if http.get("/api/config").json()["config"]["mode"] != "auto":
                http.post("/api/control/mode", json={"controller": "g36", "mode": "auto"}, headers=ui_mesh.auth())
