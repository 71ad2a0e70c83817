#!/usr/bin/env bash
# Train (or continue) a PushT model on the faithful physics with MuJoCo Warp for at most MINUTES
# of one GPU command, then pack what a later command or session continues from into $OUT:
#   OUT=dir bash experiments/results/training/run.sh pusht-fixed 6.3 [bench]
# A run directory left in /tmp by an earlier command on the same machine is resumed; else a
# learner file in experiments/results/training/<task>_learner.npz (a run moved from another
# machine) starts it, its replay buffer refilled by its policy; else it starts from scratch.
# With 'bench', the training throughput of Warp against MJX-JAX at 4,096 envs follows.
set -u
task=$1; minutes=$2; out=${OUT:?}
here=experiments/results/training
from=()
if [ ! -d "/tmp/$task/state" ] && [ -f "$here/${task}_learner.npz" ]; then
  from=(--learner-from "$here/${task}_learner.npz")
fi
python3 experiments/train.py --task "$task" --physics warp --physics-preset faithful \
  --steps 60000000 --minutes "$minutes" --out "/tmp/$task" --resume --start-if-missing \
  --learner-out "/tmp/${task}_learner.npz" "${from[@]}" --progress lines --no-tensorboard \
  > "$out/train_$task.log" 2>&1
echo "train exit $?"
tar czf "$out/$task.tgz" -C /tmp "$task/model" "$task/metrics.csv" "$task/status.json" \
  "${task}_learner.npz"
if [ "${3:-}" = bench ]; then
  timeout 200 python3 experiments/bench_training.py --preset faithful --num-envs 4096 \
    --epochs 2 --physics-steps 10 --out "$out/bench_training.json" > "$out/bench.log" 2>&1
  echo "bench exit $?"
fi
tail -3 "$out/train_$task.log"
