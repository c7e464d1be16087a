"""A bounded attack on the operator page from a process of its own (tests/it/web_load.rs).

    python3 tests/web_stress.py HOST PORT IDLE SLOW STREAMS

Keeps, until its stdin closes:
- IDLE connections that send nothing (the page closes some to make room: they are opened again,
  at most 300 a second; 50 a second for each of the other kinds);
- SLOW `POST /api/calibration` requests trickling their body one byte a second, half of them
  announcing a Content-Length of 1e9, half 60,000 bytes;
- STREAMS event streams (`GET /api/events`) that never read a byte (a small receive buffer).
None carries the page's token. Every connection comes from 127.0.0.2, another address than the
operator's (127.0.0.1), as an attacker's would: the page's limits per address are what keep the
operator in. Prints one JSON line a second: what is open, what was opened
again, what the page answered the slow bodies (status codes).
"""

import json
import resource
import select
import socket
import sys
import time


def raise_open_files():
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard == resource.RLIM_INFINITY or hard > soft:
        want = hard if hard != resource.RLIM_INFINITY else 65536
        resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))


SOURCE = "127.0.0.2"


def connect(host, port, rcvbuf=None):
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.bind((SOURCE, 0))
    if rcvbuf:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    s.settimeout(2)
    try:
        s.connect((host, port))
    except OSError:
        s.close()
        return None
    s.setblocking(False)
    return s


TCP_ESTABLISHED = 1


def closed(s):
    """Whether the page closed the connection (from the TCP state: an event stream is never
    read, so unread bytes would hide the end from a read)."""
    try:
        return s.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 1)[0] != TCP_ESTABLISHED
    except OSError:
        return True


def send(s, data):
    try:
        s.send(data)
        return True
    except (BlockingIOError, InterruptedError):
        return True
    except OSError:
        return False


def main():
    host, port = sys.argv[1], int(sys.argv[2])
    want = {"idle": int(sys.argv[3]), "slow": int(sys.argv[4]), "streams": int(sys.argv[5])}
    raise_open_files()
    open_ = {k: [] for k in want}
    reopened = {k: 0 for k in want}
    answers = {}
    # Connections opened a tick (10 ms) at most, per kind: 400 a second in all.
    budget_per_tick = {"idle": 30, "slow": 5, "streams": 5}
    started = {}
    last_report = 0.0
    n = 0
    while True:
        if select.select([sys.stdin], [], [], 0)[0] and not sys.stdin.read(1):
            break
        for kind, socks in open_.items():
            budget = budget_per_tick[kind]
            alive = []
            for s in socks:
                if closed(s):
                    if kind == "slow":
                        try:
                            head = s.recv(64)
                            code = head[9:12].decode(errors="replace") if head else "closed"
                        except OSError:
                            code = "reset"
                        answers[code] = answers.get(code, 0) + 1
                    s.close()
                    started.pop(s, None)
                    reopened[kind] += 1
                else:
                    alive.append(s)
            while len(alive) < want[kind] and budget > 0:
                budget -= 1
                s = connect(host, port, rcvbuf=4096 if kind == "streams" else None)
                if s is None:
                    break
                started[s] = time.monotonic()
                alive.append(s)
                n += 1
                if kind == "streams":
                    send(s, b"GET /api/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
                elif kind == "slow":
                    length = 1_000_000_000 if n % 2 else 60_000
                    head = (
                        "POST /api/calibration HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                        f"Content-Type: application/json\r\nContent-Length: {length}\r\n\r\n"
                    )
                    send(s, head.encode())
            open_[kind] = alive
        now = time.monotonic()
        for s in open_["slow"]:
            if now - started.get(s, now) >= 1.0:
                started[s] = now
                send(s, b"[")
        if now - last_report >= 1.0:
            last_report = now
            report = {k: len(v) for k, v in open_.items()}
            report["reopened"] = reopened
            report["slow_answers"] = answers
            print(json.dumps(report), flush=True)
        time.sleep(0.01)


if __name__ == "__main__":
    main()
