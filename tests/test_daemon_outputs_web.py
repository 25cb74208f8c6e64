"""``--web``: the live page in a real headless Chromium (Debian's chromium and
chromium-driver), fed by the daemon's event stream; the screenshot is kept.

Skipped, saying why, where chromium, chromedriver or selenium is missing
(``scripts/setup`` installs them when run as root).
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import threading
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from scotti.daemon.frames.pipeline import Prediction
from scotti.daemon.mqtt import messages
from scotti.models.contract import ACTIONS, NO_ACTION

from tests.support.outputs import predictions
from tests.support.sessions import write_synthetic_session

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")


class LiveView:
    """A ``WebOutput`` on its own event loop thread, fed like the daemon feeds it."""

    def __init__(self, devices: tuple[str, ...] = ("scotti",)) -> None:
        from scotti.daemon.outputs.web import WebOutput

        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        start = WebOutput.start("127.0.0.1", 0, devices)
        self.output = asyncio.run_coroutine_threadsafe(start, self.loop).result(5)
        self.url = f"http://127.0.0.1:{self.output.port}/"

    def send(self, p: Prediction | None = None, status: Any = None, device: str = "scotti") -> None:
        def call() -> None:
            if p is not None:
                self.output.prediction(device, p, 4.2)
            if status is not None:
                self.output.status(device, status)

        self.loop.call_soon_threadsafe(call)

    def watched(self, *devices: str) -> None:
        """Until the server's process has told the daemon these devices have readers (the
        daemon renders a device's frames only then)."""
        indices = {self.output.devices.index(d) for d in devices}
        assert self.output.front.wait_for(lambda f: indices <= f.watched, 10)

    def close(self) -> None:
        asyncio.run_coroutine_threadsafe(self.output.close(), self.loop).result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()


@pytest.fixture(scope="module")
def preds(tmp_path_factory: pytest.TempPathFactory, tiny_model_path: Path) -> list[Prediction]:
    session = write_synthetic_session(tmp_path_factory.mktemp("web") / "s.scotti", frames=60)
    return predictions(session.path, tiny_model_path)


@pytest.fixture
def view() -> Iterator[LiveView]:
    live = LiveView()
    yield live
    live.close()


def test_page_and_feed_over_plain_http(view: LiveView, preds: list[Prediction]) -> None:
    with urllib.request.urlopen(view.url, timeout=5) as page:
        html = page.read().decode()
    assert "EventSource" in html
    assert "http://" not in html.split("<script>")[1]  # nothing from a CDN
    with urllib.request.urlopen(view.url + "events", timeout=5) as feed:
        hello = json.loads(feed.readline().removeprefix(b"data: "))
        assert hello["actions"] == list(ACTIONS)
        feed.readline()
        view.watched("scotti")  # the server's process has told the daemon of its reader
        view.send(preds[0])
        frame = json.loads(feed.readline().removeprefix(b"data: "))
    assert frame["seq"] == preds[0].seq
    assert len(frame["left"]) == len(frame["right"]) == frame["rows"] * frame["cols"]
    with pytest.raises(urllib.error.HTTPError, match="404"):
        urllib.request.urlopen(view.url + "nothing", timeout=5)


@pytest.fixture
def two() -> Iterator[LiveView]:
    live = LiveView(("a", "b"))
    yield live
    live.close()


def _event(feed: Any) -> dict[str, Any]:
    line = feed.readline()
    while line == b"\n":  # the blank line that ends each event
        line = feed.readline()
    return json.loads(line.removeprefix(b"data: "))  # type: ignore[no-any-return]


def test_two_devices_one_server_a_page_and_a_feed_each(
    two: LiveView, preds: list[Prediction]
) -> None:
    two.send(status=messages.status("degraded", ["left insole silent"], None), device="b")
    with urllib.request.urlopen(two.url + "devices", timeout=5) as listing:
        devices = json.load(listing)
    assert [d["id"] for d in devices] == ["a", "b"]
    assert devices[1]["state"] == "degraded"
    assert devices[1]["view"] == "/devices/b/"
    with urllib.request.urlopen(two.url, timeout=5) as index:  # the list, linking each view
        html = index.read().decode()
    assert 'href="/devices/a/"' in html
    assert "left insole silent" in html
    with urllib.request.urlopen(two.url + "devices/b", timeout=5) as page:  # redirected
        assert page.url.endswith("/devices/b/")
        assert "EventSource" in page.read().decode()
    with (
        urllib.request.urlopen(two.url + "devices/a/events", timeout=5) as feed_a,
        urllib.request.urlopen(two.url + "devices/b/events", timeout=5) as feed_b,
    ):
        hello = _event(feed_a)
        assert (hello["device"], hello["devices"]) == ("a", ["a", "b"])  # the chooser's
        assert _event(feed_b)["device"] == "b"
        assert _event(feed_b)["state"] == "degraded"  # b's status, to b's new client
        two.watched("a", "b")  # both clients registered before the frames go out
        for to_a, to_b in zip(preds[:3], preds[3:6], strict=True):
            two.send(to_a, device="a")
            two.send(to_b, device="b")
        for p in preds[6:9]:  # then b falls silent: a's frames go on alone
            two.send(p, device="a")
        two.send(status=messages.status("online", [], None), device="b")  # b's next event
        got_a = [_event(feed_a) for _ in range(6)]
        got_b = [_event(feed_b) for _ in range(4)]
    expected_a = [("a", p.seq) for p in preds[:3] + preds[6:9]]
    assert [(e["device"], e["seq"]) for e in got_a] == expected_a
    assert [(e["device"], e["seq"]) for e in got_b[:3]] == [("b", p.seq) for p in preds[3:6]]
    assert (got_b[3]["type"], got_b[3]["state"]) == ("status", "online")  # none of a's
    with pytest.raises(urllib.error.HTTPError, match="404"):  # several: no lone feed
        urllib.request.urlopen(two.url + "events", timeout=5)
    with pytest.raises(urllib.error.HTTPError, match="404"):
        urllib.request.urlopen(two.url + "devices/c/", timeout=5)


def test_a_lone_device_is_also_under_its_id(view: LiveView, preds: list[Prediction]) -> None:
    with urllib.request.urlopen(view.url + "devices/scotti/events", timeout=5) as feed:
        hello = _event(feed)
        assert (hello["device"], hello["devices"]) == ("scotti", ["scotti"])
        view.watched("scotti")
        view.send(preds[0])
        assert _event(feed)["seq"] == preds[0].seq


def test_stopping_with_a_client_behind_ends_its_feed(
    view: LiveView, preds: list[Prediction]
) -> None:
    """Frames go out faster than the client reads, then the daemon stops: the feed ends
    (the read returns), in order, with the newest frame last."""

    async def flood_then_stop() -> None:
        for p in preds:  # on the loop, in one go: the client has not read any of them
            view.output.prediction("scotti", p, 4.2)
        await view.output.close()  # the daemon stops now, with the client behind

    with urllib.request.urlopen(view.url + "events", timeout=5) as feed:
        assert _event(feed)["type"] == "hello"
        view.watched("scotti")  # the client registered before the frames go out
        asyncio.run_coroutine_threadsafe(flood_then_stop(), view.loop).result(10)
        rest = feed.read()  # to the end of the stream: the server ended it
    seqs = [
        json.loads(e.strip().removeprefix(b"data: "))["seq"]
        for e in rest.split(b"\n\n")
        if e.strip()
    ]
    assert seqs[-1] == preds[-1].seq  # the newest, then the end
    assert seqs == sorted(seqs)


@pytest.mark.skipif(not (CHROMIUM and CHROMEDRIVER), reason="needs chromium and chromium-driver")
def test_live_view_in_headless_chromium(
    view: LiveView, preds: list[Prediction], tmp_path: Path
) -> None:
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.support.ui import WebDriverWait

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1400,800"):  # fmt: skip
        options.add_argument(arg)
    driver = webdriver.Chrome(options=options, service=webdriver.ChromeService(CHROMEDRIVER))
    try:
        driver.get(view.url)
        WebDriverWait(driver, 10).until(lambda d: d.find_element("id", "conn").text == "live")
        view.watched("scotti")
        view.send(status=messages.status("online", [], None))
        shown = preds[-1]
        for p in preds[-20:]:  # a second of frames, the last one stays on screen
            view.send(p)
            time.sleep(0.02)
        WebDriverWait(driver, 10).until(
            lambda d: d.find_element("id", "seq").text == str(shown.seq)
        )
        text = {k: driver.find_element("id", k).text
                for k in ("action", "confidence", "repetition", "status", "latency")}  # fmt: skip
        name = "none" if shown.action == NO_ACTION else ACTIONS[shown.action].replace("_", " ")
        assert text["action"] == name
        assert text["repetition"] == str(max(0, shown.repetition))
        assert text["status"] == "online"
        assert text["latency"] == "4.2 ms"
        # The colour scale runs from viridis' dark purple (0 counts) to its yellow (full).
        bar = driver.execute_script(
            "const g = document.getElementById('pressure').getContext('2d');"
            "return [18, 18 + 32*8 - 1]"
            "  .map(y => Array.from(g.getImageData(2*22*8+34, y, 1, 1).data));"
        )
        assert all(abs(a - b) <= 4 for a, b in zip(bar[0], (253, 231, 37), strict=False))
        assert all(abs(a - b) <= 4 for a, b in zip(bar[1], (68, 1, 84), strict=False))
        # Dragging turns the skeleton: the canvas is drawn anew from another angle.
        before = driver.execute_script("return document.getElementById('skeleton').toDataURL()")
        canvas = driver.find_element("id", "skeleton")
        webdriver.ActionChains(driver).drag_and_drop_by_offset(canvas, 80, 0).perform()
        after = driver.execute_script("return document.getElementById('skeleton').toDataURL()")
        assert after != before
        shot = Path(os.environ.get("SCOTTI_WEB_SCREENSHOT", tmp_path / "web-view.png"))
        assert driver.save_screenshot(str(shot))
        assert shot.stat().st_size > 10_000
    finally:
        driver.quit()
