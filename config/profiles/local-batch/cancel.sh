#!/usr/bin/env bash
# local-batch: cancel jobs (Snakemake calls this on Ctrl-C with one or more ids).
#   cancel.sh JOBID...
# The wrapper forwards the signal to the job; the job then counts as failed.
set -euo pipefail

root=${GPJA_LOCAL_BATCH_DIR:-$PWD/.snakemake/local-batch}
status=0
for id in "$@"; do
    pidfile=$root/$id/pid
    if [[ $id =~ ^[A-Za-z0-9_.-]+$ && -s $pidfile && ! -f $root/$id/exitcode ]]; then
        kill -TERM "$(< "$pidfile")" 2> /dev/null || true
    elif [[ ! $id =~ ^[A-Za-z0-9_.-]+$ || ! -d $root/$id ]]; then
        echo "local-batch: no job '$id' under $root" >&2
        status=1
    fi
done
exit $status
