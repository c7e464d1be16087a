#!/usr/bin/env python3
"""Internal-flaw detection on the 50 µm synthetic case (660 x 646 x 395 u16), side by side in one
run: `layerwise flaws` through the binary vs the equivalent scipy.ndimage / scikit-image pipeline.

Usage (from the crate root):
    cargo build --release --features testkit --example flaws_bench_case --bin layerwise
    target/release/examples/flaws_bench_case benches/peers/out-flaws
    python3 benches/peers/flaws_vs_scipy.py [--out benches/peers/out-flaws] [--layerwise target/release/layerwise]

Both sides start from the files (ct.vol + ct.pcr) and run as child processes, so each one's time
includes reading the volume and its peak memory is its own (getrusage of the child):
  - ours: `layerwise flaws --registration ct.toml --out DIR` (Otsu, the part's 6-connected
    components, internal voids filled, 26-connected labels by union-find, clearance from the
    surface, partial-volume measures, flaws.csv/json/nrrd written), rayon on all cores;
  - peer: skimage.filters.threshold_otsu, the background labelled (6-connected) and the
    components not touching the border kept as internal voids (what binary_fill_holes computes,
    faster), scipy.ndimage.label with a 3x3x3 structure (26-connected), size >= 8 voxels,
    skimage.measure.regionprops (area, centroid, inertia tensor eigenvalues); single-threaded as
    scipy is.
The script creates benches/peers/.venv-flaws (numpy, scipy, scikit-image) on first use.
"""

import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from benchenv import ensure_venv  # noqa: E402


def run_child(cmd):
    """Runs cmd; returns (seconds, peak RSS MiB, stdout)."""
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out = p.stdout.read()
    err = p.stderr.read()
    _, status, usage = os.wait4(p.pid, 0)
    seconds = time.perf_counter() - t0
    if status != 0:
        sys.exit(f"{cmd} failed: {err.decode()}")
    return seconds, usage.ru_maxrss / 1024.0, out.decode()


def peer(out):
    import numpy as np
    from scipy import ndimage
    from skimage import filters, measure

    case = json.load(open(os.path.join(out, "truth.json")))
    x, y, z = case["dims"]
    t0 = time.perf_counter()
    vol = np.fromfile(os.path.join(out, "ct.vol"), dtype="<u2").reshape(z, y, x)
    t = filters.threshold_otsu(vol)
    material = vol >= t
    background, _ = ndimage.label(~material)
    faces = np.unique(np.concatenate([
        background[0].ravel(), background[-1].ravel(),
        background[:, 0].ravel(), background[:, -1].ravel(),
        background[:, :, 0].ravel(), background[:, :, -1].ravel()]))
    voids = (background > 0) & ~np.isin(background, faces)
    del background
    labels, n = ndimage.label(voids, structure=np.ones((3, 3, 3)))
    props = [p for p in measure.regionprops(labels, intensity_image=vol) if p.area >= 8]
    rows = [(p.label, p.area, p.centroid, p.inertia_tensor_eigvals) for p in props]
    seconds = time.perf_counter() - t0
    print(json.dumps({"flaws": len(rows), "components": int(n), "seconds_in_process": seconds}))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=os.path.join(HERE, "out-flaws"))
    ap.add_argument("--layerwise", default="target/release/layerwise")
    ap.add_argument("--peer", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    ensure_venv(os.path.join(HERE, ".venv-flaws"), ["numpy", "scipy", "scikit-image"])
    if args.peer:
        peer(args.out)
        return
    truth = json.load(open(os.path.join(args.out, "truth.json")))
    flaws_dir = os.path.join(args.out, "flaws")
    ours = run_child([args.layerwise, "flaws", "--registration",
                      os.path.join(args.out, "ct.toml"), "--out", flaws_dir])
    found = json.load(open(os.path.join(flaws_dir, "flaws.json")))["flaws"]
    theirs = run_child([sys.executable, os.path.abspath(__file__), "--peer", "--out", args.out])
    peer_result = json.loads(theirs[2].strip().splitlines()[-1])
    x, y, z = truth["dims"]
    print(f"case: {x} x {y} x {z} u16 voxels at {truth['voxel_mm']} mm, "
          f"{len(truth['voids'])} internal voids; {os.cpu_count()} cores")
    print(f"{'':34} {'seconds':>8} {'peak MiB':>9} {'flaws':>6}")
    print(f"{'layerwise flaws (binary)':34} {ours[0]:8.2f} {ours[1]:9.0f} {len(found):6d}")
    print(f"{'scipy.ndimage + scikit-image':34} {theirs[0]:8.2f} {theirs[1]:9.0f} "
          f"{peer_result['flaws']:6d}")
    print(f"ratio (peer / ours): {theirs[0] / ours[0]:.2f}x time, {theirs[1] / ours[1]:.2f}x memory")


if __name__ == "__main__":
    main()
