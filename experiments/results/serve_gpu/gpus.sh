#!/usr/bin/env bash
# `pachs serve` on N GPUs of the host (Warp; the server alone on GPUs 0..N-1), bench_serve.py
# at 10,000 evaluations per request, within one device command:
#   N = 1: one client alone, 16 clients at once (one instance each), requests of 30 and 150
#          episodes; then requests of 30 episodes at the task's budget (a second server);
#   N > 1: 16 clients at once and requests of 150 episodes, the batches split over the N GPUs.
#   OUT=dir bash experiments/results/serve_gpu/gpus.sh N [N ...]   (e.g. 1 2: one after another)
# The server warms only the buckets these requests use (1, 16 and 256; 16 and 256 for N > 1).
# Each N writes s/gpus<N>/ (and s/task_budget/ for N = 1), packed as $OUT/serve_gpus<N...>.tgz
# (serve_gpus1_2.tgz for `1 2`).
# BUDGET_S: the whole script's limit (570 s); GPU_OFFSET=g: GPUs g..g+N-1 (beside another job);
# SPLIT=threads: N > 1 GPUs share a batch in parts, one per GPU (pachs serve --split threads;
# written as s/gpus<N>-threads/; default mesh); MAX_WAIT_MS=m: pachs serve --max-wait-ms m (the
# window restarts at each request; written as s/gpus<N>[-threads]-wait<m>/); K=k: pachs serve -K k
# (edges per instance and iteration; written with -k<k> last).
set -u
if [ "$#" -lt 1 ]; then echo "usage: OUT=dir bash $0 N [N ...] (GPU counts)" >&2; exit 2; fi
END=$((SECONDS + ${BUDGET_S:-570}))
o=$OUT/s; mkdir -p "$o"
have=$(($(nvidia-smi -L | wc -l) - ${GPU_OFFSET:-0}))
export PYTHONFAULTHANDLER=1  # a server that dies in native code says where
BENCH="python3 experiments/bench_serve.py --task pusht-obs --backend warp"
for n in "$@"; do
  if [ "$n" -gt "$have" ]; then echo "gpus.sh: $n GPUs asked, the host has $have" >&2; continue; fi
  first=${GPU_OFFSET:-0}; visible=$(seq -s, $first $((first + n - 1)))
  name=gpus$n; extra=()
  if [ "$n" -gt 1 ] && [ "${SPLIT:-mesh}" != mesh ]; then name=gpus$n-$SPLIT; extra=(--split "$SPLIT"); fi
  if [ -n "${MAX_WAIT_MS:-}" ]; then name=$name-wait$MAX_WAIT_MS; extra+=(--max-wait-ms "$MAX_WAIT_MS"); fi
  if [ -n "${K:-}" ]; then name=$name-k$K; extra+=(-K "$K"); fi
  # the buckets these requests use (each takes 30-45 s to warm on an H200)
  if [ "$n" = 1 ]; then clients=1,16; big=30,150; buckets=1,16,256
  else clients=16; big=150; buckets=16,256; fi
  left=$((END - SECONDS)); [ "$left" -gt 0 ] || break  # timeout 0 would mean no limit
  CUDA_VISIBLE_DEVICES=$visible timeout "$left" $BENCH --budget 10000 \
    --clients $clients --requests 20 --max-batch 16 --big $big --devices "$n" --buckets $buckets \
    "${extra[@]}" --out "$o/$name" > "$o/$name.log" 2>&1
  echo "== $name: exit $?"; tail -n 12 "$o/$name.log"
  left=$((END - SECONDS))
  if [ "$n" = 1 ] && [ "$left" -gt 0 ]; then
    CUDA_VISIBLE_DEVICES=$first timeout "$left" $BENCH --clients '' --big 30 --buckets 32 \
      --max-batch 32 --out "$o/task_budget" > "$o/task_budget.log" 2>&1
    echo "== task budget: exit $?"; tail -n 6 "$o/task_budget.log"
  fi
done
cd "$OUT" && tar czf "serve_gpus$(IFS=_; echo "$*").tgz" s && rm -rf s
