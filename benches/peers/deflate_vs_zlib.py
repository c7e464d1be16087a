#!/usr/bin/env python3
"""Side-by-side: layerwise's deflated DICOM slice encode vs zlib and pydicom.

Creates benches/peers/.venv-dicom (pydicom, numpy) on first use and re-runs itself inside it.
examples/peer_steps.rs renders a D810-size mock frame and rectifies its luma onto the 4400 x 4400
plate grid; every side then deflates the same samples (16-bit little endian, as the slice stores
them):

- ours: `peer_steps deflate` (the whole deflated CT slice file in memory, on all cores);
- zlib: `zlib.compressobj(level, DEFLATED, -15)` of the pixel data alone, level 1 (the level our
  encoder used before) and level 6 (zlib's default, which pydicom's writer uses);
- pydicom: `dcmwrite` of a data set with the same pixel data and the deflated transfer syntax.

Each timing is the median of 5 runs; the whole comparison is repeated (--rounds, default 3).
Our file is read back with pydicom and its pixels compared with the input.

Usage: python3 benches/peers/deflate_vs_zlib.py [--rounds N]
(from the crate root; honours CARGO_TARGET_DIR)
"""
import os
import subprocess
import sys

from benchenv import ensure_venv

HERE = os.path.dirname(os.path.abspath(__file__))
CRATE = os.path.dirname(os.path.dirname(HERE))
VENV = os.path.join(HERE, ".venv-dicom")

ensure_venv(VENV, ["pydicom", "numpy"])

import io  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
import zlib  # noqa: E402

import numpy as np  # noqa: E402
import pydicom  # noqa: E402
from pydicom.dataset import Dataset, FileMetaDataset  # noqa: E402
from pydicom.uid import DeflatedExplicitVRLittleEndian, generate_uid  # noqa: E402

N = 4400


def median_ms(f):
    times, out = [], None
    for _ in range(5):
        t = time.perf_counter()
        out = f()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times), out


def zlib_deflate(data, level):
    c = zlib.compressobj(level, zlib.DEFLATED, -15)
    return c.compress(data) + c.flush()


def pydicom_write(pixels):
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.2"
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = DeflatedExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID = meta.MediaStorageSOPClassUID
    ds.SOPInstanceUID = meta.MediaStorageSOPInstanceUID
    ds.Rows, ds.Columns = N, N
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
    ds.PixelData = pixels.tobytes()
    buf = io.BytesIO()
    pydicom.dcmwrite(buf, ds, enforce_file_format=True)
    return buf.getvalue()


def ours(exe, raw, out):
    res = subprocess.run([exe, "deflate", raw, str(N), str(N), out],
                         check=True, capture_output=True, text=True)
    kv = dict(ln.split("=", 1) for ln in res.stdout.splitlines() if "=" in ln)
    return float(kv["encode_ms_median"]), int(kv["bytes"])


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
    raw = os.path.join(work, "rectified.raw")
    out = os.path.join(work, "ours.dcm")
    samples = np.fromfile(raw, dtype=np.uint8).reshape(N, N)
    pixels = samples.astype("<u2")
    data = pixels.tobytes()

    ours_ms, ours_bytes = ours(exe, raw, out)
    back = pydicom.dcmread(out).pixel_array
    same = back.shape == pixels.shape and bool(np.array_equal(back, pixels))
    print(f"zlib {zlib.ZLIB_RUNTIME_VERSION}, pydicom {pydicom.__version__}, cores {os.cpu_count()}; "
          f"{N}x{N} samples ({len(data) / 1e6:.1f} MB); our file read back by pydicom: "
          f"{'pixels identical' if same else 'PIXELS DIFFER'}")
    peers = [
        ("zlib level 1", lambda: zlib_deflate(data, 1)),
        ("zlib level 6", lambda: zlib_deflate(data, 6)),
        ("pydicom dcmwrite", lambda: pydicom_write(pixels)),
    ]
    results = {name: [] for name, _ in peers}
    ours_times = []
    for _ in range(rounds):
        o, _ = ours(exe, raw, out)
        ours_times.append(o)
        for name, f in peers:
            ms, packed = median_ms(f)
            results[name].append((ms, len(packed)))
    o_med = statistics.median(ours_times)
    print(f"[ours] median rounds: {o_med:.1f} ms, {ours_bytes / 1e6:.2f} MB")
    for name, rs in results.items():
        p_med = statistics.median(r[0] for r in rs)
        print(f"[{name}] median rounds: ours {o_med:.1f} ms, peer {p_med:.1f} ms, "
              f"ratio {o_med / p_med:.2f}; size ours {ours_bytes / 1e6:.2f} MB, peer {rs[0][1] / 1e6:.2f} MB")
    for p in (raw, out, os.path.join(work, "frame.jpg")):
        os.remove(p)


if __name__ == "__main__":
    main()
