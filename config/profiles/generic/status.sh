#!/usr/bin/env bash
# Print the state of one job submitted by submit.sh, as the cluster-generic
# executor expects it: one line, `running`, `success` or `failed`.
#   status.sh SYSTEM:JOBID
# A job the batch system no longer knows counts as failed (with a note on stderr).
set -euo pipefail

[[ $# -eq 1 && $1 == *:* ]] || { echo "usage: $(basename "$0") SYSTEM:JOBID" >&2; exit 2; }
system=${1%%:*}
id=${1#*:}
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)

case $system in
    local)
        exec "$here/../local-batch/status.sh" "$id"
        ;;
    pbs)
        # OpenPBS/PBS Pro: -x also lists finished jobs (state F). Torque: -x means XML,
        # and finished jobs stay listed as state C for keep_completed seconds.
        info=$(qstat -x -f "$id" 2> /dev/null || qstat -f "$id" 2> /dev/null || true)
        # `key = value` lines (qstat -f), or XML (Torque's qstat -x)
        state=$(sed -n -e 's/^ *job_state *= *\([A-Z]\).*/\1/p' \
            -e 's/.*<job_state>\([A-Z]\)<\/job_state>.*/\1/p' <<< "$info")
        exit_status=$(sed -n -e 's/^ *[Ee]xit_status *= *\(-\{0,1\}[0-9][0-9]*\).*/\1/p' \
            -e 's/.*<exit_status>\(-\{0,1\}[0-9][0-9]*\)<\/exit_status>.*/\1/p' <<< "$info")
        state=${state%%$'\n'*}
        exit_status=${exit_status%%$'\n'*}
        case $state in
            F | C) if [[ $exit_status == 0 ]]; then echo success; else echo failed; fi ;;
            "") echo "status.sh: qstat does not know PBS job $id" >&2; echo failed ;;
            *) echo running ;;
        esac
        ;;
    lsf)
        state=$(bjobs -noheader -o stat "$id" 2> /dev/null | head -n 1 | tr -d '[:space:]' || true)
        case $state in
            DONE) echo success ;;
            EXIT | ZOMBI) echo failed ;;
            PEND | RUN | PSUSP | USUSP | SSUSP | WAIT | PROV | UNKWN) echo running ;;
            *) echo "status.sh: bjobs does not know LSF job $id (got '$state')" >&2; echo failed ;;
        esac
        ;;
    *)
        echo "status.sh: unknown system '$system' in job id '$1'" >&2
        exit 2
        ;;
esac
