"""The operator page as a console, in two headless Chromium windows through chromedriver (W3C
WebDriver over plain HTTP, no client library); tests/it/console.rs serves a finished build with
a raised alarm and flags on FIRST and SECOND, behind a token, and runs this.

usage: console_browser.py PAGE_URL_WITH_TOKEN CHROMEDRIVER ARTIFACT_DIR FIRST SECOND

Checks: a deep link #layer=FIRST opens that layer; the next flag is SECOND and the previous one
FIRST again; the alarm acknowledged on one page (name, note, the button) clears the banner of
the other open page within 2 s; the history on the page lists the acknowledgement. Keeps
screenshots: console-alarm.png (the banner with the button), console-acknowledged.png.
"""
import base64
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from webdriver import start, wait_for  # noqa: E402

page, chromedriver, artifacts, first, second = sys.argv[1:6]
first, second = int(first), int(second)


driver, call = start(chromedriver)


class Window:
    def __init__(self, url):
        args = ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1400,1000"]
        caps = {"capabilities": {"alwaysMatch": {"browserName": "chrome", "goog:chromeOptions": {"args": args}}}}
        self.s = "/session/" + call("POST", "/session", caps)["sessionId"]
        call("POST", self.s + "/url", {"url": url})
        wait_for("the page script", lambda: self.js("return window.layerwisePageLoadedAt"))

    def js(self, script, *arguments):
        return call("POST", self.s + "/execute/sync", {"script": script, "args": list(arguments)})

    def click(self, selector):
        element = call("POST", self.s + "/element", {"using": "css selector", "value": selector})
        call("POST", self.s + f"/element/{list(element.values())[0]}/click", {})

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
    linked.click("#next-flag")
    wait_for(f"the next flag, layer {second}", lambda: linked.shown() == second)
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
    result = console.js("return document.getElementById('ack-result').textContent")
    assert result.startswith("alarm acknowledged by ana"), result
    linked.screenshot("console-acknowledged.png")
finally:
    for w in windows:
        try:
            w.close()
        except Exception:
            pass
    driver.terminate()
    driver.wait()
