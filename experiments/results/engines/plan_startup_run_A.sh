# plan start-up on the GPU: first run on this machine, cold, warm (profiled, plain, cProfile)
O=/tmp/o; mkdir -p $O
W="plan --task pusht-obs"
P="python3 experiments/profile_plan_startup.py --out $O/phases.jsonl"
wall() { local t0=$(date +%s%N); "$@"; local rc=$?; echo "WALL_MS $(( ($(date +%s%N)-t0)/1000000 )) rc $rc: $*" | tee -a $O/walls.txt >&2; }
plain() { python3 -c "from pachs_jax.cli import run; import sys; sys.argv=['pachs']+sys.argv[1:]; run()" $W; }
ls ~/.cache/warp 2>&1 | head -3
wall $P --label first_on_fresh_machine -- $W
rm -rf ~/.cache/pachs_jax .jaxcache
wall $P --label cold -- $W
wall $P --label warm -- $W
wall $P --label warm2 -- $W
wall plain > $O/plain_warm.txt
rm -rf ~/.cache/pachs_jax .jaxcache
wall plain > $O/plain_cold.txt
wall plain > $O/plain_warm2.txt
python3 -m cProfile -o /tmp/warm.prof experiments/profile_plan_startup.py --out /tmp/x.jsonl --label cprofile -- $W >/dev/null
python3 -c "import pstats; s=pstats.Stats('/tmp/warm.prof'); s.sort_stats('cumulative').print_stats(100); s.sort_stats('tottime').print_stats(40)" > $O/warm_cprofile.txt
du -sh ~/.cache/warp
