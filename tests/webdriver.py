"""A chromedriver started on a free port and W3C WebDriver calls over plain HTTP (no client
library), shared by the browser tests (web_browser.py, console_browser.py)."""
import json
import socket
import subprocess
import time
import urllib.request


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start(chromedriver):
    """Starts chromedriver and waits until it answers; returns (its process, call) where
    call(method, path, body=None) returns the answer's value."""
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

    for _ in range(100):
        try:
            urllib.request.urlopen(base + "/status", timeout=1)
            break
        except OSError:
            time.sleep(0.1)
    return driver, call


def wait_for(what, check, timeout=30.0, diagnosis=lambda: ""):
    """Polls `check` until it returns something true, which it returns; fails after `timeout` s
    naming `what` and what `diagnosis` says."""
    deadline = time.time() + timeout
    while True:
        value = check()
        if value:
            return value
        if time.time() > deadline:
            raise AssertionError(f"timed out waiting for {what}{diagnosis()}")
        time.sleep(0.05)
