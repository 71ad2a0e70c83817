#!/usr/bin/env bash
# Train (or continue) a PushT model on the faithful physics with MuJoCo Warp for at most
# MINUTES of one GPU command, and pack what a later command or session continues from:
#   OUT=dir bash experiments/results/training/run.sh NAME TASK MINUTES [train.py flags...]
# The run directory /tmp/NAME left by an earlier command on the same machine is resumed; else
# a learner file experiments/results/training/NAME_learner.npz (a run moved from another
# machine) starts it, its replay buffer refilled by its policy; else it starts anew.
# $OUT/NAME.tgz holds the model, metrics, status, training log and learner file.
set -u
if [ "$#" -lt 3 ]; then
  echo "usage: OUT=dir bash $0 NAME TASK MINUTES [train.py flags...]" >&2; exit 2
fi
name=$1; task=$2; minutes=$3; shift 3; out=${OUT:?set OUT to the folder the run is packed into}
here=experiments/results/training
from=()
if [ ! -d "/tmp/$name/state" ] && [ -f "$here/${name}_learner.npz" ]; then
  from=(--learner-from "$here/${name}_learner.npz")
fi
mkdir -p "/tmp/$name"
python3 experiments/train.py --task "$task" --physics warp --physics-preset faithful \
  --steps 200000000 --minutes "$minutes" --out "/tmp/$name" --resume --start-if-missing \
  --learner-out "/tmp/${name}_learner.npz" "${from[@]}" --progress lines --no-tensorboard "$@" \
  >> "/tmp/$name/train.log" 2>&1
echo "$name: train exit $?"
tar czf "$out/$name.tgz" -C /tmp "$name/model" "$name/metrics.csv" "$name/status.json" \
  "$name/train.log" "${name}_learner.npz"
# a device command brings back files of at most 16 MiB (PushT-Rand's learner is about 25 MB):
# join the parts with cat NAME.tgz.part-* > NAME.tgz
if [ "$(stat -c %s "$out/$name.tgz")" -gt 15728640 ]; then
  split -b 15M "$out/$name.tgz" "$out/$name.tgz.part-" && rm "$out/$name.tgz"
fi
tail -3 "/tmp/$name/train.log"
