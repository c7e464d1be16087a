#!/usr/bin/env python3
"""Signed distance of the same voxelised solid: ours (layerwise tsdf) vs SciPy vs scikit-fmm.

Usage (from the crate root):
    LAYERWISE_TSDF_ONESHOT=exact LAYERWISE_TSDF_WRITE=benches/peers/out cargo bench --bench tsdf
    python3 benches/peers/sdf_vs_scipy.py [--out benches/peers/out] [--skfmm-step N] [--skip-skfmm]

The Rust bench writes benches/peers/out/solid.u8 (1 inside, 0 outside, x fastest), solid.json (dims,
voxel size) and ours_<mode>.json (seconds, peak RSS of a fresh process). This script creates
benches/peers/.venv (numpy, scipy, scikit-fmm) on first use, then runs each method in a fresh
subprocess so that ru_maxrss is that method's own peak:
  - scipy:  scipy.ndimage.distance_transform_edt of the outside and of the inside (two EDTs),
            signed = outside distance - inside distance, in mm (sampling = voxel size);
  - skfmm:  skfmm.distance(phi, dx) with phi = -1 inside, +1 outside (the zero level set
            halfway between voxel centers).
Time is the method call alone (loading the mask excluded); peak memory is the whole process.
scikit-fmm takes minutes at 500x500x600: --skfmm-step 2 runs it on every second voxel
(250x250x300), and the table says so.
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
VENV = os.path.join(HERE, ".venv")
VENV_PY = os.path.join(VENV, "bin", "python")


def ensure_venv():
    """Re-executes this script inside benches/peers/.venv, creating it when missing."""
    if os.path.realpath(sys.prefix) == os.path.realpath(VENV):
        return
    if not os.path.exists(VENV_PY):
        subprocess.check_call([sys.executable, "-m", "venv", VENV])
        subprocess.check_call(
            [VENV_PY, "-m", "pip", "install", "-q", "numpy", "scipy", "scikit-fmm"]
        )
    os.execv(VENV_PY, [VENV_PY, os.path.abspath(__file__)] + sys.argv[1:])


def load(out_dir, step):
    import numpy as np

    with open(os.path.join(out_dir, "solid.json")) as f:
        meta = json.load(f)
    nx, ny, nz = meta["dims_xyz"]
    mask = np.fromfile(os.path.join(out_dir, "solid.u8"), dtype=np.uint8)
    # x fastest in the file: C order (z, y, x).
    mask = mask.reshape(nz, ny, nx).astype(bool)
    h = meta["voxel_mm"]
    if step > 1:
        mask = np.ascontiguousarray(mask[::step, ::step, ::step])
        h *= step
    return mask, h


def run_one(method, out_dir, step):
    """Runs one method in this (fresh) process and prints a JSON line."""
    mask, h = load(out_dir, step)
    if method == "scipy":
        from scipy import ndimage

        t0 = time.perf_counter()
        outside = ndimage.distance_transform_edt(~mask, sampling=h)
        inside = ndimage.distance_transform_edt(mask, sampling=h)
        sdf = outside - inside
        seconds = time.perf_counter() - t0
    elif method == "skfmm":
        import numpy as np
        import skfmm

        phi = np.where(mask, -1.0, 1.0)
        t0 = time.perf_counter()
        sdf = skfmm.distance(phi, dx=h)
        seconds = time.perf_counter() - t0
    else:
        raise SystemExit(f"unknown method {method}")
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # kB on Linux
    print(
        json.dumps(
            {
                "method": method,
                "dims_zyx": list(mask.shape),
                "voxel_mm": h,
                "seconds": seconds,
                "peak_rss_kb": peak_kb,
                "min": float(sdf.min()),
                "max": float(sdf.max()),
            }
        )
    )


def fresh(method, out_dir, step):
    res = subprocess.run(
        [sys.executable, os.path.abspath(__file__), "--run", method, "--out", out_dir,
         "--skfmm-step", str(step)],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(res.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=os.path.join(HERE, "out"))
    ap.add_argument("--run", help=argparse.SUPPRESS)
    ap.add_argument("--skfmm-step", type=int, default=1)
    ap.add_argument("--skip-skfmm", action="store_true")
    ap.add_argument("--skip-scipy", action="store_true")
    args = ap.parse_args()
    ensure_venv()
    if args.run:
        step = args.skfmm_step if args.run == "skfmm" else 1
        run_one(args.run, args.out, step)
        return

    ours = {}
    for name in sorted(os.listdir(args.out)):
        if name.startswith("ours_") and name.endswith(".json"):
            with open(os.path.join(args.out, name)) as f:
                r = json.load(f)
            ours[r["mode"]] = r
    if not ours:
        raise SystemExit(f"no ours_*.json in {args.out}: run the Rust bench first (see --help)")
    rows = []
    for mode, r in ours.items():
        rows.append((f"ours ({mode}, trunc {r['truncation_mm']} mm)", r["dims"], r["seconds"], r["peak_rss_kb"]))
    results = {}
    if not args.skip_scipy:
        results["scipy"] = fresh("scipy", args.out, 1)
    if not args.skip_skfmm:
        results["skfmm"] = fresh("skfmm", args.out, args.skfmm_step)
    for m, r in results.items():
        dims = list(reversed(r["dims_zyx"]))
        label = m if m != "skfmm" or args.skfmm_step == 1 else f"skfmm (every {args.skfmm_step}th voxel)"
        rows.append((label, dims, r["seconds"], r["peak_rss_kb"]))

    print(f"{'method':44} {'dims (x,y,z)':>18} {'time s':>9} {'peak MB':>9}")
    for label, dims, s, kb in rows:
        print(f"{label:44} {'x'.join(map(str, dims)):>18} {s:9.2f} {kb / 1024:9.0f}")
    if "scipy" in results:
        sc = results["scipy"]
        print("\nratios ours / scipy (target: <= 0.5 in both):")
        for mode, r in ours.items():
            print(
                f"  {mode:20} time {r['seconds'] / sc['seconds']:.3f}   peak memory "
                f"{r['peak_rss_kb'] / sc['peak_rss_kb']:.3f}"
            )
    if "skfmm" in results:
        sk = results["skfmm"]
        scale = args.skfmm_step ** 3
        note = "" if scale == 1 else f" (skfmm at 1/{scale} of the voxels)"
        print(f"\nratios ours / skfmm{note}:")
        for mode, r in ours.items():
            print(
                f"  {mode:20} time {r['seconds'] / sk['seconds']:.3f}   peak memory "
                f"{r['peak_rss_kb'] / sk['peak_rss_kb']:.3f}"
            )


if __name__ == "__main__":
    main()
