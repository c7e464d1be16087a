"""Checks a build's DICOM series with readers no one here wrote: pydicom and SimpleITK.

Usage: dicom_check.py DICOM_DIR EXPECTED_DIR
  DICOM_DIR     holds one sub-folder per series (e.g. post_top/L00001.dcm ...)
  EXPECTED_DIR  holds, per series, `<series>.json` with the contract the series must follow:
                {"x_min":..,"y_max":..,"pixel_mm":..,"rows":..,"columns":..,"z":{"<layer>":z_mm,...},
                 "thickness":..} and, for some layers, `<series>_L<layer>.u16` raw little-endian
                pixels that pydicom must read back exactly.
Prints one line per series and exits non-zero on the first disagreement.
"""
import json
import sys
from pathlib import Path

import numpy as np
import pydicom
import SimpleITK as sitk


def fail(msg):
    print("FAIL:", msg)
    sys.exit(1)


def main():
    dicom_dir, expected_dir = Path(sys.argv[1]), Path(sys.argv[2])
    studies, frames, dates = set(), set(), set()
    checked = 0
    for series_dir in sorted(p for p in dicom_dir.iterdir() if p.is_dir()):
        spec_path = expected_dir / f"{series_dir.name}.json"
        if not spec_path.exists():
            fail(f"no expectation for series {series_dir.name}")
        spec = json.loads(spec_path.read_text())
        reader = sitk.ImageSeriesReader()
        ids = reader.GetGDCMSeriesIDs(str(series_dir))
        if len(ids) != 1:
            fail(f"{series_dir}: {len(ids)} series ids, expected 1")
        names = reader.GetGDCMSeriesFileNames(str(series_dir), ids[0])
        reader.SetFileNames(names)
        volume = reader.Execute()
        size = volume.GetSize()
        layers = sorted(int(k) for k in spec["z"])
        if size != (spec["columns"], spec["rows"], len(layers)):
            fail(f"{series_dir.name}: SimpleITK size {size}, expected {(spec['columns'], spec['rows'], len(layers))}")
        sx, sy, sz = volume.GetSpacing()
        p = spec["pixel_mm"]
        if abs(sx - p) > 1e-6 or abs(sy - p) > 1e-6:
            fail(f"{series_dir.name}: spacing {sx},{sy} != {p}")
        # Index (column c, row r, slice s) must land where docs/frames.md says.
        zs = sorted(spec["z"][str(k)] for k in layers)
        for c, r in [(0, 0), (spec["columns"] - 1, 0), (3, spec["rows"] - 1)]:
            for s in range(len(layers)):
                x, y, z = volume.TransformIndexToPhysicalPoint((c, r, s))
                ex = spec["x_min"] + (c + 0.5) * p
                ey = spec["y_max"] - (r + 0.5) * p
                if abs(x - ex) > 1e-4 or abs(y - ey) > 1e-4:
                    fail(f"{series_dir.name}: index {(c, r, s)} at {(x, y)}, expected {(ex, ey)}")
                if not any(abs(z - ez) < 1e-4 for ez in zs):
                    fail(f"{series_dir.name}: slice {s} at z={z}, not a layer z {zs}")
        if len(layers) > 1 and abs(sz - abs(zs[1] - zs[0])) > 1e-4:
            fail(f"{series_dir.name}: z spacing {sz}, layers {zs[:2]}")
        # pydicom: attributes and pixels.
        for f in sorted(series_dir.glob("*.dcm")):
            ds = pydicom.dcmread(f)
            studies.add(ds.StudyInstanceUID)
            frames.add(ds.FrameOfReferenceUID)
            dates.add((ds.StudyDate, ds.StudyTime))
            layer = int(ds.InstanceNumber)
            if [float(v) for v in ds.ImageOrientationPatient] != [1, 0, 0, 0, -1, 0]:
                fail(f"{f}: ImageOrientationPatient {ds.ImageOrientationPatient}")
            pos = [float(v) for v in ds.ImagePositionPatient]
            want = [spec["x_min"] + p / 2, spec["y_max"] - p / 2, spec["z"][str(layer)]]
            if max(abs(a - b) for a, b in zip(pos, want)) > 1e-6:
                fail(f"{f}: ImagePositionPatient {pos}, expected {want}")
            if abs(float(ds.SliceLocation) - want[2]) > 1e-6:
                fail(f"{f}: SliceLocation {ds.SliceLocation}")
            if abs(float(ds.SliceThickness) - spec["thickness"]) > 1e-6:
                fail(f"{f}: SliceThickness {ds.SliceThickness}")
            if ds.ImageType[2] != "AXIAL" or ds.ImageLaterality != "U" or ds.RescaleType != "US":
                fail(f"{f}: ImageType/ImageLaterality/RescaleType {ds.ImageType} {ds.ImageLaterality} {ds.RescaleType}")
            for keyword in ["KVP", "PatientSex", "PatientPosition"]:
                if keyword not in ds:
                    fail(f"{f}: {keyword} missing")
            raw = expected_dir / f"{series_dir.name}_L{layer:05}.u16"
            if raw.exists():
                expected = np.fromfile(raw, dtype="<u2").reshape(spec["rows"], spec["columns"])
                if not np.array_equal(ds.pixel_array, expected):
                    diff = np.abs(ds.pixel_array.astype(int) - expected.astype(int))
                    fail(f"{f}: pixels differ from what was rectified (max diff {diff.max()})")
                checked += 1
        print(f"ok {series_dir.name}: {size[2]} slices {size[0]}x{size[1]}, SimpleITK geometry and pydicom attributes agree")
    if len(studies) != 1 or len(frames) != 1 or len(dates) != 1:
        fail(f"one study, one frame of reference and one StudyDate/Time expected: {studies} {frames} {dates}")
    if checked == 0:
        fail("no pixels were compared")
    print(f"ok: one study, one frame of reference, {checked} slices bit-exact")


if __name__ == "__main__":
    main()
