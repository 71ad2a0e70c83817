# pachs plan --task pusht-obs start-up on one GPU with the installed packages' bytecode compiled
# (as pip installs them; the GPU machine's wheels come unpacked with --no-compile): imports before
# and after compileall, then the machine's first run, cold and warm x3. Output: $OUT/d.tgz
O=$OUT/d; mkdir -p $O
W="plan --task pusht-obs"
wall() { local t0=$(date +%s%N); "$@"; local rc=$?; echo "WALL_MS $(( ($(date +%s%N)-t0)/1000000 )) rc $rc: $LABEL" | tee -a $O/walls.txt >&2; }
plain() { python3 -c "from pachs_jax.cli import run; import sys; sys.argv=['pachs']+sys.argv[1:]; run()" $W; }
imports() { python3 -X importtime -c "import pachs_jax.cli, pachs_jax.planner" 2>&1 | tail -1; }
python3 -c "import sys; print('dont_write_bytecode', sys.flags.dont_write_bytecode)" | tee $O/env.txt
echo "pyc files before: $(find /tmp/site -name '*.pyc' | wc -l)" | tee -a $O/env.txt
for i in 1 2; do LABEL=import_$i wall imports >> $O/imports.txt; done
python3 -m compileall -q -j 16 /tmp/site > /dev/null 2>&1
echo "pyc files after compileall: $(find /tmp/site -name '*.pyc' | wc -l)" | tee -a $O/env.txt
for i in 1 2 3; do LABEL=import_compiled_$i wall imports >> $O/imports.txt; done
LABEL=first_on_fresh_machine wall plain > $O/first.txt 2>&1
rm -rf ~/.cache/pachs_jax .jaxcache
LABEL=cold wall plain > $O/cold.txt 2>&1
for i in 1 2 3; do LABEL=warm$i wall plain > $O/warm$i.txt 2>&1; done
cat $O/env.txt $O/imports.txt; tail -n 1 $O/first.txt $O/cold.txt $O/warm*.txt
cd $OUT && tar czf d.tgz d && rm -rf d
