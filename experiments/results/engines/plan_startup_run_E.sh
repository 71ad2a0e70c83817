# pachs plan --task pusht-obs warm start-up on one GPU with and without the first transfer to
# the device in a thread beside the imports (cli.first_transfer), alternating, 4 runs each, after
# the machine's first run (Warp compiles its kernels) and a cold run. Output: $OUT/e.tgz
O=$OUT/e; mkdir -p $O
W="plan --task pusht-obs"
wall() { local t0=$(date +%s%N); "$@"; local rc=$?; echo "WALL_MS $(( ($(date +%s%N)-t0)/1000000 )) rc $rc: $LABEL" | tee -a $O/walls.txt >&2; }
with() { python3 -c "from pachs_jax.cli import run; import sys; sys.argv=['pachs']+sys.argv[1:]; run()" $W; }
without() { python3 -c "from pachs_jax import cli; cli.first_transfer = lambda: None; import sys; sys.argv=['pachs']+sys.argv[1:]; cli.run()" $W; }
python3 -m compileall -q -j 16 /tmp/site > /dev/null 2>&1  # as pip compiles on install
LABEL=first_on_fresh_machine wall with > $O/first.txt 2>&1
rm -rf ~/.cache/pachs_jax .jaxcache
LABEL=cold wall with > $O/cold.txt 2>&1
for i in 1 2 3 4; do
  LABEL=without$i wall without > $O/without$i.txt 2>&1
  LABEL=with$i wall with > $O/with$i.txt 2>&1
done
tail -n 1 $O/*.txt | grep -E "found|WALL"
cd $OUT && tar czf e.tgz e && rm -rf e
