# The comparison of run.sh again with search seed 1, on the second instance set for detour and
# wall, and on both held-out layouts; three calls at a time on one GPU (walls are upper bounds).
# Runs at its revision only, as run.sh.
# run as: bash experiments/results/novelty_power_gpu/run_seed1.sh
source experiments/results/default_gpu_runs/common.sh
python3 -m compileall -q -j 16 /tmp/site > /dev/null 2>&1
export XLA_PYTHON_CLIENT_PREALLOCATE=false
one() {  # one() LAYOUT NAME [flags]: one open_loop call, its log and wall
  local L=$1 N=$2; shift 2
  local RUN=$OL; case $L in gate-mirror|wall-right) RUN=$HO;; esac
  LABEL=$N wall $RUN --layout $L --seed 1 "$@" --out $O/$N.json > $O/$N.log 2>&1
}
export -f one wall; export O OL HO
printf '%s\n' \
  "detour detour_set1_seed1 --instance-seed 1 --planners pachs-improve,parallel" \
  "detour detour_set1_seed1_power05 --instance-seed 1 --planners pachs-improve --novelty-power 0.5" \
  "wall wall_set1_seed1 --instance-seed 1 --planners pachs-improve,parallel" \
  "wall wall_set1_seed1_power05 --instance-seed 1 --planners pachs-improve --novelty-power 0.5" \
  "two-gaps two-gaps_seed1 --planners pachs-improve,parallel" \
  "two-gaps two-gaps_seed1_power05 --planners pachs-improve --novelty-power 0.5" \
  "gate-mirror gate-mirror_seed1 --planners pachs-improve,parallel" \
  "gate-mirror gate-mirror_seed1_power05 --planners pachs-improve --novelty-power 0.5" \
  "wall-right wall-right_seed1 --planners pachs-improve,parallel" \
  "wall-right wall-right_seed1_power05 --planners pachs-improve --novelty-power 0.5" \
  | timeout 540 xargs -P 3 -I{} bash -c 'one {}'
summ $O/*.json; cat $O/walls.txt
cd $OUT && tar czf r.tgz r && rm -rf r
