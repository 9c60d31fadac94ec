"""Time a job's start: a fresh interpreter that limits its threads (``gpja --threads 1``) and runs a command that
never renders, with the limits set at import (``gpja.threads.limit_threads``, the default) against importing
torch, numba and OpenCV up front to set them (the start before it), alternating, side by side in one run.

The command is ``gpja --threads 1 tables`` on an empty results folder: it parses its arguments, limits its
threads, looks for the first metrics file and stops with an error (exit status 2), as a job that reads JSON and
writes tables would up to its real work.

Prints JSON: the median seconds of each over ``--repeats``, their difference and ratio.
Usage: python benchmarks/bench_startup.py [--repeats 7]
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time

#: The start before the lazy limits: every library imported so that its threads can be set.
EAGER = "import cv2, numba, torch; "
COMMAND = ("import sys; from gpja.cli import main; "
           "status = main(['--threads', '1', 'tables', '--results', {d!r}, '--benchmarks', {d!r}, '--subjects', "
           "'S01', '--expressions', '1_neutral', '--methods', 'gpja', '--output-dir', {d!r} + '/tables']); "
           "sys.exit(0 if status == 2 else 1)")


def run(code: str) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        lazy = COMMAND.format(d=folder)
        codes = {"lazy": lazy, "eager": EAGER + lazy}
        run(codes["eager"])  # warm the file cache once
        times: dict[str, list[float]] = {name: [] for name in codes}
        for _ in range(args.repeats):
            for name, code in codes.items():
                times[name].append(run(code))
    median = {name: statistics.median(t) for name, t in times.items()}
    print(json.dumps({"command": "gpja --threads 1 tables (stops at the first missing metrics file)",
                      "repeats": args.repeats,
                      "lazy_s": round(median["lazy"], 3), "eager_s": round(median["eager"], 3),
                      "saved_s": round(median["eager"] - median["lazy"], 3),
                      "ratio": round(median["lazy"] / median["eager"], 3)}, indent=1))


if __name__ == "__main__":
    main()
