"""How many threads a job's native libraries use, set when each library is first imported.

Jobs sharing a machine otherwise oversubscribe it: torch's OpenMP workers spin while they wait, so two jobs of
2 threads on 2 cores run several times slower. :func:`limit_threads` sets torch's, numba's and OpenCV's thread
counts. A library already imported is set at once; one not yet imported is set right after its import
completes, by a finder on ``sys.meta_path`` that wraps that one module's loader. So a job that never renders
(tables, figures from saved images, the glTF export) does not pay for importing torch (about 1.6 s) only to
limit threads it never starts.

Why not environment variables (``OMP_NUM_THREADS``, ``NUMBA_NUM_THREADS``) set before the imports: numpy's
bundled OpenBLAS reads ``OMP_NUM_THREADS`` as well, so its thread count, and with it the last bits of its
products, would change with ``--threads``; torch's and numba's own calls change nothing else.
"""
from __future__ import annotations

import importlib.abc
import sys
from types import ModuleType
from typing import Callable


def limit_torch(module: ModuleType, n: int) -> None:
    module.set_num_threads(n)


def limit_numba(module: ModuleType, n: int) -> None:
    module.set_num_threads(min(n, module.config.NUMBA_NUM_THREADS))


def limit_cv2(module: ModuleType, n: int) -> None:
    module.setNumThreads(n)  # the flow stage's DIS optical flow (gpja.register.flow)


#: Each library whose threads :func:`limit_threads` sets, with the call that sets them (module, n).
LIMITS: dict[str, Callable[[ModuleType, int], None]] = {"torch": limit_torch, "numba": limit_numba,
                                                        "cv2": limit_cv2}


class AfterImport(importlib.abc.MetaPathFinder):
    """A ``sys.meta_path`` finder that runs ``action(module)`` once a named top-level module has been executed.

    It finds nothing itself: for a watched name it asks the finders after it for the spec, wraps that spec's
    loader's ``exec_module`` (the loader object is the spec's own) and then forgets the name. Every other
    import passes through untouched.
    """

    def __init__(self, actions: dict[str, Callable[[ModuleType], None]]):
        self.actions = dict(actions)

    def find_spec(self, name, path, target=None):
        action = self.actions.get(name)
        if action is None:
            return None
        spec = None
        for finder in sys.meta_path:
            find = getattr(finder, "find_spec", None)
            if finder is not self and find is not None:
                spec = find(name, path, target)
                if spec is not None:
                    break
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        del self.actions[name]
        if not self.actions and self in sys.meta_path:
            sys.meta_path.remove(self)
        execute = spec.loader.exec_module

        def exec_module(module: ModuleType) -> None:
            execute(module)
            # what ``import name`` returns: a package may put another object there (cv2's loader does)
            action(sys.modules.get(name, module))

        spec.loader.exec_module = exec_module
        return spec


def limit_threads(n: int) -> None:
    """Use at most ``n`` (>= 1) threads in torch, numba and OpenCV, now for those already imported, at their
    import for the others (module docstring)."""
    if n < 1:
        raise ValueError(f"threads must be at least 1, got {n}")
    later = {}
    for name, limit in LIMITS.items():
        if name in sys.modules:
            limit(sys.modules[name], n)
        else:
            later[name] = (lambda module, limit=limit: limit(module, n))
    for finder in [f for f in sys.meta_path if isinstance(f, AfterImport)]:
        sys.meta_path.remove(finder)  # a second call replaces the first's pending limits
    if later:
        sys.meta_path.insert(0, AfterImport(later))
