#!/usr/bin/env python3
"""Side by side: OpenCV's findTransformECC (MOTION_HOMOGRAPHY) against our IC-LM
(examples/register_file.rs) on the same std-filtered frame, exemplar, pyramid and start warp.

Usage (from the crate root):
    python3 -m venv benches/peers/.venv && benches/peers/.venv/bin/pip install opencv-python-headless numpy
    benches/peers/.venv/bin/python benches/peers/ecc_vs_ours.py [--size 4400] [--levels 4] [--data DIR]

The data (I_B, I_E, start and true warps, the parts' contour points) are made once by
`cargo run --release --example register_file -- make DIR --size N`. Both sides:
- start from the same warp (exemplar px -> image px, from 4 clicks off by up to 6 px);
- use a pyramid of `levels` levels, 2x2 box averaging (cv2.INTER_AREA on even sizes), the warp
  conjugated by x_fine = 2 x_coarse + 1/2 between levels;
- are scored by the mean and max distance to the true warp over the parts' contour points, in
  image pixels.
ECC keeps its own default Gaussian pre-smoothing (gaussFiltSize 5). Times are wall clock; the
best of --repeat runs each; threads: OpenCV's default and rayon's default (all cores).
"""

import argparse
import json
import os
import subprocess
import sys
import time

import cv2
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def scale(level):
    s = float(2 ** level)
    return np.array([[s, 0, 0.5 * (s - 1)], [0, s, 0.5 * (s - 1)], [0, 0, 1]])


def to_level(w0, level):
    s = scale(level)
    return np.linalg.inv(s) @ w0 @ s


def from_level(wl, level):
    s = scale(level)
    return s @ wl @ np.linalg.inv(s)


def down(img):
    h, w = img.shape
    img = img[: h - h % 2, : w - w % 2]
    return cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)


def error(warp, truth, contour):
    pts = np.hstack([contour, np.ones((len(contour), 1))])
    a = pts @ warp.T
    b = pts @ truth.T
    d = np.hypot(a[:, 0] / a[:, 2] - b[:, 0] / b[:, 2], a[:, 1] / a[:, 2] - b[:, 1] / b[:, 2])
    return float(d.mean()), float(d.max())


def near_parts_mask(image, exemplar, start, margin=24):
    """Our default cost region (exemplar pixels within `margin` px of the parts' std support)
    as an ECC input mask: dilated in the exemplar, carried into the frame by the start warp."""
    support = (exemplar > 0.01 * exemplar.max()).astype(np.uint8)
    kernel = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    near = cv2.dilate(support, kernel)
    return cv2.warpPerspective(near, start, (image.shape[1], image.shape[0]),
                               flags=cv2.INTER_NEAREST)


def ecc(image, exemplar, start, levels, iterations, eps, mask=None):
    images, exemplars, masks = [image], [exemplar], [mask]
    for _ in range(1, levels):
        images.append(down(images[-1]))
        exemplars.append(down(exemplars[-1]))
        masks.append(None if mask is None else (down(masks[-1].astype(np.float32)) > 0)
                     .astype(np.uint8))
    warp0 = start.copy()
    per_level = []
    for level in reversed(range(levels)):
        w = to_level(warp0, level).astype(np.float32)
        w /= w[2, 2]
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iterations, eps)
        t = time.perf_counter()
        rho, w = cv2.findTransformECC(exemplars[level], images[level], w,
                                      cv2.MOTION_HOMOGRAPHY, criteria, masks[level], 5)
        per_level.append({"level": level, "rho": float(rho),
                          "seconds": time.perf_counter() - t})
        warp0 = from_level(w.astype(np.float64), level)
    return warp0, per_level


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=4400)
    ap.add_argument("--levels", type=int, default=4)
    ap.add_argument("--data", default=None)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--ecc-iterations", type=int, default=100)
    ap.add_argument("--ecc-eps", type=float, default=1e-6)
    args = ap.parse_args()
    data = args.data or os.path.join(ROOT, "bench", "data", str(args.size))
    cargo_env = dict(os.environ)
    cargo_env.setdefault("CARGO_TARGET_DIR", "/work/scratch/target-registration")
    example = ["cargo", "run", "--quiet", "--offline", "--release", "--example", "register_file", "--"]
    if not os.path.exists(os.path.join(data, "truth.txt")):
        subprocess.run(example + ["make", data, "--size", str(args.size)], cwd=ROOT,
                       env=cargo_env, check=True)

    image = np.load(os.path.join(data, "image.npy"))
    exemplar = np.load(os.path.join(data, "exemplar.npy"))
    contour = np.load(os.path.join(data, "contour.npy"))
    start = np.loadtxt(os.path.join(data, "start.txt"))
    truth = np.loadtxt(os.path.join(data, "truth.txt"))

    def run_ecc(mask):
        best, result = float("inf"), None
        for _ in range(args.repeat):
            t = time.perf_counter()
            result = ecc(image, exemplar, start, args.levels, args.ecc_iterations, args.ecc_eps,
                         mask)
            best = min(best, time.perf_counter() - t)
        warp, per_level = result
        return best, error(warp, truth, contour), per_level

    best, (ecc_mean, ecc_max), per_level = run_ecc(None)
    best_m, (eccm_mean, eccm_max), per_level_m = run_ecc(near_parts_mask(image, exemplar, start))
    start_mean, start_max = error(start, truth, contour)

    def ours(extra):
        out = subprocess.run(example + ["run", data, "--levels", str(args.levels), "--repeat",
                                        str(args.repeat)] + extra,
                             cwd=ROOT, env=cargo_env, check=True, capture_output=True, text=True)
        return json.loads(out.stdout.strip().splitlines()[-1])

    near = ours([])
    every = ours(["--all-pixels"])

    print(f"data: {data}: image {image.shape[1]}x{image.shape[0]}, exemplar "
          f"{exemplar.shape[1]}x{exemplar.shape[0]}, {args.levels} levels, "
          f"OpenCV {cv2.__version__} ({cv2.getNumThreads()} threads), start error mean "
          f"{start_mean:.3f} px, max {start_max:.3f} px")
    print(f"{'method':<34}{'time s':>9}{'mean px':>10}{'max px':>10}")
    print(f"{'OpenCV findTransformECC':<34}{best:>9.3f}{ecc_mean:>10.4f}{ecc_max:>10.4f}")
    print(f"{'ECC, near-parts input mask':<34}{best_m:>9.3f}{eccm_mean:>10.4f}{eccm_max:>10.4f}")
    for name, r in [("ours IC-LM, all pixels", every), ("ours IC-LM, near the parts", near)]:
        print(f"{name:<34}{r['seconds']:>9.3f}{r['mean_px']:>10.4f}{r['max_px']:>10.4f}"
              f"   ratio ours/ECC {r['seconds'] / best:.3f}, /masked ECC {r['seconds'] / best_m:.3f}")
    print("ECC per level:", json.dumps(per_level))
    print("masked ECC per level:", json.dumps(per_level_m))
    print("ours per level (all pixels):", json.dumps(every["levels"]))
    print("ours per level (near the parts):", json.dumps(near["levels"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
