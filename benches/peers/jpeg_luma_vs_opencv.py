#!/usr/bin/env python3
"""Side-by-side: layerwise's JPEG decode to luma vs libjpeg-turbo through OpenCV and PIL.

Runs inside benches/peers/.venv (opencv-python-headless, numpy, pillow; shared with
rectify_vs_opencv.py). examples/peer_steps.rs renders a D810-size mock frame
(7360 x 4912, quality 95, as the camera serves); each side decodes the same file to 8-bit luma:

- ours: `decode_jpeg_luma` (what the views use), on all cores;
- OpenCV: `cv2.imdecode(buf, IMREAD_GRAYSCALE)` (libjpeg-turbo, decoding the Y channel only);
- OpenCV colour: `cv2.imdecode(buf, IMREAD_COLOR)` for reference;
- OpenCV at 1/8 scale: `cv2.imdecode(buf, IMREAD_REDUCED_GRAYSCALE_8)`, for reference too: every
  Huffman code of the file is still decoded (a scan without restart markers is one sequence),
  but each block keeps only its DC term, so no inverse DCT: libjpeg-turbo's entropy decoding,
  the part of a decode no decoder of such a file can run in parallel or skip;
- PIL: `Image.open(...).convert("L")`.

And the same file to 8-bit colour, ours against the same two libraries:

- ours: `decode_jpeg` (zune-jpeg, what colour images go through);
- OpenCV: `cv2.imdecode(buf, IMREAD_COLOR)` (libjpeg-turbo; BGR, compared channel for channel);
- PIL: `Image.open(...)` and `load()` (libjpeg-turbo, RGB).

Each timing is the median of 5 runs; the comparison is repeated (--rounds, default 3). The two
lumas are compared pixel by pixel.

Usage: python3 benches/peers/jpeg_luma_vs_opencv.py [--rounds N]
(from the crate root; honours CARGO_TARGET_DIR)
"""
import os
import subprocess
import sys

from benchenv import ensure_venv

HERE = os.path.dirname(os.path.abspath(__file__))
CRATE = os.path.dirname(os.path.dirname(HERE))
VENV = os.path.join(HERE, ".venv")

ensure_venv(VENV, ["opencv-python-headless", "numpy", "pillow"])

import io  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

try:
    from PIL import Image
except ImportError:
    Image = None


def median_ms(f):
    times, out = [], None
    for _ in range(5):
        t = time.perf_counter()
        out = f()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times), out


def ours(exe, step, jpg, out):
    """Runs `peer_steps STEP` ("luma" or "colour"): its median time (ms) and the output's shape."""
    res = subprocess.run([exe, step, jpg, out], check=True, capture_output=True, text=True)
    kv = dict(ln.split("=", 1) for ln in res.stdout.splitlines() if "=" in ln)
    w, h = (int(x) for x in kv["size"].split("x"))
    return float(kv["decode_ms_median"]), (h, w) if step == "luma" else (h, w, 3)


def side_by_side(label, exe, step, jpg, out, peers, rounds):
    """Alternates ours and each peer for `rounds` rounds; prints the medians and the ratios."""
    results = {name: [] for name, _ in peers}
    ours_times = []
    for _ in range(rounds):
        ours_times.append(ours(exe, step, jpg, out)[0])
        for name, f in peers:
            results[name].append(median_ms(f)[0])
    o_med = statistics.median(ours_times)
    for name, ts in results.items():
        p_med = statistics.median(ts)
        print(f"[{label} vs {name}] median rounds: ours {o_med:.1f} ms, peer {p_med:.1f} ms, "
              f"ratio {o_med / p_med:.2f}")


def pil_rgb(data):
    im = Image.open(io.BytesIO(data))
    im.load()
    return im


def main():
    rounds = int(sys.argv[sys.argv.index("--rounds") + 1]) if "--rounds" in sys.argv else 3
    work = os.path.join(HERE, "out")
    os.makedirs(work, exist_ok=True)
    target = os.environ.get("CARGO_TARGET_DIR", os.path.join(CRATE, "target"))
    print("building examples/peer_steps (release) ...", flush=True)
    subprocess.check_call(["cargo", "build", "--release", "--quiet", "--example", "peer_steps"],
                          cwd=CRATE)
    exe = os.path.join(target, "release", "examples", "peer_steps")
    subprocess.check_call([exe, "frames", work])
    jpg = os.path.join(work, "frame.jpg")
    out = os.path.join(work, "ours_luma.raw")
    buf = np.fromfile(jpg, dtype=np.uint8)

    _, shape = ours(exe, "luma", jpg, out)
    mine = np.fromfile(out, dtype=np.uint8).reshape(shape)
    theirs = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    d = np.abs(mine.astype(np.int16) - theirs.astype(np.int16))
    print(f"opencv {cv2.__version__}, cv2 threads {cv2.getNumThreads()}, cores {os.cpu_count()}; "
          f"{shape[1]}x{shape[0]} JPEG ({buf.size / 1e6:.1f} MB); luma vs cv2 grey: max abs diff "
          f"{d.max()}, {100.0 * np.mean(d <= 1):.4f}% within +-1")
    data = buf.tobytes()
    peers = [
        ("cv2.imdecode GRAYSCALE", lambda: cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)),
        ("cv2.imdecode COLOR", lambda: cv2.imdecode(buf, cv2.IMREAD_COLOR)),
        ("cv2.imdecode REDUCED_GRAYSCALE_8 (entropy decoding, no IDCT)",
         lambda: cv2.imdecode(buf, cv2.IMREAD_REDUCED_GRAYSCALE_8)),
    ]
    if Image is not None:
        peers.append(("PIL convert L", lambda: Image.open(io.BytesIO(data)).convert("L")))
    side_by_side("luma", exe, "luma", jpg, out, peers, rounds)

    # Colour: ours (RGB) against libjpeg-turbo through OpenCV (BGR) and PIL (RGB).
    out_rgb = os.path.join(work, "ours_rgb.raw")
    _, shape = ours(exe, "colour", jpg, out_rgb)
    mine = np.fromfile(out_rgb, dtype=np.uint8).reshape(shape)
    theirs = cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1]
    d = np.abs(mine.astype(np.int16) - theirs.astype(np.int16))
    print(f"colour vs cv2 colour: max abs diff {d.max()}, {100.0 * np.mean(d <= 1):.4f}% of "
          f"samples within +-1, {100.0 * np.mean(d <= 2):.4f}% within +-2")
    peers = [("cv2.imdecode COLOR", lambda: cv2.imdecode(buf, cv2.IMREAD_COLOR))]
    if Image is not None:
        peers.append(("PIL RGB", lambda: pil_rgb(data)))
    side_by_side("colour", exe, "colour", jpg, out_rgb, peers, rounds)
    for p in (jpg, out, out_rgb, os.path.join(work, "rectified.raw")):
        os.remove(p)


if __name__ == "__main__":
    main()
