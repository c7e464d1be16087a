#!/usr/bin/env python3
"""What a model tolerates of another camera: `learn eval --part val` on its data's validation
frames after one change to every frame (resolution, field, blur, gain, tone curve, JPEG
compression, a quarter turn), each model side by side. Prints the table of docs/learning.md
("Frames of another camera"): per change and model, right / good layers called good / defect
frames called a defect.

The changed copies are written under a temporary folder (never into the repository) with the
same class folders and file names, so the validation part is the same frames.

Usage: python3 benches/learn_tolerance.py --model M1.safetensors [--model M2 ...]
           [--data ../shared/data/real/pblm] [--layerwise target/release/layerwise] [--keep DIR]

Creates benches/peers/.venv (pillow) on first use and re-runs inside it.
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "peers"))
from benchenv import ensure_venv  # noqa: E402

ensure_venv(os.path.join(HERE, "peers", ".venv"), ["pillow"])

from PIL import Image, ImageFilter  # noqa: E402


def tone(exponent):
    return lambda im: im.point(lambda v: int(255 * (v / 255) ** exponent))


def crop85(im):
    w, h = im.size
    dx, dy = int(w * 0.075), int(h * 0.075)
    return im.crop((dx, dy, w - dx, h - dy))


def crop85_left(im):
    """85 % of the side, the left edge kept (where pblm's uneven powder lies)."""
    w, h = im.size
    dy = int(h * 0.075)
    return im.crop((0, dy, int(w * 0.85), h - dy))


def wide85(im):
    """A wider field: the frame shrunk to 85 % in the middle of a black surround."""
    w, h = im.size
    small = im.resize((int(w * 0.85), int(h * 0.85)), Image.BILINEAR)
    out = Image.new("L", (w, h), 0)
    out.paste(small, ((w - small.width) // 2, (h - small.height) // 2))
    return out


# (name, what the docs call it, change, JPEG quality written)
CHANGES = [
    ("half", "half the resolution (bilinear)",
     lambda im: im.resize((im.width // 2, im.height // 2), Image.BILINEAR), 95),
    ("crop85", "the centre 85 % (a narrower field)", crop85, 95),
    ("crop85left", "85 % of the side, the left edge kept", crop85_left, 95),
    ("wide85", "a wider field: shrunk to 85 % in a black surround", wide85, 95),
    ("blur2", "Gaussian blur, radius 2 px", lambda im: im.filter(ImageFilter.GaussianBlur(2)), 95),
    ("gain06", "grey levels x 0.6", lambda im: im.point(lambda v: int(0.6 * v)), 95),
    ("gamma08", "tone curve `255 (v/255)^0.8`", tone(0.8), 95),
    ("gamma11", "tone curve, exponent 1.1", tone(1.1), 95),
    ("gamma12", "tone curve, exponent 1.2", tone(1.2), 95),
    ("gamma13", "tone curve, exponent 1.3", tone(1.3), 95),
    ("dark", "x 0.6, then exponent 1.3",
     lambda im: im.point(lambda v: int(255 * (0.6 * v / 255) ** 1.3)), 95),
    ("jpeg70", "JPEG quality 70", lambda im: im, 70),
    ("jpeg40", "JPEG quality 40", lambda im: im, 40),
    ("rot90", "turned a quarter (the streaks across instead of along)",
     lambda im: im.transpose(Image.ROTATE_90), 95),
]

PICTURES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")


def changed_copy(data, out, change, quality):
    for c in sorted(os.listdir(data)):
        src = os.path.join(data, c)
        if not os.path.isdir(src):
            continue
        os.makedirs(os.path.join(out, c), exist_ok=True)
        for f in sorted(os.listdir(src)):
            if f.lower().endswith(PICTURES):
                stem = os.path.splitext(f)[0]
                im = change(Image.open(os.path.join(src, f)).convert("L"))
                im.save(os.path.join(out, c, stem + ".jpg"), quality=quality)


def evaluate(exe, model, data):
    out = subprocess.run([exe, "learn", "eval", "--model", model, "--data", data, "--part", "val",
                          "--json"], check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def cell(report, normal):
    classes, c = report["classes"], report["confusion"]
    n = classes.index(normal)
    right = sum(c[i][i] for i in range(len(c)))
    defects = [i for i in range(len(c)) if i != n]
    flagged = sum(c[i][j] for i in defects for j in defects)
    return f"{right} / {c[n][n]} / {flagged}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", action="append", required=True)
    ap.add_argument("--data", default=os.path.join(HERE, "..", "..", "shared", "data", "real",
                                                    "pblm"))
    ap.add_argument("--layerwise", default=os.path.join(HERE, "..", "target", "release",
                                                         "layerwise"))
    ap.add_argument("--normal", default="No_Defect", help="the defect-free class")
    ap.add_argument("--keep", help="write the changed copies here and keep them")
    a = ap.parse_args()
    root = a.keep or tempfile.mkdtemp(prefix="layerwise-tolerance-")
    rows = [("as they are", [evaluate(a.layerwise, m, a.data) for m in a.model])]
    for name, label, change, quality in CHANGES:
        out = os.path.join(root, name)
        if not os.path.isdir(out):
            changed_copy(a.data, out, change, quality)
        rows.append((label, [evaluate(a.layerwise, m, out) for m in a.model]))
        print(f"{label}: done", file=sys.stderr, flush=True)
    first = rows[0][1][0]
    print(f"right of {sum(map(sum, first['confusion']))} / good layers called good / defect "
          "frames called a defect")
    print("| every frame | " + " | ".join(os.path.basename(m) for m in a.model) + " |")
    print("| --- |" + " --- |" * len(a.model))
    for label, reports in rows:
        print(f"| {label} | " + " | ".join(cell(r, a.normal) for r in reports) + " |")
    if not a.keep:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
