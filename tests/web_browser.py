"""Drives the operator page in headless Chromium through chromedriver (W3C WebDriver over plain
HTTP, no client library) while a demo build runs; tests/it/web.rs starts the build and runs this.

usage: web_browser.py PAGE_URL CHROMEDRIVER SCREENSHOT_PNG [FLAGGED_LAYER VIEW X Y W H CLEAN_LAYER FLAG_PNG]

Checks that the shown layer number advances without a reload, that a picture of the newest
layer loads, that a click on an earlier layer in the timeline shows that layer, and keeps a
screenshot. With the optional arguments: on FLAGGED_LAYER an inspection flag is outlined over
VIEW at X Y W H (fractions of the rectified picture, from the injected anomaly's place), in
the small view, the large view and a crop; F hides the outlines; CLEAN_LAYER shows none; the
powder bed the inspection judged is outlined (faint, dashed) over the pre-scan views of
FLAGGED_LAYER, after the bed settled, and not over the post-scan ones nor on CLEAN_LAYER, before
it settled; a screenshot of the flagged layer is kept in FLAG_PNG.
"""
import base64
import json
import os
import re
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import webdriver  # noqa: E402
from webdriver import start  # noqa: E402

page, chromedriver, screenshot = sys.argv[1:4]
flagged = None
if len(sys.argv) > 4:
    flagged_layer, flagged_view = int(sys.argv[4]), sys.argv[5]
    expected = [float(v) for v in sys.argv[6:10]]
    clean_layer, flag_png = int(sys.argv[10]), sys.argv[11]
    flagged = True


driver, call = start(chromedriver)


def wait_for(what, check, timeout=30.0):
    return webdriver.wait_for(what, check, timeout, diagnosis)


def diagnosis():
    # What the page showed when a wait ran out: the layer, and each picture's state.
    try:
        return "\n" + json.dumps(js("""
            return {layer: document.getElementById('layer-number').textContent,
                    pictures: [...document.querySelectorAll('#views img')].map(i =>
                        [i.src.replace(location.origin, ''), i.complete, i.naturalWidth]),
                    outlines: document.querySelectorAll('.flag-box').length,
                    beds: document.querySelectorAll('.bed-outline').length};"""), indent=1)
    except Exception as e:  # no session yet
        return f" ({e})"



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

    def click(selector, timeout=30.0):
        # The page redraws as layers arrive: an element found just before a redraw is stale by
        # the click, so find it again and click again (a person's click lands on the redrawn one);
        # a layer the build has not reached yet has no cell until it arrives, so wait for it.
        deadline = time.time() + timeout
        while True:
            try:
                element = call("POST", s + "/element", {"using": "css selector", "value": selector})
                call("POST", s + f"/element/{list(element.values())[0]}/click", {})
                return
            except RuntimeError as e:
                waiting = "stale element" in str(e) or "no such element" in str(e)
                if not waiting or time.time() > deadline:
                    raise
                time.sleep(0.05)

    def click_layer(n):
        # The timeline's cells narrow as layers arrive: a redraw between finding a cell and the
        # pointer's click moves it, and the click lands on a neighbour; a person looks and
        # clicks again.
        for attempt in range(10):
            click(f'#timeline .cell[data-layer="{n}"]')
            try:
                wait_for(f"layer {n} shown after the click", lambda: shown() == n, timeout=2.0)
                return
            except AssertionError:
                if attempt == 9:
                    raise

    # A click on an earlier layer of the timeline shows that layer.
    click_layer(2)
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

    if flagged:
        # Where each outline sits on its picture, as fractions of the picture's shown size.
        boxes = """
            const [frame, flags] = arguments;
            const img = document.querySelector(frame + ' img');
            if (!img || !img.complete || !img.naturalWidth) return null;
            const p = img.getBoundingClientRect();
            return [...document.querySelectorAll(flags + ' .flag-box')].map(b => {
                const r = b.getBoundingClientRect();
                return {kind: b.dataset.kind, visible: b.offsetParent !== null, px: p.width,
                        box: [(r.left - p.left) / p.width, (r.top - p.top) / p.height, r.width / p.width, r.height / p.height]};
            });"""

        def near(found, want, px, what, scale=1.0):
            # The injected place within 2 mm (the inspection's cells) of the 275 mm plate, plus
            # two pixels of the picture as shown (px wide); scale: the crop's share of the plate.
            tolerance = 2.0 / 275 / scale + 2.0 / px
            assert all(abs(a - b) < tolerance for a, b in zip(found, want)), f"{what}: outline at {found}, anomaly at {want}"

        click_layer(clean_layer)
        wait_for(f"layer {clean_layer} shown", lambda: shown() == clean_layer and js(boxes, f'.tile[data-view="{flagged_view}"]', '#views') is not None)
        assert js("return document.querySelectorAll('.flag-box').length") == 0, "a clean layer has no outline"
        assert js("return document.querySelectorAll('.bed-outline').length") == 0, "no bed outline before the bed settled"
        click_layer(flagged_layer)
        tile = f'.tile[data-view="{flagged_view}"][data-layer="{flagged_layer}"]'
        found = wait_for(f"an outline over {flagged_view} of layer {flagged_layer}", lambda: shown() == flagged_layer and js(boxes, tile, tile))
        near(found[0]["box"], expected, found[0]["px"], "small view")
        others = js("return [...document.querySelectorAll('.tile')].filter(t => t.querySelector('.flag-box')).map(t => t.dataset.view)")
        assert others == [flagged_view], f"a part's flag is outlined over its own view only: {others}"
        # The powder bed: a dashed outline over each pre-scan view, most of the picture, inside it.
        beds = js("""
            return [...document.querySelectorAll('.tile')].map(t => {
                const line = t.querySelector('.bed-outline polygon'), img = t.querySelector('img');
                if (!line || !img) return [t.dataset.view, null];
                const p = img.getBoundingClientRect(), r = line.getBoundingClientRect();
                return [t.dataset.view, [(r.left - p.left) / p.width, (r.top - p.top) / p.height,
                    (r.right - p.left) / p.width, (r.bottom - p.top) / p.height,
                    getComputedStyle(line).strokeDasharray]];
            });""")
        outlined = [v for v, b in beds if b]
        assert outlined and outlined == [v for v, _ in beds if v.startswith("pre_")], f"the powder bed is outlined over the pre-scan views only: {beds}"
        for view, (x0, y0, x1, y1, dashes) in [(v, b) for v, b in beds if b]:
            assert -0.01 <= x0 < x1 <= 1.01 and -0.01 <= y0 < y1 <= 1.01 and x1 - x0 > 0.3 and y1 - y0 > 0.3, f"{view}: bed outline at {x0, y0, x1, y1}"
            assert dashes not in ("", "none"), f"{view}: the bed outline is dashed ({dashes!r})"
        print(f"layer {flagged_layer}: the powder bed outlined over {outlined} at {[round(v, 3) for v in dict(beds)[outlined[0]][:4]]}")
        print(f"layer {flagged_layer}: {found[0]['kind']} outlined over {flagged_view} at {[round(v, 4) for v in found[0]['box']]} (anomaly at {[round(v, 4) for v in expected]})")
        js("document.dispatchEvent(new KeyboardEvent('keydown', {key: 'f'}))")
        assert not js(boxes, tile, tile)[0]["visible"], "F hides the outlines"
        js("document.dispatchEvent(new KeyboardEvent('keydown', {key: 'f'}))")
        assert js(boxes, tile, tile)[0]["visible"], "F shows them again"
        js("window.scrollTo(0, 0)")
        time.sleep(0.5)
        with open(flag_png, "wb") as f:
            f.write(base64.b64decode(call("GET", s + "/screenshot")))
        # The large view, then a crop around the anomaly at full resolution: outlined in both.
        click(tile + " img")
        large = wait_for("the outline in the large view", lambda: js(boxes, ".zoom-frame", "#zoom-flags"))
        near(large[0]["box"], expected, large[0]["px"], "large view")
        rect = js("const r = document.getElementById('zoom-img').getBoundingClientRect(); return [r.left, r.top, r.width, r.height]")
        cx, cy = expected[0] + expected[2] / 2, expected[1] + expected[3] / 2
        actions = {"actions": [{"type": "pointer", "id": "mouse", "parameters": {"pointerType": "mouse"}, "actions": [
            {"type": "pointerMove", "origin": "viewport", "x": int(rect[0] + cx * rect[2]), "y": int(rect[1] + cy * rect[3])},
            {"type": "pointerDown", "button": 0}, {"type": "pointerUp", "button": 0}]}]}
        call("POST", s + "/actions", actions)
        # The crop halves or doubles itself as its picture loads until it fits the room; the
        # scale label is written once it has settled, and only then are its outline and its
        # picture's place final.
        crop = wait_for("the crop settled, with its outline", lambda: js("return document.getElementById('zoom-scale').textContent")
                        and js(boxes, "#zoom-crop-frame", "#zoom-crop-flags"))
        src = js("return document.getElementById('zoom-crop').getAttribute('src')")
        q = dict(kv.split("=") for kv in src.split("?")[1].split("&"))
        x, y, w, h = (float(q[k]) for k in "xywh")
        in_crop = [(expected[0] - x) / w, (expected[1] - y) / h, expected[2] / w, expected[3] / h]
        near(crop[0]["box"], in_crop, crop[0]["px"], "crop", w)
        print(f"outlined in the large view and in the crop {src.split('?')[1]}")
        with open(flag_png.replace(".png", "-zoom.png"), "wb") as f:
            f.write(base64.b64decode(call("GET", s + "/screenshot")))
        js("document.dispatchEvent(new KeyboardEvent('keydown', {key: 'Escape'}))")
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
