"""The Python side of the bench scripts: each runs inside a venv of its peer tools."""
import os
import subprocess
import sys
import venv


def ensure_venv(venv_dir, packages):
    """Re-executes the calling script inside venv_dir, creating it with packages when missing."""
    py = os.path.join(venv_dir, "bin", "python")
    if os.path.realpath(sys.prefix) == os.path.realpath(venv_dir):
        return
    if not os.path.exists(py):
        print("creating", venv_dir, flush=True)
        venv.create(venv_dir, with_pip=True)
        subprocess.check_call([py, "-m", "pip", "install", "-q", *packages])
    os.execv(py, [py, os.path.abspath(sys.argv[0])] + sys.argv[1:])
