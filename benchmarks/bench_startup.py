"""Time a job's start: a fresh interpreter that limits its threads (``gpja --threads 1``) and runs a command that
never renders, with the limits set at import (``gpja.threads.limit_threads``, the default) against importing
torch, numba and OpenCV up front to set them (the start before it), alternating, side by side in one run.

The command is ``gpja --threads 1 tables`` on an empty results folder: it parses its arguments, limits its
threads, looks for the first metrics file and stops with an error (exit status 2), as a job that reads JSON and
writes tables would up to its real work.

A second pair times Open3D's import in a job that queries a surface (a registration, a metrics job, NICP):
``gpja.surface.load_open3d`` (its visualisation package, with plotly and dash, deferred; the default) against
``import open3d``, each followed by one closest-point query, fresh interpreters alternating with the first pair.

Prints JSON: the median seconds of each over ``--repeats``, their differences and ratios.
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


#: A job that queries a surface, with Open3D's visualisation deferred (the default) and imported (before it).
QUERY = ("import numpy as np; from gpja.surface import closest_points, prepare_surface; "
         "closest_points(prepare_surface(np.eye(3), np.array([[0, 1, 2]])), np.zeros((1, 3)))")
OPEN3D = {"deferred": QUERY, "plain": "import open3d; " + QUERY}


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
        codes = {"lazy": lazy, "eager": EAGER + lazy, **OPEN3D}
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
                      "ratio": round(median["lazy"] / median["eager"], 3),
                      "open3d": {"command": "a closest-point query in a fresh interpreter",
                                 "deferred_s": round(median["deferred"], 3), "plain_s": round(median["plain"], 3),
                                 "saved_s": round(median["plain"] - median["deferred"], 3),
                                 "ratio": round(median["deferred"] / median["plain"], 3)}}, indent=1))


if __name__ == "__main__":
    main()
