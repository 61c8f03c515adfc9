#!/bin/bash
# Submits a causalcity dataset to Slurm: a job array of TASKS shards with CPUS
# cores each, then a merge (and validate) that runs only when every shard
# succeeded. Logs go to OUT/logs/, which validate accepts beside the dataset.
#
#   examples/slurm/submit.sh SPEC OUT [TASKS] [CPUS] [-- gen flags...]
#   examples/slurm/submit.sh configs/city.json /shared/city 4 2 -- --limit 50 --no-images
#
# TASKS defaults to 4 and CPUS to 1: ask for no more CPUs per task than one
# node has (`sinfo -o %c`), or the array pends for ever. Run it from the
# repository (paths are passed to the jobs as given; use absolute ones on a
# cluster whose nodes see another working directory).
set -euo pipefail

usage="usage: $0 SPEC OUT [TASKS] [CPUS] [-- gen flags...]"
SPEC=${1:?$usage}
OUT=${2:?$usage}
shift 2
TASKS=4
CPUS=1
if [[ $# -gt 0 && $1 != -- ]]; then TASKS=$1; shift; fi
if [[ $# -gt 0 && $1 != -- ]]; then CPUS=$1; shift; fi
if [[ $# -gt 0 && $1 == -- ]]; then shift; fi
if ! [[ $TASKS =~ ^[1-9][0-9]*$ && $CPUS =~ ^[1-9][0-9]*$ ]]; then
    echo "TASKS and CPUS must be positive whole numbers, got '$TASKS' and '$CPUS'; $usage" >&2
    exit 2
fi
[[ -f $SPEC ]] || { echo "no spec file '$SPEC'" >&2; exit 2; }

here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$OUT/logs"
gen=$(sbatch --parsable --array="0-$((TASKS - 1))" --cpus-per-task="$CPUS" \
    --output="$OUT/logs/gen-%A_%a.log" "$here/gen.sbatch" "$SPEC" "$OUT" "$@")
gen=${gen%%;*}
merge=$(sbatch --parsable --dependency="afterok:$gen" --kill-on-invalid-dep=yes \
    --output="$OUT/logs/merge-%j.log" "$here/merge.sbatch" "$OUT")
echo "submitted gen array $gen ($TASKS tasks x $CPUS CPUs) and merge $merge after it; logs in $OUT/logs/"
