#!/usr/bin/env bash
# Submit one Snakemake job script to a batch system (cluster-generic executor).
#
#   submit.sh --system SYSTEM [--mem-mb N] [--runtime MINUTES] [--threads N] [--name NAME] JOBSCRIPT
#
# SYSTEM: local  the local-batch stand-in (config/profiles/local-batch/): runs the
#                job in the background on this machine; for testing the scale-out path
#         pbs    OpenPBS / PBS Pro (qsub -l select=...); Torque users: see below
#         lsf    IBM Spectrum LSF (bsub)
# For SLURM use the slurm profile (the dedicated executor plugin) instead.
# Another system: add a case here and in status.sh and cancel.sh.
#
# Prints one line, the job id, prefixed with the system ("pbs:1234.server") so
# that status.sh and cancel.sh know whom to ask. pbs and lsf write the job's
# output under .snakemake/<system>-logs/; local writes under .snakemake/local-batch/.
# Only the local system has been run for real in this repository; the pbs and lsf
# command lines are checked against stand-in qsub/bsub in tests/test_profiles.py.
set -euo pipefail

usage() { echo "usage: $(basename "$0") --system local|pbs|lsf [--mem-mb N] [--runtime MINUTES] [--threads N] [--name NAME] JOBSCRIPT" >&2; exit 2; }

system=
mem_mb=1000
runtime=60
threads=1
name=job
while [[ $# -gt 1 ]]; do
    case $1 in
        --system) system=$2; shift 2 ;;
        --mem-mb) mem_mb=$2; shift 2 ;;
        --runtime) runtime=$2; shift 2 ;;
        --threads) threads=$2; shift 2 ;;
        --name) name=$2; shift 2 ;;
        *) usage ;;
    esac
done
[[ $# -eq 1 && -n $system ]] || usage
jobscript=$1
[[ -f $jobscript ]] || { echo "submit.sh: job script '$jobscript' does not exist" >&2; exit 1; }
for value in "$mem_mb" "$runtime" "$threads"; do
    [[ $value =~ ^[0-9]+$ ]] || { echo "submit.sh: memory, runtime and threads must be whole numbers, got '$value'" >&2; exit 2; }
done
name=smk.${name//[^A-Za-z0-9_.-]/_}
name=${name:0:60}
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)

case $system in
    local)
        id=$("$here/../local-batch/submit.sh" --mem-mb "$mem_mb" --runtime "$runtime" --threads "$threads" \
            --name "$name" "$jobscript")
        ;;
    pbs)
        logdir=$PWD/.snakemake/pbs-logs
        mkdir -p "$logdir"
        walltime=$(printf '%02d:%02d:00' $((runtime / 60)) $((runtime % 60)))
        # Torque: replace the select line with  -l nodes=1:ppn=$threads -l mem=${mem_mb}mb
        id=$(qsub -V -N "$name" -j oe -o "$logdir/" \
            -l "select=1:ncpus=$threads:mem=${mem_mb}mb" -l "walltime=$walltime" "$jobscript")
        ;;
    lsf)
        logdir=$PWD/.snakemake/lsf-logs
        mkdir -p "$logdir"
        # Memory in MB per job (whether rusage is per slot depends on the site's
        # RESOURCE_RESERVE_PER_TASK); span[hosts=1] keeps all threads on one host.
        out=$(bsub -J "$name" -n "$threads" -M "${mem_mb}MB" -R "rusage[mem=${mem_mb}MB] span[hosts=1]" \
            -W "$runtime" -o "$logdir/%J.log" < "$jobscript")
        id=$(sed -n 's/^Job <\([0-9][0-9]*\)>.*/\1/p' <<< "$out")
        [[ -n $id ]] || { echo "submit.sh: could not read a job id from bsub's answer: $out" >&2; exit 1; }
        ;;
    *)
        echo "submit.sh: unknown system '$system' (local, pbs or lsf)" >&2
        exit 2
        ;;
esac
id=$(head -n 1 <<< "$id" | tr -d '[:space:]')
[[ -n $id ]] || { echo "submit.sh: $system returned no job id" >&2; exit 1; }
echo "$system:$id"
