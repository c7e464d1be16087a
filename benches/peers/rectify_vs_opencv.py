#!/usr/bin/env python3
"""Side-by-side: layerwise's rectifier vs OpenCV warpPerspective.

Creates benches/peers/.venv (opencv-python-headless, numpy) on first use and re-runs
itself inside it. Generates a synthetic textured 7360 x 4912 frame and the
oblique homography of the bench (plate corners -> image trapezoid), warps it
onto the 4400 x 4400 plate grid with
cv2.warpPerspective(INTER_LINEAR | WARP_INVERSE_MAP, BORDER_CONSTANT) and
with examples/rectify_file.rs, and compares time and output.

Both sides run with their default threads (all cores). Each timing is the
median of 5 runs after 2 untimed ones (both sides: a fresh process's first
large outputs are fresh pages from the kernel, a long-running one reuses
what it freed); the machine may be shared, so the whole comparison is
repeated (--rounds, default 3) alternating the two tools, and the round
with the lowest figures (least outside load) is also reported.

Two modes: "alloc" (each call allocates its output: cv2 without dst, our
rectify_dynamic) and "reuse" (output buffer reused: cv2 with dst=, our
rectify_*_into). Each side allocates as its program does: numpy's allocator
(huge pages for large arrays) for OpenCV, the layerwise binary's for ours
(src/alloc.rs: the last large block freed serves the next allocation of its
size).

Usage: python3 benches/peers/rectify_vs_opencv.py [--keep] [--rounds N]
(from the crate root; honours CARGO_TARGET_DIR)
"""
import json
import os
import subprocess
import sys

from benchenv import ensure_venv

HERE = os.path.dirname(os.path.abspath(__file__))
CRATE = os.path.dirname(os.path.dirname(HERE))
VENV = os.path.join(HERE, ".venv")


ensure_venv(VENV, ["opencv-python-headless", "numpy"])

import statistics  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

W_IMG, H_IMG = 7360, 4912
PIXEL_MM, HALF = 0.0625, 137.5
N_GRID = 4400
IMAGE_PTS = np.float64([[1400, 600], [5960, 600], [6900, 4500], [460, 4500]])
PLATE_PTS = np.float64([[-HALF, HALF], [HALF, HALF], [HALF, -HALF], [-HALF, -HALF]])


def synthetic_frame(rng):
    """Textured frame: smooth blobs + fine noise + hard-edged stripes."""
    small = rng.integers(0, 256, (H_IMG // 16, W_IMG // 16, 3), dtype=np.uint8)
    img = cv2.resize(small, (W_IMG, H_IMG), interpolation=cv2.INTER_CUBIC).astype(np.int16)
    img += rng.integers(-24, 25, img.shape, dtype=np.int16)
    yy, xx = np.mgrid[0:H_IMG, 0:W_IMG]
    stripes = ((xx // 37 + yy // 53) % 2 == 0)
    img[stripes] = img[stripes] // 3
    return np.clip(img, 0, 255).astype(np.uint8)


def grid_to_image(h_img_to_build):
    """Matrix mapping grid (col, row, 1) -> image, for WARP_INVERSE_MAP."""
    g = np.array([[PIXEL_MM, 0, -HALF + PIXEL_MM / 2],
                  [0, -PIXEL_MM, HALF - PIXEL_MM / 2],
                  [0, 0, 1.0]])
    return np.linalg.inv(h_img_to_build) @ g


def valid_mask(m, w, h, border=2):
    """Grid pixels whose sample lies in [0, w-1] x [0, h-1] (our inside rule),
    shrunk by `border` grid pixels."""
    r, c = np.mgrid[0:N_GRID, 0:N_GRID].astype(np.float64)
    ww = m[2, 0] * c + m[2, 1] * r + m[2, 2]
    u = (m[0, 0] * c + m[0, 1] * r + m[0, 2]) / ww
    v = (m[1, 0] * c + m[1, 1] * r + m[1, 2]) / ww
    ok = (ww > 0) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    k = np.ones((2 * border + 1, 2 * border + 1), np.uint8)
    return cv2.erode(ok.astype(np.uint8), k, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)


# Untimed runs before the 5 timed ones, on both sides (examples/rectify_file.rs: WARM_UP).
WARM_UP = 2


def time_opencv(src, m, reuse):
    times, out, dst = [], None, None
    for run in range(WARM_UP + 5):
        t = time.perf_counter()
        res = cv2.warpPerspective(src, m, (N_GRID, N_GRID), dst=dst,
                                  flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        if run >= WARM_UP:
            times.append((time.perf_counter() - t) * 1e3)
        out = res  # the previous output is released here, outside the timing
        if reuse:
            dst = res
    return statistics.median(times), out


def time_ours(exe, in_png, h_path, out_png, reuse):
    args = [exe, in_png, h_path, out_png] + (["--reuse"] if reuse else [])
    res = subprocess.run(args, check=True, capture_output=True, text=True)
    line = [ln for ln in res.stdout.splitlines() if ln.startswith("warp_ms_median=")][0]
    return float(line.split("=")[1])


def main():
    keep = "--keep" in sys.argv
    rounds = int(sys.argv[sys.argv.index("--rounds") + 1]) if "--rounds" in sys.argv else 3
    work = os.path.join(HERE, "out")
    os.makedirs(work, exist_ok=True)
    target = os.environ.get("CARGO_TARGET_DIR", os.path.join(CRATE, "target"))
    print("building examples/rectify_file (release) ...", flush=True)
    subprocess.check_call(["cargo", "build", "--release", "--quiet", "--example", "rectify_file"],
                          cwd=CRATE)
    exe = os.path.join(target, "release", "examples", "rectify_file")

    rng = np.random.default_rng(2024)
    frame = synthetic_frame(rng)
    h = cv2.getPerspectiveTransform(IMAGE_PTS.astype(np.float32), PLATE_PTS.astype(np.float32)).astype(np.float64)
    h /= h[2, 2]
    m = grid_to_image(h)
    h_path = os.path.join(work, "H.json")
    with open(h_path, "w") as f:
        json.dump({"homography": h.tolist()}, f)
    mask = valid_mask(m, W_IMG, H_IMG)
    print(f"opencv {cv2.__version__}, cv2 threads {cv2.getNumThreads()}, cores {os.cpu_count()}; "
          f"compared pixels (valid region minus 2 px band): {mask.sum()} of {N_GRID * N_GRID}")

    for name, src in (("rgb8", frame), ("gray8", cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))):
        in_png = os.path.join(work, f"in_{name}.png")
        out_png = os.path.join(work, f"ours_{name}.png")
        # cv2 writes BGR order: reverse so the PNG holds our array as RGB.
        cv2.imwrite(in_png, src[:, :, ::-1] if src.ndim == 3 else src, [cv2.IMWRITE_PNG_COMPRESSION, 1])

        # Output agreement (alloc mode outputs).
        _, cv_out = time_opencv(src, m, reuse=False)
        time_ours(exe, in_png, h_path, out_png, reuse=False)
        ours = cv2.imread(out_png, cv2.IMREAD_UNCHANGED)
        if ours.ndim == 3:
            ours = ours[:, :, ::-1]
        d = np.abs(ours.astype(np.int16) - cv_out.astype(np.int16))
        dm = d[mask]
        print(f"[{name}] max abs diff {dm.max()} in the compared region, "
              f"{100.0 * np.mean(dm <= 1):.4f}% within +-1, {100.0 * np.mean(dm == 0):.2f}% identical; "
              f"outside it (image border band, fill): max abs diff {d[~mask].max()}")

        for mode in ("alloc", "reuse"):
            reuse = mode == "reuse"
            results = []
            for _ in range(rounds):
                cv_ms, _ = time_opencv(src, m, reuse)
                ours_ms = time_ours(exe, in_png, h_path, out_png, reuse)
                results.append((ours_ms, cv_ms))
            for k, (o, c) in enumerate(results):
                print(f"[{name} {mode}] round {k + 1}: ours {o:.1f} ms, opencv {c:.1f} ms, ratio {o / c:.2f}")
            o_best = min(r[0] for r in results)
            c_best = min(r[1] for r in results)
            o_med = statistics.median(r[0] for r in results)
            c_med = statistics.median(r[1] for r in results)
            print(f"[{name} {mode}] best rounds: ours {o_best:.1f} ms, opencv {c_best:.1f} ms, ratio {o_best / c_best:.2f}")
            print(f"[{name} {mode}] median rounds: ours {o_med:.1f} ms, opencv {c_med:.1f} ms, ratio {o_med / c_med:.2f}")
        if not keep:
            for p in (in_png, out_png):
                os.remove(p)


if __name__ == "__main__":
    main()
