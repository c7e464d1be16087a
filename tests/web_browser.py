"""Drives the operator page in headless Chromium through chromedriver (W3C WebDriver over plain
HTTP, no client library) while a demo build runs; tests/web.rs starts the build and runs this.

usage: web_browser.py PAGE_URL CHROMEDRIVER SCREENSHOT_PNG

Checks that the shown layer number advances without a reload, that a picture of the newest
layer loads, that a click on an earlier layer in the timeline shows that layer, and keeps a
screenshot.
"""
import base64
import json
import re
import socket
import subprocess
import sys
import time
import urllib.request

page, chromedriver, screenshot = sys.argv[1:4]


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


port = free_port()
driver = subprocess.Popen([chromedriver, f"--port={port}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
base = f"http://127.0.0.1:{port}"


def call(method, path, body=None):
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(base + path, data=data, method=method, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(request, timeout=60) as r:
            return json.loads(r.read())["value"]
    except urllib.error.HTTPError as e:
        raise RuntimeError(f"{method} {path}: {e.code} {e.read()[:500]!r}") from None


def wait_for(what, check, timeout=30.0):
    deadline = time.time() + timeout
    while True:
        value = check()
        if value:
            return value
        if time.time() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.1)


for _ in range(100):
    try:
        urllib.request.urlopen(base + "/status", timeout=1)
        break
    except OSError:
        time.sleep(0.1)

session = None
try:
    args = ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1400,1000"]
    caps = {"capabilities": {"alwaysMatch": {"browserName": "chrome", "goog:chromeOptions": {"args": args}}}}
    session = call("POST", "/session", caps)["sessionId"]
    s = f"/session/{session}"

    def js(script, *arguments):
        return call("POST", s + "/execute/sync", {"script": script, "args": list(arguments)})

    call("POST", s + "/url", {"url": page})
    loaded_at = wait_for("the page script", lambda: js("return window.layerwisePageLoadedAt"))
    shown = lambda: js("const t = document.getElementById('layer-number').textContent; return /^\\d+$/.test(t) ? Number(t) : 0")
    first = wait_for("a layer number", shown)
    advanced = wait_for("the layer number to advance", lambda: shown() > first and shown())
    assert js("return window.layerwisePageLoadedAt") == loaded_at, "the page was reloaded"
    print(f"layer {first} then {advanced} without a reload")

    # A picture of the layer shown (the newest, following the build) loads.
    def newest_picture():
        return js("""
            const n = document.getElementById('layer-number').textContent;
            const imgs = [...document.querySelectorAll('#views img')];
            return imgs.some(i => i.dataset.layer === n && i.complete && i.naturalWidth > 0) && n;""")
    n = wait_for("a picture of the newest layer", newest_picture)
    print(f"picture of layer {n} loaded")

    # A click on an earlier layer of the timeline shows that layer.
    # The timeline is redrawn as layers arrive: a cell found just before a redraw is stale by the
    # click, so find it again and click again (a person's click lands on the redrawn cell).
    for attempt in range(20):
        try:
            cell = call("POST", s + "/element", {"using": "css selector", "value": '#timeline .cell[data-layer="2"]'})
            call("POST", s + f"/element/{list(cell.values())[0]}/click", {})
            break
        except RuntimeError as e:
            if "stale element" not in str(e) or attempt == 19:
                raise
            time.sleep(0.05)
    wait_for("layer 2 to be shown", lambda: shown() == 2)
    wait_for("a picture of layer 2", lambda: js("""
        const imgs = [...document.querySelectorAll('#views img')];
        return imgs.length > 0 && imgs.every(i => i.dataset.layer === '2') && imgs.some(i => i.complete && i.naturalWidth > 0);"""))
    print("layer 2 shown after a click on the timeline")

    # Health in the daemon's words (the same as `layerwise status`): the trigger's last signal is
    # seconds old while signals arrive, and every part has its line.
    def health(part):
        return js("""
            const dt = [...document.querySelectorAll('#health dt')].find(d => d.textContent === arguments[0]);
            return dt ? dt.nextElementSibling.textContent : '';""", part)
    trigger = wait_for("the trigger's last signal in the health panel", lambda: re.search(r"last signal \d+ s ago", health("trigger")) and health("trigger"))
    for part in ["camera", "lights", "processing", "disk"]:
        assert health(part), f"no {part} line in the health panel"
    assert "switching" in health("lights"), health("lights")
    assert "rest of build needs" in health("disk"), health("disk")
    print(f"health: trigger {trigger!r}, lights {health('lights')!r}")
    # Back to the newest complete layer (End), then stay there for the screenshot: on a loaded
    # machine the build may move on faster than six pictures load.
    js("document.dispatchEvent(new KeyboardEvent('keydown', {key: 'End'}))")
    wait_for("the newest layer again", lambda: shown() > 2)
    js("document.getElementById('follow').click()")
    wait_for("all pictures of the layer shown", lambda: js("""
        const n = document.getElementById('layer-number').textContent;
        const imgs = [...document.querySelectorAll('#views img')];
        return imgs.length === 6 && imgs.every(i => i.dataset.layer === n && i.complete && i.naturalWidth > 0);"""), 90)
    js("window.scrollTo(0, 0)")
    time.sleep(0.5)
    png = base64.b64decode(call("GET", s + "/screenshot"))
    with open(screenshot, "wb") as f:
        f.write(png)
    print(f"screenshot {screenshot} ({len(png)} bytes)")
finally:
    if session:
        try:
            call("DELETE", f"/session/{session}")
        except Exception:
            pass
    driver.terminate()
    driver.wait(10)
