#!/usr/bin/env bash
# local-batch: a stand-in "batch system" that runs each job script in the
# background on this machine, so that the cluster-generic path (submit, poll,
# cancel) can be exercised without a cluster.
#
#   submit.sh [--mem-mb N] [--runtime MINUTES] [--threads N] [--name NAME] JOBSCRIPT
#
# Prints one line: the job id. Everything about the job lives in
#   $GPJA_LOCAL_BATCH_DIR/<id>/   (default: .snakemake/local-batch/<id>/ under the
#                                  current directory, i.e. Snakemake's working directory)
#     job.log       stdout + stderr of the job script
#     jobscript.sh  the spooled copy of the job script
#     request       what was asked for (memory, runtime, threads, name)
#     pid           pid of the wrapper (run-job.sh) while it runs
#     exitcode      written once, when the job script has ended (124: runtime exceeded)
# The runtime (minutes, decimals allowed) is enforced with `timeout`; 0 means no
# limit. Memory and threads are recorded, not enforced.
set -euo pipefail

usage() { echo "usage: $(basename "$0") [--mem-mb N] [--runtime MINUTES] [--threads N] [--name NAME] JOBSCRIPT" >&2; exit 2; }
number() { [[ $2 =~ ^[0-9]+([.][0-9]+)?$ ]] || { echo "local-batch: $1 must be a number, got '$2'" >&2; exit 2; }; }

mem_mb=1000
runtime=60
threads=1
name=job
while [[ $# -gt 1 ]]; do
    case $1 in
        --mem-mb) mem_mb=$2; shift 2 ;;
        --runtime) runtime=$2; shift 2 ;;
        --threads) threads=$2; shift 2 ;;
        --name) name=$2; shift 2 ;;
        *) usage ;;
    esac
done
[[ $# -eq 1 ]] || usage
jobscript=$1
[[ -f $jobscript && -r $jobscript ]] || { echo "local-batch: job script '$jobscript' does not exist or is not readable" >&2; exit 1; }
number --mem-mb "$mem_mb"
number --runtime "$runtime"
number --threads "$threads"
name=${name//[^A-Za-z0-9_.-]/_}

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
root=${GPJA_LOCAL_BATCH_DIR:-$PWD/.snakemake/local-batch}
mkdir -p "$root"
jobdir=$(mktemp -d "$root/${name:0:40}.XXXXXXXX")
id=$(basename "$jobdir")
cp "$jobscript" "$jobdir/jobscript.sh"
printf 'name=%s\nmem_mb=%s\nruntime=%s\nthreads=%s\njobscript=%s\nsubmitted=%s\n' \
    "$name" "$mem_mb" "$runtime" "$threads" "$jobscript" "$(date -Is)" > "$jobdir/request"

# Detach from Snakemake: new session (when setsid exists), no stdin, immune to hang-ups.
launcher=()
command -v setsid > /dev/null && launcher=(setsid)
"${launcher[@]}" nohup bash "$here/run-job.sh" "$jobdir" "$runtime" > "$jobdir/job.log" 2>&1 < /dev/null &

# Only hand out the id once the wrapper has recorded its pid, so status.sh never
# sees a job without one.
for _ in $(seq 200); do
    [[ -s $jobdir/pid || -f $jobdir/exitcode ]] && break
    sleep 0.05
done
[[ -s $jobdir/pid || -f $jobdir/exitcode ]] || { echo "local-batch: job $id did not start (see $jobdir/job.log)" >&2; exit 1; }
echo "$id"
