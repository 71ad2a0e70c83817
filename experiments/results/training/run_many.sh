#!/usr/bin/env bash
# Training runs side by side, run i on GPU i mod (the host's GPUs), for MINUTES each (run.sh),
# after one process has compiled Warp's kernels for the machine (cached on disk for the rest):
#   OUT=dir bash experiments/results/training/run_many.sh MINUTES 'NAME TASK [flags]' ...
set -u
if [ "$#" -lt 2 ]; then
  echo "usage: OUT=dir bash $0 MINUTES 'NAME TASK [train.py flags]' ..." >&2; exit 2
fi
minutes=$1; shift
here=experiments/results/training
gpus=$(nvidia-smi -L | wc -l)
if [ "$#" -gt "$gpus" ]; then
  export XLA_PYTHON_CLIENT_PREALLOCATE=false  # processes share a GPU's memory
fi
python3 - <<'PY'
import jax, jax.numpy as jnp
from pachs_jax import envs
from pachs_jax.envs import backends
env = backends.make_backend(envs.make('pusht-fixed', physics='faithful'), 'warp')
nodes = env.initial_nodes(jax.random.split(jax.random.PRNGKey(0), 4))
jax.block_until_ready(env.evaluate(nodes, jnp.zeros((4, env.action_size))))
print('warp kernels ready', flush=True)
PY
i=0
for spec in "$@"; do
  # shellcheck disable=SC2086  # a spec is words: NAME TASK [train.py flags]
  set -- $spec
  name=$1; task=$2; shift 2
  CUDA_VISIBLE_DEVICES=$((i % gpus)) bash $here/run.sh "$name" "$task" "$minutes" "$@" \
    > "/tmp/run_$name.out" 2>&1 &
  i=$((i + 1))
done
wait
cat /tmp/run_*.out
