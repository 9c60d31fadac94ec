"""Scale-out profiles (config/profiles/): SLURM, generic cluster, and the local-batch stand-in.

The generic path is run for real: a tiny throwaway workflow goes through the
cluster-generic executor with the profile's submit/status scripts, whose `local`
system runs each job in the background on this machine. The PBS and LSF command
lines are checked against stand-in qsub/qstat/bsub/bjobs; the SLURM profile
can only be parsed here (its executor plugin is not installed).
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
PROFILES = REPO / "config" / "profiles"
GENERIC = PROFILES / "generic"
LOCAL_BATCH = PROFILES / "local-batch"
SNAKEMAKE = [sys.executable, "-m", "snakemake"]


def load_profile(name: str) -> dict:
    return yaml.safe_load((PROFILES / name / "config.yaml").read_text())


def run(cmd, cwd: Path, env: dict | None = None, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], cwd=cwd, env={**os.environ, **(env or {})},
                          capture_output=True, text=True, timeout=timeout, check=False)


def test_every_script_is_executable_and_strict():
    scripts = sorted(PROFILES.glob("*/*.sh"))
    assert {s.name for s in LOCAL_BATCH.glob("*.sh")} >= {"submit.sh", "status.sh", "cancel.sh", "run-job.sh"}
    assert {s.name for s in GENERIC.glob("*.sh")} >= {"submit.sh", "status.sh", "cancel.sh"}
    for script in scripts:
        assert os.access(script, os.X_OK), f"{script} is not executable"
        text = script.read_text()
        assert text.startswith("#!/usr/bin/env bash\n"), script
        assert "set -euo pipefail" in text, script
        assert run(["bash", "-n", script], cwd=REPO).returncode == 0, f"{script} has a syntax error"


def test_slurm_profile_has_the_required_keys():
    profile = load_profile("slurm")
    assert profile["executor"] == "slurm"
    resources = profile["default-resources"]
    assert isinstance(resources["mem_mb"], int) and isinstance(resources["runtime"], int)
    for key in ("jobs", "latency-wait", "retries"):
        assert isinstance(profile[key], int) and profile[key] >= 0, key
    assert profile["rerun-incomplete"] is True
    text = (PROFILES / "slurm" / "config.yaml").read_text()
    assert "pip install snakemake-executor-plugin-slurm" in text
    assert "slurm_partition" in text and "slurm_account" in text


def test_generic_profile_has_the_required_keys():
    profile = load_profile("generic")
    assert profile["executor"] == "cluster-generic"
    submit = profile["cluster-generic-submit-cmd"]
    for field in ("{resources.mem_mb}", "{resources.runtime}", "{threads}"):
        assert field in submit
    script = REPO / submit.split()[0]  # run from the repository root
    assert script == GENERIC / "submit.sh" and os.access(script, os.X_OK)
    for key in ("cluster-generic-status-cmd", "cluster-generic-cancel-cmd"):  # resolved next to config.yaml
        assert os.access(GENERIC / profile[key], os.X_OK), key
    resources = profile["default-resources"]
    assert isinstance(resources["mem_mb"], int) and isinstance(resources["runtime"], int)
    for key in ("jobs", "latency-wait", "retries"):
        assert isinstance(profile[key], int), key
    assert profile["rerun-incomplete"] is True


def test_every_rule_declares_threads_memory_and_runtime():
    """What the profiles pass to the batch system comes from the rules themselves."""
    missing = []
    rules = 0
    for smk in sorted((REPO / "workflow" / "rules").glob("*.smk")):
        blocks = re.split(r"^\s*rule (\w+):\s*$", smk.read_text(), flags=re.MULTILINE)
        for name, body in zip(blocks[1::2], blocks[2::2]):
            rules += 1
            for what, pattern in (("threads", r"^\s*threads:"), ("resources", r"^\s*resources:"),
                                  ("mem_mb", r"^\s*mem_mb\s*="), ("runtime", r"^\s*runtime\s*=")):
                if not re.search(pattern, body, flags=re.MULTILINE):
                    missing.append(f"{smk.name}: rule {name} lacks {what}")
    assert rules >= 7
    assert not missing, missing


# --- local-batch on its own ----------------------------------------------------------------------

def wait_for(status_of, job_id: str, timeout: float = 20) -> str:
    deadline = time.monotonic() + timeout
    while (state := status_of(job_id)) == "running" and time.monotonic() < deadline:
        time.sleep(0.1)
    return state


def test_local_batch_reports_success_failure_timeout_and_cancel(tmp_path):
    def submit(body: str, *options) -> str:
        script = tmp_path / f"job{len(list(tmp_path.glob('job*.sh')))}.sh"
        script.write_text(f"#!/bin/sh\n{body}\n")
        out = run([LOCAL_BATCH / "submit.sh", *options, script], cwd=tmp_path)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip()

    def status(job_id: str) -> str:
        out = run([LOCAL_BATCH / "status.sh", job_id], cwd=tmp_path)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip()

    ok = submit("echo hello", "--mem-mb", "100", "--runtime", "1", "--threads", "2", "--name", "ok")
    bad = submit("echo oops >&2; exit 3", "--name", "bad")
    slow = submit("sleep 30", "--runtime", "0.01", "--name", "slow")  # 0.6 s limit
    doomed = submit("sleep 30", "--name", "doomed")
    assert status(doomed) == "running"
    assert run([LOCAL_BATCH / "cancel.sh", doomed], cwd=tmp_path).returncode == 0

    assert [wait_for(status, j) for j in (ok, bad, slow, doomed)] == ["success", "failed", "failed", "failed"]
    root = tmp_path / ".snakemake" / "local-batch"
    assert "hello" in (root / ok / "job.log").read_text()
    assert "mem_mb=100\nruntime=1\nthreads=2\n" in (root / ok / "request").read_text()
    assert "oops" in (root / bad / "job.log").read_text()
    assert "runtime of 0.01 min exceeded" in (root / slow / "job.log").read_text()
    assert (root / slow / "exitcode").read_text().strip() == "124"
    assert status("no-such-job") == "failed"
    assert run([LOCAL_BATCH / "cancel.sh", "no-such-job"], cwd=tmp_path).returncode == 1
    assert run([LOCAL_BATCH / "submit.sh", "--mem-mb", "lots", tmp_path / "job0.sh"], cwd=tmp_path).returncode == 2


# --- PBS and LSF command lines, against stand-ins --------------------------------------------------

STUBS = {
    "qsub": 'echo "$@" > "$STUB_LOG/qsub"; echo 4242.pbs01',
    "qstat": '[ -f "$STUB_LOG/qstat.out" ] && cat "$STUB_LOG/qstat.out" || { echo "qstat: Unknown Job Id $3" >&2; exit 153; }',
    "qdel": 'echo "$@" >> "$STUB_LOG/qdel"',
    "bsub": 'echo "$@" > "$STUB_LOG/bsub"; cat > "$STUB_LOG/bsub.stdin"; echo "Job <777> is submitted to default queue <normal>."',
    "bjobs": '[ -f "$STUB_LOG/bjobs.out" ] && cat "$STUB_LOG/bjobs.out" || { echo "Job <$4> is not found" >&2; exit 255; }',
    "bkill": 'echo "$@" >> "$STUB_LOG/bkill"',
}


@pytest.fixture
def stubs(tmp_path):
    bin_dir, log = tmp_path / "bin", tmp_path / "log"
    bin_dir.mkdir()
    log.mkdir()
    for name, body in STUBS.items():
        (bin_dir / name).write_text(f"#!/bin/sh\n{body}\n")
        (bin_dir / name).chmod(0o755)
    env = {"PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "STUB_LOG": str(log)}
    jobscript = tmp_path / "jobscript.sh"
    jobscript.write_text("#!/bin/sh\n# properties = {}\necho job\n")
    return {"env": env, "log": log, "jobscript": jobscript, "cwd": tmp_path}


def generic(stubs, script: str, *args, ok: bool = True):
    out = run([GENERIC / script, *args], cwd=stubs["cwd"], env=stubs["env"])
    if ok:
        assert out.returncode == 0, out.stderr
    return out


def test_generic_submit_translates_resources_for_pbs_and_lsf(stubs):
    options = ["--mem-mb", "4000", "--runtime", "90", "--threads", "2", "--name", "register_expression"]
    out = generic(stubs, "submit.sh", "--system", "pbs", *options, stubs["jobscript"])
    assert out.stdout == "pbs:4242.pbs01\n"
    qsub = (stubs["log"] / "qsub").read_text().split()
    assert "select=1:ncpus=2:mem=4000mb" in qsub and "walltime=01:30:00" in qsub
    assert qsub[qsub.index("-N") + 1] == "smk.register_expression" and qsub[-1] == str(stubs["jobscript"])

    out = generic(stubs, "submit.sh", "--system", "lsf", *options, stubs["jobscript"])
    assert out.stdout == "lsf:777\n"
    bsub = (stubs["log"] / "bsub").read_text().split()
    assert bsub[bsub.index("-n") + 1] == "2" and bsub[bsub.index("-M") + 1] == "4000MB"
    assert bsub[bsub.index("-W") + 1] == "90"
    assert (stubs["log"] / "bsub.stdin").read_text() == stubs["jobscript"].read_text()

    assert generic(stubs, "submit.sh", "--system", "sge", stubs["jobscript"], ok=False).returncode == 2
    assert generic(stubs, "submit.sh", "--system", "pbs", "--mem-mb", "4G", stubs["jobscript"], ok=False).returncode == 2


@pytest.mark.parametrize("qstat, expected", [
    ("Job Id: 4242.pbs01\n    job_state = Q\n", "running"),
    ("Job Id: 4242.pbs01\n    job_state = R\n", "running"),
    ("Job Id: 4242.pbs01\n    job_state = F\n    Exit_status = 0\n", "success"),
    ("Job Id: 4242.pbs01\n    job_state = F\n    Exit_status = 271\n", "failed"),
    ("<Data><Job><job_state>C</job_state><exit_status>0</exit_status></Job></Data>", "success"),  # Torque -x
    ("<Data><Job><job_state>C</job_state><exit_status>-11</exit_status></Job></Data>", "failed"),
    (None, "failed"),  # purged from qstat
], ids=["queued", "running", "finished-ok", "finished-failed", "torque-ok", "torque-failed", "unknown"])
def test_generic_status_reads_pbs(stubs, qstat, expected):
    if qstat is not None:
        (stubs["log"] / "qstat.out").write_text(qstat)
    assert generic(stubs, "status.sh", "pbs:4242.pbs01").stdout == f"{expected}\n"


@pytest.mark.parametrize("bjobs, expected", [
    ("PEND\n", "running"), ("RUN\n", "running"), ("DONE\n", "success"), ("EXIT\n", "failed"), (None, "failed"),
], ids=["pending", "running", "done", "exit", "unknown"])
def test_generic_status_reads_lsf(stubs, bjobs, expected):
    if bjobs is not None:
        (stubs["log"] / "bjobs.out").write_text(bjobs)
    assert generic(stubs, "status.sh", "lsf:777").stdout == f"{expected}\n"


def test_generic_cancel_dispatches_by_system(stubs):
    generic(stubs, "cancel.sh", "pbs:4242.pbs01", "lsf:777", "lsf:778")
    assert (stubs["log"] / "qdel").read_text() == "4242.pbs01\n"
    assert (stubs["log"] / "bkill").read_text() == "777\n778\n"
    assert generic(stubs, "status.sh", "sge:1", ok=False).returncode == 2


# --- Snakemake through the profiles ---------------------------------------------------------------

TINY_SNAKEFILE = """
rule all:
    input: "c.txt"

rule a:
    output: "a.txt"
    threads: 1
    resources: mem_mb=100, runtime=1
    shell: "echo a > {output}"

rule b:
    output: "b.txt"
    threads: 1
    resources: mem_mb=100, runtime=1
    shell: "echo b > {output}"

rule c:
    input: "a.txt", "b.txt"
    output: "c.txt"
    threads: 2
    resources: mem_mb=150, runtime=1
    shell: "cat {input} > {output}"
"""


def test_tiny_workflow_runs_through_the_generic_profile_on_local_batch(tmp_path):
    pytest.importorskip("snakemake_executor_plugin_cluster_generic")
    (tmp_path / "Snakefile").write_text(TINY_SNAKEFILE)
    shutil.copytree(PROFILES, tmp_path / "config" / "profiles")  # the submit command is relative to the workdir
    out = run([*SNAKEMAKE, "--profile", "config/profiles/generic", "--jobs", "2", "--latency-wait", "5",
               "--retries", "0", "--seconds-between-status-checks", "1",
               "--default-resources", "mem_mb=100", "runtime=1"], cwd=tmp_path, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert (tmp_path / "c.txt").read_text() == "a\nb\n"
    assert len(re.findall(r"Submitted job \d+ with external jobid 'local:smk\.\w\.", out.stdout + out.stderr)) == 3

    jobs = {d.name.split(".")[1]: d for d in (tmp_path / ".snakemake" / "local-batch").iterdir()}
    assert sorted(jobs) == ["a", "b", "c"]  # `all` has no command and stays on the submitting host
    for job in jobs.values():
        assert (job / "exitcode").read_text().strip() == "0"
        assert "ended" in (job / "job.log").read_text()
    assert "mem_mb=150\nruntime=1\nthreads=2\n" in (jobs["c"] / "request").read_text()


def copy_workflow(tmp_path: Path) -> Path:
    shutil.copy(REPO / "Snakefile", tmp_path / "Snakefile")
    shutil.copytree(REPO / "workflow", tmp_path / "workflow")
    shutil.copytree(REPO / "config", tmp_path / "config")
    return tmp_path


def test_generic_profile_dry_runs_the_real_workflow(tmp_path):
    pytest.importorskip("snakemake_executor_plugin_cluster_generic")
    workdir = copy_workflow(tmp_path)
    out = run([*SNAKEMAKE, "-n", "--profile", "config/profiles/generic"], cwd=workdir)
    assert out.returncode == 0, out.stdout + out.stderr
    assert re.search(r"^register_expression\s+\d+$", out.stdout, flags=re.MULTILINE), out.stdout
    assert "This was a dry-run" in out.stdout
    assert not (workdir / ".snakemake" / "local-batch").exists()  # nothing was submitted


def test_slurm_profile_dry_runs_the_real_workflow(tmp_path):
    pytest.importorskip("snakemake_executor_plugin_slurm", reason="the SLURM executor plugin is not installed")
    workdir = copy_workflow(tmp_path)
    out = run([*SNAKEMAKE, "-n", "--profile", "config/profiles/slurm"], cwd=workdir)
    assert out.returncode == 0, out.stdout + out.stderr


def test_default_profile_keeps_the_schedulers_wake_ups_rare():
    """Snakemake's re-evaluation timer runs on the rate limit's timespan (profiles/default/config.yaml): at least
    10 s, at no lower an average rate than Snakemake's default of 100 jobs a second."""
    from snakemake.settings.types import MaxJobsPerTimespan

    profile = yaml.safe_load((REPO / "profiles" / "default" / "config.yaml").read_text())
    limit = MaxJobsPerTimespan.parse_choice(profile["max-jobs-per-timespan"])
    assert limit.timespan >= 10 and limit.max_jobs / limit.timespan >= 100
