#!/usr/bin/env bash
# The closed loop through `pachs serve` on one GPU (Warp), within one device command: a server
# for LAYOUT, the closed loop's protocol through it (closed_loop.py --server: 20 instances x 5
# rounds, 3 s queries, MuJoCo C worlds; the server's K that of 3 s queries, as in process), to
# set beside the in-process closed loop of closed_loop_gpu; then requests of 30 episodes to
# that server at the task's budget (bench_serve.py --url). One bucket, the one every batch of the closed loop takes, so that no
# smaller bucket's warm-up while idle delays a query. The latency and throughput benchmark on 1
# and N GPUs: gpus.sh.
#   OUT=dir bash experiments/results/serve_gpu/run.sh [LAYOUT]   (GPU_OFFSET=n: on GPU n)
set -u
layout=${1:-wall}
END=$((SECONDS + ${BUDGET_S:-570}))  # the device tool's 600 s, less packing
o=$OUT/r; mkdir -p "$o"
export PYTHONFAULTHANDLER=1  # a server that dies in native code says where
CUDA_VISIBLE_DEVICES=${GPU_OFFSET:-0} python3 -m pachs_jax.cli serve --task pusht-obs \
  --layout "$layout" --backend warp --port 0 --max-batch 128 --buckets 128 --query-time 3 \
  > "$o/server.log" 2>&1 &
server=$!
url=''
while [ -z "$url" ] && kill -0 $server 2>/dev/null && [ $SECONDS -lt $END ]; do
  sleep 1; url=$(grep -o 'ws://[^ ]*' "$o/server.log" | head -n 1)
done
left() {  # seconds left, at least 1 (timeout 0 would mean no limit)
  local s=$((END - SECONDS)); [ "$s" -gt 0 ] && echo "$s" || echo 1
}
if [ -n "$url" ]; then  # the client's own JAX stays off the server's GPU
  JAX_PLATFORMS=cpu timeout "$(left)" python3 experiments/heldout_layouts.py \
    experiments/closed_loop.py --task pusht-obs --layout "$layout" --planners pachs \
    --server "$url" --out "$o/${layout}_pachs-served.json" > "$o/closed_loop.log" 2>&1
  timeout "$(left)" python3 experiments/bench_serve.py --task pusht-obs --url "$url" \
    --clients '' --big 30 --out "$o/bench_task_budget" > "$o/bench_task_budget.log" 2>&1
fi
kill -TERM $server 2>/dev/null; wait $server
tail -n 5 "$o/closed_loop.log" "$o/bench_task_budget.log" "$o/server.log"
cd "$OUT" && tar czf serve.tgz r && rm -rf r
