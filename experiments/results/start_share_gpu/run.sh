# Chains that restart at the start with probability 1/4 (else at novel cells) against the default
# and the parallel rollout, one call per layout and planner set, on one GPU with Warp physics:
# 150 runs per planner and layout at 100,000 evaluations. The --start-share option of
# open_loop.py left with the variant (it lost: docs/results.md, "Chains restarting at the start").
# run as: bash experiments/results/start_share_gpu/run.sh
source experiments/results/default_gpu_runs/common.sh
python3 -m compileall -q -j 16 /tmp/site > /dev/null 2>&1
for L in gate two-gaps detour; do
  LABEL=${L} wall $OL --layout $L --planners pachs-improve,parallel --out $O/${L}.json > $O/${L}.log 2>&1
  LABEL=${L}_start25 wall $OL --layout $L --planners pachs-improve --start-share 0.25 --out $O/${L}_start25.json > $O/${L}_start25.log 2>&1
  summ $O/${L}.json $O/${L}_start25.json
done
cd $OUT && tar czf r.tgz r && rm -rf r
