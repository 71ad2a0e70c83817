"""The XLA CPU setting that keeps batched LAPACK calls from deadlocking XLA's thread pool."""

import os
import subprocess
import sys
import textwrap

import pytest

from pachs_jax.runtime import xla_cpu


# Two independent chains of batched Cholesky factorizations (2048 10x10 matrices: big enough for
# jaxlib to split each call over the thread pool) in one loop, on 2 CPUs: without the setting
# it deadlocks (4 runs of 4 on a 2-core machine; all XLA threads in lapack_spotrf_ffi waiting).
PROGRAM = textwrap.dedent('''
    import os, sys
    os.sched_setaffinity(0, {cpus!r})  # before JAX sizes its thread pool: 2 threads
    sys.path.insert(0, {root!r})
    from pachs_jax.runtime import xla_cpu
    if {fix}:
      xla_cpu.configure(os.environ)
    import jax, jax.numpy as jnp
    a = jax.random.normal(jax.random.PRNGKey(0), (2048, 10, 10))
    spd = a @ jnp.swapaxes(a, -1, -2) + 10.0 * jnp.eye(10)

    def chain(x):
      for _ in range(4):
        low = jnp.linalg.cholesky(x)
        x = low @ jnp.swapaxes(low, -1, -2) * 0.5 + 5.0 * jnp.eye(10)
      return x

    def run(chains):
      body = lambda i, xs: tuple(chain(x) for x in xs)
      return jax.jit(lambda x: jax.lax.fori_loop(0, 300, body, tuple(x + j for j in chains)))(spd)

    both = run((0, 1))
    alone = run((1,))
    print(float(jnp.max(jnp.abs(both[1] - alone[0]))), flush=True)
''')


def test_configure_adds_the_flag_once_and_keeps_a_users_choice():
  env = {'XLA_FLAGS': '--xla_gpu_deterministic_ops=true'}
  xla_cpu.configure(env)
  assert env['XLA_FLAGS'] == '--xla_gpu_deterministic_ops=true ' + xla_cpu.LAPACK_SAFE_FLAG
  assert xla_cpu.is_configured(env)
  xla_cpu.configure(env)
  assert env['XLA_FLAGS'].count('multi_thread_eigen') == 1
  chosen = {'XLA_FLAGS': '--xla_cpu_multi_thread_eigen=true'}
  xla_cpu.configure(chosen)
  assert chosen == {'XLA_FLAGS': '--xla_cpu_multi_thread_eigen=true'}
  assert not xla_cpu.is_configured(chosen)
  empty = {}
  xla_cpu.configure(empty)
  assert empty == {'XLA_FLAGS': xla_cpu.LAPACK_SAFE_FLAG}


@pytest.mark.skipif(not hasattr(os, 'sched_getaffinity') or len(os.sched_getaffinity(0)) < 2,
                    reason='needs 2 CPUs for a 2-thread XLA pool')
def test_concurrent_batched_cholesky_on_two_cpus_finishes_with_the_setting():
  cpus = sorted(os.sched_getaffinity(0))[:2]
  root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
  env = {k: v for k, v in os.environ.items() if k != 'XLA_FLAGS'}
  env['JAX_PLATFORMS'] = 'cpu'
  try:
    out = subprocess.run([sys.executable, '-c', PROGRAM.format(root=root, fix=True, cpus=cpus)],
                         env=env, capture_output=True, text=True, timeout=240)
  except subprocess.TimeoutExpired:
    pytest.fail('batched Cholesky calls deadlocked XLA\'s CPU thread pool')
  assert out.returncode == 0, out.stderr[-2000:]
  assert float(out.stdout.strip().splitlines()[-1]) < 1e-4  # the same answer as one chain alone
