#!/usr/bin/env bash
# local-batch wrapper (started by submit.sh): run one spooled job script, enforce
# its runtime, and record the pid and the exit code for status.sh.
#   run-job.sh JOBDIR RUNTIME_MINUTES
set -euo pipefail

jobdir=$1
runtime=$2
echo $$ > "$jobdir/pid.tmp"
mv "$jobdir/pid.tmp" "$jobdir/pid"
echo "local-batch: job $(basename "$jobdir") started $(date -Is) on $(hostname) (pid $$)"

child=
forward() { [[ -n $child ]] && kill -TERM "$child" 2> /dev/null || true; }
trap forward TERM INT HUP

if [[ $runtime != 0 ]] && command -v timeout > /dev/null; then
    # timeout forwards TERM to the job and kills it 30 s later if it is still there.
    timeout --kill-after=30 "${runtime}m" bash "$jobdir/jobscript.sh" &
else
    bash "$jobdir/jobscript.sh" &
fi
child=$!

# A trapped signal interrupts `wait` (status > 128) while the job may still be
# running: wait again until it has really ended.
while :; do
    if wait "$child"; then rc=0; else rc=$?; fi
    if (( rc > 128 )) && kill -0 "$child" 2> /dev/null; then continue; fi
    break
done

[[ $rc -eq 124 ]] && echo "local-batch: runtime of ${runtime} min exceeded, job killed"
echo "local-batch: job $(basename "$jobdir") ended $(date -Is) with exit code $rc"
echo "$rc" > "$jobdir/exitcode.tmp"
mv "$jobdir/exitcode.tmp" "$jobdir/exitcode"
