#!/usr/bin/env bash
# Cancel jobs submitted by submit.sh (Snakemake calls this on Ctrl-C).
#   cancel.sh SYSTEM:JOBID...
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
status=0
for job in "$@"; do
    id=${job#*:}
    case ${job%%:*} in
        local) "$here/../local-batch/cancel.sh" "$id" || status=1 ;;
        pbs) qdel "$id" || status=1 ;;
        lsf) bkill "$id" || status=1 ;;
        *) echo "cancel.sh: unknown system in job id '$job'" >&2; status=1 ;;
    esac
done
exit $status
