#!/usr/bin/env python3
"""Side-by-side: layerwise's NEF path vs LibRaw (rawpy) on the same D810 NEF.

Creates benches/peers/.venv-raw (rawpy, numpy) on first use and re-runs itself inside it.
examples/nef_luminance.rs writes a full-size D810 NEF of the demo plate (7380 x 4928,
lossless compressed) and times what the view series need of it: decode, then linear
luminance on the default crop. LibRaw does the same job its way: unpack, then
postprocess with bilinear demosaicing, camera white balance, sRGB primaries, linear
16-bit output, no auto-brightening, and Rec. 709 luminance mixed in numpy.

Both run with their default threads. Each timing is the median of 5 runs; the whole
comparison is repeated (--rounds, default 2) alternating the two tools.

Agreement: LibRaw keeps the whole sensor, so its luminance is cropped to the D810
default crop (12, 8, 7360 x 4912) and compared by the best single gain (least
squares; 1 when both scale by the same white level) and the mean residual after it.

Usage: python3 benches/peers/nef_vs_rawpy.py [--rounds N]   (from the crate root)
"""
import os
import subprocess
import sys
import tempfile

from benchenv import ensure_venv

HERE = os.path.dirname(os.path.abspath(__file__))
CRATE = os.path.dirname(os.path.dirname(HERE))
VENV = os.path.join(HERE, ".venv-raw")


ensure_venv(VENV, ["rawpy", "numpy"])

import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import rawpy  # noqa: E402

CROP_X, CROP_Y, W, H = 12, 8, 7360, 4912


def ours(exe, nef, out):
    line = subprocess.check_output([exe, "time", nef, out], text=True).strip()
    fields = dict(kv.split("=") for kv in line.split())
    y = np.fromfile(out, dtype="<u2").reshape(int(fields["height"]), int(fields["width"]))
    return float(fields["decode_ms_median"]), float(fields["luminance_ms_median"]), y


def libraw(nef):
    unpack, develop = [], []
    y = None
    for _ in range(5):
        t = time.perf_counter()
        raw = rawpy.imread(nef)
        raw.raw_image_visible  # forces the unpack
        t1 = time.perf_counter()
        rgb = raw.postprocess(
            demosaic_algorithm=rawpy.DemosaicAlgorithm.LINEAR,
            output_bps=16,
            gamma=(1, 1),
            no_auto_bright=True,
            use_camera_wb=True,
            output_color=rawpy.ColorSpace.sRGB,
            user_flip=0,
        )
        y = rgb.astype(np.float32) @ np.float32([0.2126, 0.7152, 0.0722])
        t2 = time.perf_counter()
        unpack.append((t1 - t) * 1e3)
        develop.append((t2 - t1) * 1e3)
        raw.close()
    return statistics.median(unpack), statistics.median(develop), y


def main():
    rounds = 2
    if "--rounds" in sys.argv:
        rounds = int(sys.argv[sys.argv.index("--rounds") + 1])
    target = os.environ.get("CARGO_TARGET_DIR", os.path.join(CRATE, "target"))
    print("building examples/nef_luminance (release) ...", flush=True)
    subprocess.check_call(["cargo", "build", "--release", "--quiet", "--example", "nef_luminance"],
                          cwd=CRATE)
    exe = os.path.join(target, "release", "examples", "nef_luminance")
    with tempfile.TemporaryDirectory() as tmp:
        nef = os.path.join(tmp, "plate.nef")
        subprocess.check_call([exe, "write", nef])
        print(f"NEF: {os.path.getsize(nef) / 1e6:.1f} MB", flush=True)
        results = []
        for r in range(rounds):
            o_dec, o_lum, y_ours = ours(exe, nef, os.path.join(tmp, "y.u16"))
            l_dec, l_lum, y_libraw = libraw(nef)
            results.append((o_dec + o_lum, l_dec + l_lum))
            print(f"round {r + 1}: layerwise decode {o_dec:.0f} ms + luminance {o_lum:.0f} ms = "
                  f"{o_dec + o_lum:.0f} ms; LibRaw unpack {l_dec:.0f} ms + postprocess and "
                  f"luminance {l_lum:.0f} ms = {l_dec + l_lum:.0f} ms; "
                  f"ratio LibRaw / layerwise {(l_dec + l_lum) / (o_dec + o_lum):.2f}", flush=True)
        best = min(results, key=lambda t: t[0] + t[1])
        print(f"best round: layerwise {best[0]:.0f} ms, LibRaw {best[1]:.0f} ms, "
              f"LibRaw / layerwise {best[1] / best[0]:.2f}")
        # Agreement away from the crop's edge rows and columns.
        a = y_ours.astype(np.float64)[2:-2, 2:-2]
        b = y_libraw[CROP_Y:CROP_Y + H, CROP_X:CROP_X + W].astype(np.float64)[2:-2, 2:-2]
        gain = float((a * b).sum() / (b * b).sum())
        resid = np.abs(a - gain * b).mean() / a.mean()
        print(f"agreement: layerwise = {gain:.4f} x LibRaw; mean |residual| after that gain "
              f"{resid * 100:.2f}% of the mean luminance")


if __name__ == "__main__":
    main()
