#!/bin/bash
# Runs independent jobs side by side, one per GPU of the host: line i of JOBS runs with
# CUDA_VISIBLE_DEVICES=i (a line may chain commands with &&), its output in LOGDIR/gpu<i>.log.
# TIMEOUT_S (optional) stops each line after that many seconds; scripts that write their results
# as they go keep what they finished. Waits for all lines. GPU_OFFSET=n starts at GPU n (two job
# scripts side by side on one host).
#   bash experiments/parallel_gpus.sh JOBS LOGDIR [TIMEOUT_S]
# or, from a job script that exports a function FN (NAME -> one command line) and what it reads,
# one line per GPU of comma-separated names, their commands run one after another:
#   bash experiments/parallel_gpus.sh --lines FN LOGDIR TIMEOUT_S LINE [LINE ...]
set -u
if [ "$1" = --lines ]; then
  fn=$2; logdir=$3; limit=$4; shift 4
  mkdir -p "$logdir"; jobs=$logdir/jobs.txt; : > "$jobs"
  for line in "$@"; do
    commands=()
    IFS=',' read -ra names <<< "$line"
    for name in "${names[@]}"; do commands+=("$("$fn" "$name")"); done
    (IFS=';'; echo "${commands[*]}") >> "$jobs"
  done
  cat "$jobs"
else
  jobs=$1; logdir=$2; limit=${3:-0}
fi
mkdir -p "$logdir"
i=0
while IFS= read -r line || [ -n "$line" ]; do
  [ -z "$line" ] && continue
  (
    export CUDA_VISIBLE_DEVICES=$((i + ${GPU_OFFSET:-0}))
    if [ "$limit" -gt 0 ]; then timeout "$limit" bash -c "$line"; else bash -c "$line"; fi
    echo "exit status $?"
  ) > "$logdir/gpu$((i + ${GPU_OFFSET:-0})).log" 2>&1 &
  i=$((i + 1))
done < "$jobs"
wait
tail -n 3 "$logdir"/gpu*.log
