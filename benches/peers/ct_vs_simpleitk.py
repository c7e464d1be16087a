#!/usr/bin/env python3
"""CT-to-vectors registration on the same 50 µm synthetic case: ours (TSDF + Levenberg-Marquardt)
vs SimpleITK (Euler3DTransform, mean squares against the rasterised vectors, multi-resolution).

Usage (from the crate root):
    cargo run --release --example ct_bench_export -- benches/peers/out      # writes the case
    python3 benches/peers/ct_vs_simpleitk.py [--out benches/peers/out] [--sampling 0.02]

The Rust example writes benches/peers/out/ct.mha (the synthetic CT, u16, CT physical mm),
benches/peers/out/nominal.mha (binary raster of the nominal part in build mm, the "vectors as a
volume"), and case.json (truth, the 3-point start, our time and errors). This script creates
benches/peers/.venv (SimpleITK, numpy) on first use and registers CT (moving) to the raster (fixed):
  - intensities: the CT is mapped to 0..1 with the means of its two Otsu classes, so that mean
    squares against the 0/1 raster is meaningful (timed: it is part of the method);
  - Euler3DTransform centred on the part, started from the same 3-point Horn transform
    (inverted: SimpleITK maps fixed → moving, i.e. build → CT);
  - mean squares, linear interpolation, random sampling (--sampling of the fixed voxels),
    regular-step gradient descent with physical-shift scales, shrink 4/2/1, smoothing 2/1/0 vox.
Errors are measured as ours: rotation angle to the truth, and displacement at the part centre.
"""

import argparse
import json
import math
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
VENV = os.path.join(HERE, ".venv")


def ensure_venv():
    py = os.path.join(VENV, "bin", "python")
    if os.path.realpath(sys.executable) == os.path.realpath(py) or sys.prefix == VENV:
        return
    if not os.path.exists(py):
        subprocess.check_call([sys.executable, "-m", "venv", VENV])
        subprocess.check_call([py, "-m", "pip", "install", "-q", "SimpleITK", "numpy"])
    os.execv(py, [py] + sys.argv)


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(len(b))) for j in range(len(b[0]))] for i in range(len(a))]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=os.path.join(HERE, "out"))
    ap.add_argument("--sampling", type=float, default=0.02)
    ap.add_argument("--iterations", type=int, default=300)
    ap.add_argument("--plate-mask-mm", type=float, default=0.0,
                    help="leave out fixed voxels below this build z (SimpleITK's plate-side exclusion)")
    args = ap.parse_args()
    ensure_venv()
    import numpy as np
    import SimpleITK as sitk

    threads = int(os.environ.get("SITK_THREADS", "2"))
    sitk.ProcessObject.SetGlobalDefaultNumberOfThreads(threads)
    case = json.load(open(os.path.join(args.out, "case.json")))
    fixed = sitk.ReadImage(os.path.join(args.out, "nominal.mha"), sitk.sitkFloat32)
    moving_raw = sitk.ReadImage(os.path.join(args.out, "ct.mha"))

    t0 = time.perf_counter()
    moving = sitk.Cast(moving_raw, sitk.sitkFloat32)
    otsu = sitk.OtsuThresholdImageFilter()
    otsu.SetInsideValue(0)
    otsu.SetOutsideValue(1)
    labels = otsu.Execute(moving)
    stats = sitk.LabelStatisticsImageFilter()
    stats.Execute(moving, labels)
    bg, mat = stats.GetMean(0), stats.GetMean(1)
    moving = sitk.Cast((moving - bg) / (mat - bg), sitk.sitkFloat32)
    t_norm = time.perf_counter() - t0

    # Start: inverse of our 3-point transform (CT → build), centred on the part.
    s = case["start_ct_to_build"]
    r = [row[:3] for row in s[:3]]
    t = [row[3] for row in s[:3]]
    rinv = [[r[j][i] for j in range(3)] for i in range(3)]
    tinv = [-sum(rinv[i][k] * t[k] for k in range(3)) for i in range(3)]
    c = case["center_build_mm"]
    tx = sitk.Euler3DTransform()
    tx.SetCenter(c)
    tx.SetMatrix([v for row in rinv for v in row])
    rc = [sum(rinv[i][k] * c[k] for k in range(3)) for i in range(3)]
    tx.SetTranslation([rc[i] + tinv[i] - c[i] for i in range(3)])

    reg = sitk.ImageRegistrationMethod()
    reg.SetMetricAsMeanSquares()
    reg.SetMetricSamplingStrategy(reg.RANDOM)
    reg.SetMetricSamplingPercentage(args.sampling, 1)
    reg.SetInterpolator(sitk.sitkLinear)
    reg.SetOptimizerAsRegularStepGradientDescent(
        learningRate=0.5, minStep=1e-5, numberOfIterations=args.iterations,
        relaxationFactor=0.5, gradientMagnitudeTolerance=1e-10)
    reg.SetOptimizerScalesFromPhysicalShift()
    reg.SetShrinkFactorsPerLevel([4, 2, 1])
    reg.SetSmoothingSigmasPerLevel([2, 1, 0])
    reg.SmoothingSigmasAreSpecifiedInPhysicalUnitsOff()
    reg.SetInitialTransform(tx, inPlace=False)
    if args.plate_mask_mm > 0:
        # The analogue of our plate-side exclusion: sample the raster only above the slab.
        arr = np.zeros(sitk.GetArrayViewFromImage(fixed).shape, dtype=np.uint8)
        z0 = fixed.GetOrigin()[2]
        k = int(math.ceil((args.plate_mask_mm - z0) / fixed.GetSpacing()[2]))
        arr[max(k, 0):, :, :] = 1
        mask = sitk.GetImageFromArray(arr)
        mask.CopyInformation(fixed)
        reg.SetMetricFixedMask(mask)
    t1 = time.perf_counter()
    out = reg.Execute(fixed, moving)
    t_reg = time.perf_counter() - t1
    sitk_seconds = t_norm + t_reg

    # Errors as ours: T_sitk maps build → CT; the truth's inverse maps build → CT.
    truth = case["truth_ct_to_build"]
    rt = [row[:3] for row in truth[:3]]
    p0 = np.array(out.TransformPoint(c))
    m = np.column_stack([np.array(out.TransformPoint([c[0] + (i == 0), c[1] + (i == 1), c[2] + (i == 2)])) - p0
                         for i in range(3)])
    rot = m @ np.array(rt)  # ≈ I
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(rot) - 1) / 2))))
    disp_um = float(np.linalg.norm(p0 - np.array(case["center_ct_mm"]))) * 1e3

    ours = case["ours"]
    print(f"case: CT {case['ct_dims']} at {case['voxel_mm']} mm, raster {case['nominal_dims']}, "
          f"start {case['start_error']['rotation_deg']:.3f}° / {case['start_error']['displacement_um']:.1f} µm")
    print(f"{'method':<12}{'seconds':>10}{'rotation err (deg)':>22}{'displacement (µm)':>20}")
    print(f"{'ours':<12}{ours['seconds']:>10.2f}{ours['rotation_error_deg']:>22.5f}{ours['displacement_um']:>20.3f}")
    print(f"{'SimpleITK':<12}{sitk_seconds:>10.2f}{angle:>22.5f}{disp_um:>20.3f}")
    print(f"SimpleITK: normalise {t_norm:.2f} s + register {t_reg:.2f} s, "
          f"{reg.GetOptimizerIteration()} iterations at the last level, stop: {reg.GetOptimizerStopConditionDescription()}")
    print(f"time ratio SimpleITK / ours = {sitk_seconds / ours['seconds']:.1f}x; "
          f"rotation error ratio = {angle / max(ours['rotation_error_deg'], 1e-12):.0f}x, "
          f"displacement ratio = {disp_um / max(ours['displacement_um'], 1e-12):.0f}x")
    json.dump({"ours": ours, "simpleitk": {"seconds": sitk_seconds, "normalise_seconds": t_norm,
               "register_seconds": t_reg, "rotation_error_deg": angle, "displacement_um": disp_um,
               "sampling": args.sampling, "plate_mask_mm": args.plate_mask_mm, "threads": threads}},
              open(os.path.join(args.out, "comparison.json"), "w"), indent=2)


if __name__ == "__main__":
    main()
