"""The package's exception types.

Every problem with user-supplied input (files, configs, arrays) raises
:class:`InputError`, whose message starts with the offending file so a user
of the workflow can find it from the log alone.
"""
from __future__ import annotations

from pathlib import Path


class GpjaError(Exception):
    """Base class of every error raised on purpose by gpja."""


class InputError(GpjaError, ValueError):
    """Bad input: a missing or corrupt file, an inconsistent value, wrong units.

    Args:
        path: the file (or logical source, e.g. ``"config"``) the problem is in.
        problem: what is wrong, in words a user can act on.
    """

    def __init__(self, path: str | Path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")
