#!/usr/bin/env bash
# `pachs serve` on GPUs (Warp), each part alone on its GPU, within one device command:
#   GPU a: bench_serve.py (one client alone, 16 at once, requests of 30 and 150 episodes), its
#          server started by the benchmark;
#   GPU b: a server for LAYOUT, and the closed loop's protocol through it (closed_loop.py
#          --server: 20 instances x 5 rounds, 3 s queries, MuJoCo C worlds), to set beside the
#          in-process closed loop of closed_loop_gpu; then requests of 30 episodes to that
#          server, at the task's budget.
#   OUT=dir bash experiments/results/serve_gpu/run.sh [LAYOUT]   (GPU_OFFSET=n: a = n, b = n + 1)
# On a host of one GPU, a = b: the benchmark runs first (at most BENCH_S, 270 s), then the
# server and its closed loop.
set -u
layout=${1:-wall}
END=$((SECONDS + ${BUDGET_S:-570}))  # the device tool's 600 s, less packing
o=$OUT/r; mkdir -p "$o"
a=${GPU_OFFSET:-0}; b=$((a + 1))
limit=$((END - SECONDS))
if [ "$b" -ge "$(nvidia-smi -L | wc -l)" ]; then b=$a; limit=${BENCH_S:-270}; fi
CUDA_VISIBLE_DEVICES=$a timeout $limit python3 experiments/bench_serve.py \
  --task pusht-obs --backend warp --budget 10000 --clients 1,16 --requests 20 --max-batch 16 \
  --big 30,150 --out "$o/bench" > "$o/bench.log" 2>&1 &
bench=$!
[ "$b" = "$a" ] && wait $bench
CUDA_VISIBLE_DEVICES=$b python3 -m pachs_jax.cli serve --task pusht-obs --layout "$layout" \
  --backend warp --port 0 --max-batch 128 > "$o/server.log" 2>&1 &
server=$!
url=''
while [ -z "$url" ] && kill -0 $server 2>/dev/null && [ $SECONDS -lt $END ]; do
  sleep 1; url=$(grep -o 'ws://[^ ]*' "$o/server.log" | head -n 1)
done
if [ -n "$url" ]; then  # the client's own JAX stays off the server's GPU
  JAX_PLATFORMS=cpu timeout $((END - SECONDS)) python3 experiments/heldout_layouts.py \
    experiments/closed_loop.py --task pusht-obs --layout "$layout" --planners pachs \
    --server "$url" --out "$o/${layout}_pachs-served.json" > "$o/closed_loop.log" 2>&1
  # requests of 30 episodes at the task's budget, to the same server
  timeout $((END - SECONDS)) python3 experiments/bench_serve.py --task pusht-obs --url "$url" \
    --clients '' --big 30 --out "$o/bench_task_budget" > "$o/bench_task_budget.log" 2>&1
fi
kill -TERM $server 2>/dev/null; wait $server; wait $bench
tail -n 5 "$o/bench.log" "$o/closed_loop.log" "$o/server.log"
cd "$OUT" && tar czf serve.tgz r && rm -rf r
