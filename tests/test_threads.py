"""gpja.threads: thread limits set at import time, so jobs that never render do not import torch."""
import subprocess
import sys
import textwrap

import pytest

from gpja.threads import AfterImport, limit_threads


def run_python(code: str) -> str:
    """Run ``code`` in a fresh interpreter (this one has torch imported already); its stdout, stripped."""
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_after_import_runs_the_action_once_on_the_executed_module(tmp_path, monkeypatch):
    (tmp_path / "tiny_watched.py").write_text("VALUE = 41\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    seen = []
    finder = AfterImport({"tiny_watched": lambda module: seen.append(module.VALUE + 1)})
    monkeypatch.setattr(sys, "meta_path", [finder, *sys.meta_path])
    import json  # noqa: F401  (an import the finder does not watch passes through)

    import tiny_watched

    assert seen == [42]
    assert tiny_watched.VALUE == 41
    assert finder not in sys.meta_path  # nothing left to watch: it took itself out
    sys.modules.pop("tiny_watched")
    import tiny_watched  # noqa: F811  (a second import runs nothing again)

    assert seen == [42]
    sys.modules.pop("tiny_watched")


def test_limits_are_set_when_the_libraries_are_imported_later():
    out = run_python("""
        import sys
        from gpja.threads import AfterImport, limit_threads
        limit_threads(1)
        before = [name in sys.modules for name in ("torch", "numba", "cv2")]
        import cv2, numba, torch
        left = [f for f in sys.meta_path if isinstance(f, AfterImport)]
        print(before, torch.get_num_threads(), numba.get_num_threads(), cv2.getNumThreads(), len(left))
    """)
    assert out == "[False, False, False] 1 1 1 0"


def test_limits_are_set_at_once_for_libraries_already_imported():
    out = run_python("""
        import sys
        import torch
        from gpja.threads import AfterImport, limit_threads
        limit_threads(1)
        pending = [sorted(f.actions) for f in sys.meta_path if isinstance(f, AfterImport)]
        print(torch.get_num_threads(), pending)
    """)
    assert out == "1 [['cv2', 'numba']]"


def test_a_job_that_does_not_render_does_not_import_torch(tmp_path):
    # `gpja tables` on a run without metrics: it limits its threads, then stops with an error naming the file
    out = run_python(f"""
        import sys
        from gpja.cli import main
        status = main(["--threads", "1", "tables", "--results", "{tmp_path}", "--benchmarks", "{tmp_path}",
                       "--subjects", "S01", "--expressions", "1_neutral", "--methods", "gpja",
                       "--output-dir", "{tmp_path / 'tables'}"])
        print(status, "torch" in sys.modules, "numba" in sys.modules)
    """)
    assert out == "2 False False"


def test_fewer_than_one_thread_is_an_error():
    with pytest.raises(ValueError, match="at least 1"):
        limit_threads(0)
