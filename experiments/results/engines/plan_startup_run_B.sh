# after the fixes: plan first/cold/warm walls on a fresh machine, a profile, live lanes
O=/tmp/o; mkdir -p $O
W="plan --task pusht-obs"
wall() { local t0=$(date +%s%N); "$@"; local rc=$?; echo "WALL_MS $(( ($(date +%s%N)-t0)/1000000 )) rc $rc: $LABEL" | tee -a $O/walls.txt >&2; }
plain() { python3 -c "from pachs_jax.cli import run; import sys; sys.argv=['pachs']+sys.argv[1:]; run()" $W; }
P="python3 experiments/profile_plan_startup.py --out $O/phases.jsonl"
LABEL=compileall wall python3 -m compileall -q -j 16 /tmp/site pachs_jax >/dev/null
ls ~/.cache/warp 2>&1 | head -2
LABEL=first_on_fresh_machine wall plain > $O/plain_first.txt 2> $O/plain_first.err
rm -rf ~/.cache/pachs_jax .jaxcache
LABEL=cold wall plain > $O/plain_cold.txt 2>&1
for i in 1 2 3; do LABEL=warm$i wall plain > $O/plain_warm$i.txt 2>&1; done
LABEL=warm_profiled wall $P --label warm -- $W > /dev/null 2>&1
LABEL=warm_no_prealloc XLA_PYTHON_CLIENT_PREALLOCATE=false wall plain > $O/plain_warm_noprealloc.txt 2>&1
rm -rf ~/.cache/pachs_jax .jaxcache
LABEL=cold_profiled wall $P --label cold -- $W > /dev/null 2>&1
LABEL=warm4 wall plain > $O/plain_warm4.txt 2>&1
LABEL=live_lanes wall timeout 200 python3 experiments/live_lanes.py --layout two-gaps --backend warp --out $O/live_lanes_two-gaps_warp.json
