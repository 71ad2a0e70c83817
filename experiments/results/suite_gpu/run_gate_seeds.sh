# The default and the parallel rollout on gate with search seeds 1 and 2, one call after another
# on one GPU with Warp physics; the first call's wall includes Warp's kernel compile on a fresh
# machine.
# run as: bash experiments/results/suite_gpu/run_gate_seeds.sh
source experiments/results/default_gpu_runs/common.sh
python3 -m compileall -q -j 16 /tmp/site > /dev/null 2>&1
END=$((SECONDS + 280))  # what is left of this session's device time
for s in 1 2; do
  LABEL=gate_seed$s wall timeout $((END - SECONDS)) $OL --layout gate --seed $s \
    --planners pachs-improve,parallel --out $O/gate_seed$s.json > $O/gate_seed$s.log 2>&1
  summ $O/gate_seed$s.json
done
cat $O/walls.txt
cd $OUT && tar czf r.tgz r && rm -rf r
