#!/usr/bin/env bash
# PushT-Fixed trained from scratch and fine-tuned from the planar model side by side on one GPU
# for MINUTES each (each process stepping 2,048 Warp worlds leaves the GPU room for the other),
# after one process has compiled Warp's kernels for the machine:
#   OUT=dir bash experiments/results/training/run_both.sh 7.3
set -u
minutes=$1
export XLA_PYTHON_CLIENT_PREALLOCATE=false  # two processes share the GPU's memory
python3 - <<'PY'
import jax, jax.numpy as jnp
from pachs_jax import envs
from pachs_jax.envs import backends
env = backends.make_backend(envs.make('pusht-fixed'), 'warp')
nodes = env.initial_nodes(jax.random.split(jax.random.PRNGKey(0), 4))
jax.block_until_ready(env.evaluate(nodes, jnp.zeros((4, env.action_size))))
print('warp kernels ready', flush=True)
PY
here=experiments/results/training
bash $here/run.sh fixed-scratch pusht-fixed "$minutes" > "$OUT/scratch.out" 2>&1 &
bash $here/run.sh fixed-tuned pusht-fixed "$minutes" --init-from pachs_jax/checkpoints/pusht-fixed \
  > "$OUT/tuned.out" 2>&1
wait
cat "$OUT/scratch.out" "$OUT/tuned.out"
