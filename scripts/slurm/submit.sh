#!/usr/bin/env bash
# Runs an experiment on a Slurm cluster: a job array with one task per shard
# ('dhrbench run EXPERIMENT --shard K/N', each with the cores Slurm gives it), then a merge job
# that starts when every task has succeeded (--dependency=afterok) and writes OUT/results.json,
# frames.csv and report.md as one unsharded run would (README.md, "On a Slurm cluster").
#
#   scripts/slurm/submit.sh EXPERIMENT [options] [-- dhrbench run options, e.g. --set run.frames=30]
#     --shards N        tasks in the array (default 8; 'dhrbench validate EXPERIMENT --shards N'
#                       prints the plan: runs sharing traces stay in one shard)
#     --partition P     Slurm partition (default: the cluster's default)
#     --time T          time limit per task, as sbatch --time (default 4:00:00)
#     --cpus C          cores per task (default 4): dhrbench runs with --threads C
#     --mem M           memory per task, as sbatch --mem (default 8G)
#     --cache DIR       disk cache shared by the tasks ($DHR_CACHE_DIR; default: the repository's
#                       cache/): on a filesystem every node mounts, so that traces and ground
#                       truths are computed once
#     --out DIR         results folder (default out/<experiment file name>); the shards write
#                       DIR.shards/K/ and their logs DIR.shards/logs/
#     --only K[,K...]   submit only these shards (a rerun of failed ones) and the merge
#     --dhrbench PATH   the dhrbench binary (default build/experiments/dhrbench), on a shared filesystem
#     --sbatch ARG      one more sbatch option for every job (repeatable), e.g. --sbatch=--account=x
# Prints the array's and the merge job's ids. A failed task leaves the merge job pending
# (DependencyNeverSatisfied): 'scancel' it, then resubmit the failed shards with --only.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)

usage() { sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit "${1:-0}"; }
[ $# -ge 1 ] || usage 2
case "$1" in -h|--help) usage 0 ;; esac
experiment=$1
shift
shards=8 partition= time=4:00:00 cpus=4 mem=8G cache= out= only= dhrbench=$root/build/experiments/dhrbench
extra_sbatch=()
while [ $# -gt 0 ]; do
  case "$1" in
    --shards) shards=$2; shift 2 ;;
    --partition) partition=$2; shift 2 ;;
    --time) time=$2; shift 2 ;;
    --cpus) cpus=$2; shift 2 ;;
    --mem) mem=$2; shift 2 ;;
    --cache) cache=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    --only) only=$2; shift 2 ;;
    --dhrbench) dhrbench=$2; shift 2 ;;
    --sbatch=*) extra_sbatch+=("${1#--sbatch=}"); shift ;;
    --sbatch) extra_sbatch+=("$2"); shift 2 ;;
    --) shift; break ;;
    -h|--help) usage 0 ;;
    *) echo "submit.sh: unknown option '$1' (--help lists them)" >&2; exit 2 ;;
  esac
done
run_args=("$@")

die() { echo "submit.sh: $*" >&2; exit 2; }
[ -f "$experiment" ] || die "experiment file '$experiment' not found"
[ -x "$dhrbench" ] || die "'$dhrbench' is not an executable dhrbench (build it: bash scripts/build.sh build, or pass --dhrbench)"
[[ "$shards" =~ ^[1-9][0-9]*$ ]] && [ "$shards" -le 10000 ] || die "--shards '$shards': a whole number 1..10000"
[[ "$cpus" =~ ^[1-9][0-9]*$ ]] || die "--cpus '$cpus': a whole number of cores, 1 or more"
if [ -n "$only" ]; then
  [[ "$only" =~ ^[0-9]+(,[0-9]+)*$ ]] || die "--only '$only': shard numbers separated by commas, e.g. 3 or 2,5"
  for k in ${only//,/ }; do [ "$k" -ge 1 ] && [ "$k" -le "$shards" ] || die "--only: shard $k is not in 1..$shards"; done
fi
command -v sbatch >/dev/null || die "sbatch not found: run this on a Slurm login node"
# Validate here, before anything waits in a queue (every problem at once; the plan).
validate_args=()
for ((i = 0; i < ${#run_args[@]}; i++)); do
  case "${run_args[$i]}" in
    --set|--scene-path) validate_args+=("${run_args[$i]}" "${run_args[$((i + 1))]:-}"); i=$((i + 1)) ;;
    --set=*|--scene-path=*) validate_args+=("${run_args[$i]}") ;;
  esac
done
"$dhrbench" validate "$experiment" --shards "$shards" "${validate_args[@]}" >/dev/null

name=$(basename "$experiment" .json)
out=$(realpath -m "${out:-out/$name}")
dir=$out.shards
mkdir -p "$dir/logs"
common=(--parsable --time "$time" "${extra_sbatch[@]}")
[ -z "$partition" ] || common+=(--partition "$partition")
export DHR_CACHE_DIR=${cache:-${DHR_CACHE_DIR:-}}
[ -z "$DHR_CACHE_DIR" ] || mkdir -p "$DHR_CACHE_DIR"

array=$(sbatch "${common[@]}" --job-name "dhr-$name" --array "${only:-1-$shards}" --cpus-per-task "$cpus" --mem "$mem" \
  --export ALL --output "$dir/logs/shard_%a.log" \
  "$here/shard.sbatch" "$dhrbench" "$experiment" "$shards" "$dir" "${run_args[@]}")
array=${array%%;*}
merge=$(sbatch "${common[@]}" --job-name "dhr-$name-merge" --dependency "afterok:$array" --cpus-per-task 1 --mem 2G \
  --export ALL --output "$dir/logs/merge.log" \
  "$here/merge.sbatch" "$dhrbench" "$out" "$shards" "$dir")
merge=${merge%%;*}
echo "array job $array: shards ${only:-1-$shards} of $shards of $experiment (logs: $dir/logs/)"
echo "merge job $merge: after the array succeeds, writes $out/report.md"
