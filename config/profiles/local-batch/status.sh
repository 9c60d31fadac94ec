#!/usr/bin/env bash
# local-batch: print the state of one job as Snakemake's cluster-generic executor
# expects it: exactly one line, `running`, `success` or `failed`.
#   status.sh JOBID
# A job whose wrapper is gone without an exit code (killed, machine rebooted) and
# an unknown id both count as failed (with a note on stderr).
set -euo pipefail

[[ $# -eq 1 ]] || { echo "usage: $(basename "$0") JOBID" >&2; exit 2; }
id=$1
root=${GPJA_LOCAL_BATCH_DIR:-$PWD/.snakemake/local-batch}
jobdir=$root/$id

if [[ ! $id =~ ^[A-Za-z0-9_.-]+$ || ! -d $jobdir ]]; then
    echo "local-batch: no job '$id' under $root" >&2
    echo failed
elif [[ -f $jobdir/exitcode ]]; then
    if [[ $(< "$jobdir/exitcode") == 0 ]]; then echo success; else echo failed; fi
elif [[ -s $jobdir/pid ]] && kill -0 "$(< "$jobdir/pid")" 2> /dev/null; then
    echo running
elif [[ -f $jobdir/exitcode ]]; then  # ended between the two checks above
    if [[ $(< "$jobdir/exitcode") == 0 ]]; then echo success; else echo failed; fi
else
    echo "local-batch: job '$id' ended without an exit code (see $jobdir/job.log)" >&2
    echo failed
fi
