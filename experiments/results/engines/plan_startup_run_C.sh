# pachs plan --task pusht-obs start-up on one GPU: the machine's first run (Warp compiles its
# kernels), cold (JAX cache and stored programs emptied, Warp kernels cached), warm x3, then the
# phases of a cold and two warm runs (bench_startup.py profile). Output: $OUT/c.tgz
O=$OUT/c; mkdir -p $O
W="plan --task pusht-obs"
wall() { local t0=$(date +%s%N); "$@"; local rc=$?; echo "WALL_MS $(( ($(date +%s%N)-t0)/1000000 )) rc $rc: $LABEL" | tee -a $O/walls.txt >&2; }
plain() { python3 -c "from pachs_jax.cli import run; import sys; sys.argv=['pachs']+sys.argv[1:]; run()" $W; }
P="python3 experiments/bench_startup.py profile --out $O/phases.json"
ls ~/.cache/warp 2>&1 | head -2
LABEL=first_on_fresh_machine wall plain > $O/first.txt 2>&1
rm -rf ~/.cache/pachs_jax .jaxcache
LABEL=cold wall plain > $O/cold.txt 2>&1
for i in 1 2 3; do LABEL=warm$i wall plain > $O/warm$i.txt 2>&1; done
rm -rf ~/.cache/pachs_jax .jaxcache
LABEL=cold_profiled wall $P --label cold -- $W > $O/cold_profiled.txt 2>&1
LABEL=warm_profiled1 wall $P --label warm -- $W > $O/warm_profiled1.txt 2>&1
LABEL=warm_profiled2 wall $P --label warm2 -- $W > $O/warm_profiled2.txt 2>&1
python3 -X importtime -c "import pachs_jax.cli, pachs_jax.planner" 2> $O/importtime.txt
tail -n 2 $O/*.txt | cut -c1-300
cd $OUT && tar czf c.tgz c && rm -rf c
