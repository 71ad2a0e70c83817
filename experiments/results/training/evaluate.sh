#!/usr/bin/env bash
# The retrained PushT models (left in /tmp by run.sh on this machine) measured on the default
# (faithful) physics with Warp: the policy alone, then PACHS against the parallel rollout open
# loop on PushT-Fixed, PushT-Rand and two PushT-Obs layouts; results packed into $OUT/eval.tgz.
#   OUT=dir bash experiments/results/training/evaluate.sh
set -u
for task in pusht-fixed pusht-rand; do
  if [ -f "/tmp/$task/model/actor_critic.json" ]; then
    rm -rf "pachs_jax/checkpoints/$task" && cp -r "/tmp/$task/model" "pachs_jax/checkpoints/$task"
  fi
done
mkdir -p /tmp/eval
timeout 120 python3 experiments/eval_policy.py --tasks pusht-fixed,pusht-rand --out /tmp/eval/policy.json > /tmp/eval/policy.log 2>&1
echo "policy exit $?"; tail -2 /tmp/eval/policy.log
for task in pusht-fixed pusht-rand; do
  timeout 100 python3 experiments/open_loop.py --task $task --backend warp --planners pachs,parallel --rounds 1 --out /tmp/eval/open_loop_$task.json > /tmp/eval/open_loop_$task.log 2>&1
  echo "$task exit $?"; tail -4 /tmp/eval/open_loop_$task.log
done
for layout in gate wall; do
  timeout 100 python3 experiments/open_loop.py --task pusht-obs --layout $layout --backend warp --planners pachs,parallel --rounds 1 --out /tmp/eval/open_loop_pusht-obs_$layout.json > /tmp/eval/open_loop_obs_$layout.log 2>&1
  echo "obs $layout exit $?"; tail -4 /tmp/eval/open_loop_obs_$layout.log
done
tar czf "$OUT/eval.tgz" -C /tmp eval
