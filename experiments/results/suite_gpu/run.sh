# PACHS's PushT-Obs default and the parallel rollout on the suite layouts named (default: all
# five), one call per layout, one after another on one GPU with Warp physics: 150 runs per
# planner at 100,000 evaluations. A one-run call first compiles MuJoCo Warp's kernels, so that
# no timed call includes it. The README's headline reads these files.
# run as: bash experiments/results/suite_gpu/run.sh [LAYOUT ...]
source experiments/results/default_gpu_runs/common.sh
python3 -m compileall -q -j 16 /tmp/site > /dev/null 2>&1
END=$((SECONDS + 570))  # the calls share the device tool's 600 s
LABEL=warp_kernels wall $OL --layout slot --planners pachs-improve --instances 1 --rounds 1 \
  --budget 2000 --out /tmp/warp_kernels.json > $O/warp_kernels.log 2>&1
for L in ${@:-slot gate wall two-gaps detour}; do
  LABEL=$L wall timeout $((END - SECONDS)) $OL --layout $L --planners pachs-improve,parallel --out $O/$L.json > $O/$L.log 2>&1
  summ $O/$L.json
done
cat $O/walls.txt
cd $OUT && tar czf r.tgz r && rm -rf r
