"""The operator page as a console, in two headless Chromium windows through chromedriver (W3C
WebDriver over plain HTTP, no client library); tests/it/console.rs serves a finished build with
a raised alarm and flags on FIRST and SECOND, behind a token, and runs this.

usage: console_browser.py PAGE_URL_WITH_TOKEN CHROMEDRIVER ARTIFACT_DIR FIRST SECOND SERVER_PID BUILD_DIR

Checks: a deep link #layer=FIRST opens that layer; the health of the stopped daemon that wrote
the build is shown nowhere green and says "daemon stopped"; its three flags or more have no two labels
overlapping and each says what to do; a view zoomed shows a crop at 1:1 (full resolution) and
at 2:1 with +; the trends of part 2 have a value for every layer and a baseline band; a link to a view and a flag opens that view with the flag marked; the next flag is SECOND and the previous one
FIRST again; the alarm acknowledged on one page (name, note, the button) clears the banner of
the other open page within 2 s; the history on the page lists the acknowledgement; the page
server stopped (SIGSTOP to SERVER_PID), the page says it is stale within 30 s, and clears that
once the server goes on; the build's UID changed in BUILD_DIR (another build there), the page
reloads. Keeps screenshots: console-alarm.png (the banner with the button),
console-acknowledged.png, console-flags.png (layer FIRST), console-trends.png,
console-zoom.png, console-stale.png.
"""
import base64
import json
import os
import signal
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from webdriver import start, wait_for  # noqa: E402

page, chromedriver, artifacts, first, second, server_pid, build_dir = sys.argv[1:8]
first, second, server_pid = int(first), int(second), int(server_pid)


driver, call = start(chromedriver)


class Window:
    def __init__(self, url):
        args = ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1400,1000"]
        caps = {"capabilities": {"alwaysMatch": {"browserName": "chrome", "goog:chromeOptions": {"args": args}}}}
        self.s = "/session/" + call("POST", "/session", caps)["sessionId"]
        call("POST", self.s + "/url", {"url": url})
        wait_for("the page script", lambda: self.js("return window.layerwisePageLoadedAt"))
        # Where every click lands, for `click` to check and a failed wait to show.
        self.js("""window.clicks = [];
            document.addEventListener('click', (e) => clicks.push(e.target), true);""")

    def js(self, script, *arguments):
        return call("POST", self.s + "/execute/sync", {"script": script, "args": list(arguments)})

    def click(self, selector):
        """Clicks the element as a user does (WebDriver, at its centre). WebDriver finds the
        centre, then presses there: should the page move in between (a busy machine), the press
        lands on something else. That is said, and the click given again, once."""
        for attempt in range(2):
            before = self.js("return clicks.length")
            element = call("POST", self.s + "/element", {"using": "css selector", "value": selector})
            call("POST", self.s + f"/element/{list(element.values())[0]}/click", {})
            hit = self.js("return clicks.slice(arguments[0]).map((t) => t === arguments[1] || t.id || t.tagName)", before, element)
            if True in hit:
                return
            print(f"the click on {selector} landed on {hit or 'nothing'}; clicking again", file=sys.stderr)
        raise AssertionError(f"two clicks on {selector} did not reach it")

    def type(self, selector, text):
        element = call("POST", self.s + "/element", {"using": "css selector", "value": selector})
        call("POST", self.s + f"/element/{list(element.values())[0]}/value", {"text": text})

    def shown(self):
        t = self.js("return document.getElementById('layer-number').textContent")
        return int(t) if t.isdigit() else 0

    def banner(self):
        return self.js("const w = document.getElementById('warning'); return w.hidden ? '' : w.textContent")

    def screenshot(self, name):
        png = base64.b64decode(call("GET", self.s + "/screenshot"))
        with open(os.path.join(artifacts, name), "wb") as f:
            f.write(png)

    def diagnosis(self):
        # What the page showed when a wait ran out: the layer and address, the flagged layers
        # the page knows, and what lies over the next-flag button.
        try:
            return "\n" + str(self.js("""
                const b = document.getElementById('next-flag').getBoundingClientRect();
                const top = document.elementFromPoint(b.x + b.width / 2, b.y + b.height / 2);
                return {layer: document.getElementById('layer-number').textContent, hash: location.hash,
                        current: state.current, follow: state.follow,
                        flagged: state.layers.filter((l) => l.flags).map((l) => l.layer),
                        zoom_hidden: document.getElementById('zoom').hidden,
                        clicks: clicks.map((t) => t.id || t.tagName),
                        over_button: top && (top.id || top.tagName)};"""))
        except Exception as e:
            return f" ({e})"

    def close(self):
        call("DELETE", self.s)



windows = []
try:
    # The second operator opens a link to the first flagged layer.
    linked = Window(page + f"#layer={first}")
    windows.append(linked)
    wait_for(f"the linked layer {first}", lambda: linked.shown() == first)
    assert not linked.js("return document.getElementById('follow').checked"), "a linked layer is not followed away from"
    wait_for("the alarm banner", lambda: "ALARM since layer" in linked.banner())
    print(f"#layer={first} opened layer {first}; banner: {linked.banner()[:80]}")

    # The daemon that wrote this build has stopped: nothing of it is shown green, and each part
    # says when it was last true and that the daemon stopped.
    health_js = "return [...document.querySelectorAll('#health dd')].map(d => [d.previousElementSibling.textContent, d.className, d.textContent])"
    health = wait_for("the health panel", lambda: linked.js(health_js) or None)
    parts = [h for h in health if h[0] in ("trigger", "camera", "lights", "processing")]
    assert len(parts) == 4, health
    assert not [h for h in parts if "ok" in h[1].split()], f"green for a stopped daemon: {health}"
    assert all("daemon stopped" in h[2] for h in parts), health
    green = linked.js("return getComputedStyle(document.querySelector('#health dd')).color")
    assert green != "rgb(119, 221, 119)", green
    print("health of the stopped daemon:", "; ".join(f"{h[0]}: {h[2]}" for h in parts))

    # Layer FIRST has three flags or more: no two labels overlap anywhere on the page.
    labels = """
        return [...document.querySelectorAll(arguments[0] + ' .flags')].map(layer =>
            [...layer.querySelectorAll('.flag-box span')].map(l => { const r = l.getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom, l.textContent]; }));"""

    def overlaps(groups):
        return [(a[4], b[4]) for g in groups for i, a in enumerate(g) for b in g[i + 1:]
                if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]]

    def settled():
        shown = linked.js(labels, "#views")
        # The labels are moved once the layer is drawn: wait for a frame after the pictures.
        return shown if shown and linked.js("return [...document.querySelectorAll('#views img')].every(i => i.complete)") else None
    groups = wait_for("the flag labels of layer FIRST", settled)
    time.sleep(0.3)
    groups = linked.js(labels, "#views")
    most = max(len(g) for g in groups)
    assert most >= 3, f"a view of layer {first} with three flag labels: {[[l[4] for l in g] for g in groups]}"
    assert not overlaps(groups), f"overlapping flag labels: {overlaps(groups)}"
    print(f"layer {first}: {sum(map(len, groups))} flag labels, {most} on one view, none overlapping")
    # Each flag in the layer's list says what it means, what to check and when to stop.
    guide = linked.js("return [...document.querySelectorAll('#layer-detail details.guide')].map(d => d.textContent)")
    assert guide and all("when to stop" in g for g in guide), guide
    linked.screenshot("console-flags.png")

    # The trends: part 2's metrics (never flagged) over every layer, each with its baseline band
    # once the part has inspection.drift_min_layers (10) layers, and the line of the layer shown.
    linked.js("document.getElementById('trends').open = true; document.getElementById('trends').dispatchEvent(new Event('toggle'))")
    charts = wait_for("the trend charts", lambda: linked.js("""
        const part = document.getElementById('trend-part');
        if (!part.options.length) return null;
        part.value = '2'; part.dispatchEvent(new Event('change'));
        return [...document.querySelectorAll('#trend-charts .trend')].map(t => ({metric: t.dataset.metric,
            points: t.querySelector('.value').getAttribute('points').split(' ').length,
            bands: t.querySelectorAll('.band').length, now: t.querySelectorAll('.now').length}));"""))
    post_mean = [c for c in charts if c["metric"] == "post_mean"]
    # Every value /api/trends gives is drawn (a loaded machine may leave a layer uninspected: the
    # API's own layers, not the slider's, are the count), and 10 or more layers have one.
    layers = linked.js("return trends.parts['2'].series.post_mean.value.filter(v => v !== null).length")
    assert layers >= 10, f"part 2 measured on {layers} layers"
    # The band is drawn where the API gives a baseline: from the 11th measured layer on (a
    # loaded machine that left layers uninspected may give none), and always beyond that.
    with_band = linked.js("return trends.parts['2'].series.post_mean.median.some(v => v !== null)")
    assert with_band or layers <= 10, f"part 2 measured on {layers} layers and no baseline"
    assert post_mean and post_mean[0]["points"] == layers and (post_mean[0]["bands"] >= 1) == with_band and post_mean[0]["now"] == 1, charts
    print(f"trends of part 2 over {layers} layers: {charts}")
    linked.js("document.getElementById('trends').scrollIntoView()")
    time.sleep(0.3)
    linked.screenshot("console-trends.png")
    linked.js("window.scrollTo(0, 0)")

    # Zoom a view to full resolution: a crop at 1:1, then enlarged 2:1 with +.
    linked.click(".tile img")
    wait_for("the large view", lambda: linked.js("return !document.getElementById('zoom').hidden"))
    linked.click("#zoom-img")
    crop = """
        const c = document.getElementById('zoom-crop');
        if (!c.complete || !c.naturalWidth || !c.dataset.scale) return null;
        const r = c.getBoundingClientRect();
        return {natural: [c.naturalWidth, c.naturalHeight], shown: [r.width, r.height], scale: Number(c.dataset.scale),
                src: c.getAttribute('src'), label: document.getElementById('zoom-scale').textContent,
                crop_px: window.layerwiseCropPx};"""
    one = wait_for("a crop at 1:1", lambda: (lambda c: c if c and c["scale"] == 1 else None)(linked.js(crop)))
    assert all(abs(s - n) < 1 for s, n in zip(one["shown"], one["natural"])), f"1:1 shows a pixel as a pixel: {one}"
    assert max(one["natural"]) < one["crop_px"], f"the crop is not scaled down by the server: {one}"
    assert "full resolution" in one["label"], one
    linked.js("document.dispatchEvent(new KeyboardEvent('keydown', {key: '+'}))")
    two = wait_for("the crop at 2:1", lambda: (lambda c: c if c and c["scale"] == 2 and c["src"] != one["src"] else None)(linked.js(crop)))
    assert all(abs(s - 2 * n) < 1.5 for s, n in zip(two["shown"], two["natural"])), f"2:1: {two}"
    q1 = dict(kv.split("=") for kv in one["src"].split("?")[1].split("&"))
    q2 = dict(kv.split("=") for kv in two["src"].split("?")[1].split("&"))
    assert abs(float(q2["w"]) - float(q1["w"]) / 2) < 2e-4, (q1, q2)
    print(f"zoom: crop {one['natural']} at 1:1 ({q1['w']} of the picture), then 2:1 ({q2['w']})")
    linked.screenshot("console-zoom.png")
    linked.js("document.dispatchEvent(new KeyboardEvent('keydown', {key: 'Escape'}))")

    # A link to a view and a flag opens that view large with the flag marked.
    view = linked.js("return document.querySelector('#layer-detail .flag-link').getAttribute('href')")
    assert view.startswith(f"#layer={first}&view=") and view.endswith("&flag=1"), view
    linked.js("location.hash = arguments[0]", view)
    wait_for("the linked view large, its flag marked", lambda: linked.js(
        "return !document.getElementById('zoom').hidden && document.querySelector('#zoom-flags .flag-box.selected') !== null"
        " && document.querySelector('#layer-detail dd.selected') !== null"))
    print(f"link {view} opened the view with flag 1 marked")
    linked.js("document.dispatchEvent(new KeyboardEvent('keydown', {key: 'Escape'}))")
    linked.click("#next-flag")
    wait_for(f"the next flag, layer {second}", lambda: linked.shown() == second, diagnosis=linked.diagnosis)
    assert linked.js("return location.hash") == f"#layer={second}", linked.js("return location.hash")
    linked.click("#prev-flag")
    wait_for(f"the previous flag, layer {first}", lambda: linked.shown() == first)
    print(f"next flag {second}, previous flag {first}")

    # The first operator acknowledges on the page.
    console = Window(page)
    windows.append(console)
    wait_for("the acknowledge button", lambda: console.js("return !document.getElementById('ack-form').hidden"))
    console.type("#ack-by", "ana")
    console.type("#ack-note", "stopped the build, checking part 3")
    console.screenshot("console-alarm.png")
    console.click("#ack")
    clicked = time.time()
    wait_for("the other page's banner to clear", lambda: "ALARM" not in linked.banner(), timeout=2.0)
    cleared = time.time() - clicked
    print(f"banner cleared on the other page {cleared:.2f} s after the click")
    history = wait_for("the acknowledgement in the history", lambda: (lambda t: "acknowledged by ana" in t and t)(
        console.js("return document.getElementById('alarm-history').textContent")))
    assert "checking part 3" in history, history
    assert "raised at layer" in history, history
    print("history:", history[:200])
    # The answer to the page's own POST can land after the event stream has
    # already updated the history: wait for it rather than read it once.
    result = wait_for("the acknowledgement's answer on the page", lambda: console.js(
        "return document.getElementById('ack-result').textContent") or None)
    assert result.startswith("alarm acknowledged by ana"), result
    linked.screenshot("console-acknowledged.png")

    # The page server stuck (stopped): within the page's 15 s the page says it is stale, with
    # since when, above everything it shows; once the server goes on, the banner clears.
    os.kill(server_pid, signal.SIGSTOP)
    stopped = time.time()
    try:
        stale = wait_for("the stale banner", lambda: linked.js(
            "const s = document.getElementById('stale'); return s.hidden ? null : s.textContent"), timeout=30.0)
        waited = time.time() - stopped
        assert stale.startswith("STALE: nothing heard from the page server since "), stale
        assert waited >= 10.0, f"stale after {waited:.1f} s: updates come every 5 s at most"
        print(f"stale banner {waited:.1f} s after the server stopped: {stale}")
        # It asks the server why (5 s without an answer) and says so.
        why = wait_for("the stale banner's reason", lambda: (lambda t: "does not answer" in t and t)(linked.js(
            "return document.getElementById('stale').textContent")), timeout=20.0)
        print(f"stale banner {time.time() - stopped:.1f} s after the stop: {why}")
        linked.screenshot("console-stale.png")
    finally:
        os.kill(server_pid, signal.SIGCONT)
    wait_for("the stale banner to clear", lambda: linked.js("return document.getElementById('stale').hidden"), timeout=30.0)
    print(f"stale banner cleared {time.time() - stopped:.1f} s after the stop")

    # Another build in the same folder (its manifest's UID another): the open page reloads, so
    # nothing it held of the build before (layers, vectors, pictures) is shown for the new one.
    loaded = linked.js("return window.layerwisePageLoadedAt")
    manifest_path = os.path.join(build_dir, "build.json")
    with open(manifest_path) as f:
        manifest = json.load(f)
    manifest["study_instance_uid"] += ".9"
    with open(manifest_path + ".tmp", "w") as f:
        json.dump(manifest, f)
    os.replace(manifest_path + ".tmp", manifest_path)
    changed = time.time()
    wait_for("the page to reload for the other build", lambda: linked.js(
        "return window.layerwisePageLoadedAt !== arguments[0] && window.layerwisePageLoadedAt", loaded), timeout=30.0)
    print(f"page reloaded {time.time() - changed:.1f} s after the build's UID changed")
finally:
    for w in windows:
        try:
            w.close()
        except Exception:
            pass
    driver.terminate()
    driver.wait()
