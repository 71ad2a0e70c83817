# PACHS's PushT-Obs default and the parallel rollout on the five suite layouts, one call per
# layout, one after another on one GPU with Warp physics: 150 runs per planner at 100,000
# evaluations. The first call's wall includes MuJoCo Warp's kernel compile when the machine is
# fresh (its log says so). The README's headline reads these files.
# run as: bash experiments/results/suite_gpu/run.sh
source experiments/results/default_gpu_runs/common.sh
python3 -m compileall -q -j 16 /tmp/site > /dev/null 2>&1
END=$((SECONDS + 560))  # the calls share the device tool's 600 s
for L in slot gate wall two-gaps detour; do
  LABEL=$L wall timeout $((END - SECONDS)) $OL --layout $L --planners pachs-improve,parallel --out $O/$L.json > $O/$L.log 2>&1
  summ $O/$L.json
done
cat $O/walls.txt
cd $OUT && tar czf r.tgz r && rm -rf r
