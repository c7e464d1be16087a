"""The Python side of the bench scripts: each runs inside a venv of its peer tools."""
import os
import subprocess
import sys
import venv


# The module each package is imported as, where the names differ.
IMPORT_NAMES = {"opencv-python-headless": "cv2", "pillow": "PIL"}


def ensure_venv(venv_dir, packages):
    """Re-executes the calling script inside venv_dir, creating it with packages when missing."""
    py = os.path.join(venv_dir, "bin", "python")
    if os.path.realpath(sys.prefix) == os.path.realpath(venv_dir):
        return
    if not os.path.exists(py):
        print("creating", venv_dir, flush=True)
        venv.create(venv_dir, with_pip=True)
    # A venv made by another script (they share one) may lack this script's packages.
    missing = [p for p in packages if subprocess.call(
        [py, "-c", f"import {IMPORT_NAMES.get(p, p)}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) != 0]
    if missing:
        subprocess.check_call([py, "-m", "pip", "install", "-q", *missing])
    os.execv(py, [py, os.path.abspath(sys.argv[0])] + sys.argv[1:])
