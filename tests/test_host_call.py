"""NumPy functions as XLA FFI custom calls (envs/host_call.py): the results of the function
under jit and vmap, its errors, and programs that JAX's persistent compilation cache stores
(a `jax.pure_callback` program is not stored: the control)."""

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pachs_jax.envs import host_call


def _scaled(x, y):
  return (2.0 * x + y).astype(np.float32), x.sum(-1) > 0


host_call.register('pachs_test_scaled', _scaled)


def _call(x, y):
  specs = (jax.ShapeDtypeStruct(x.shape, jnp.float32), jax.ShapeDtypeStruct(x.shape[:-1], bool))
  return host_call.call('pachs_test_scaled', specs, x, y)


def test_results_under_jit_vmap_and_a_loop():
  rng = np.random.default_rng(0)
  x = rng.normal(size=(5, 3)).astype(np.float32)
  y = rng.normal(size=(5, 3)).astype(np.float32)
  got, positive = jax.jit(_call)(x, y)
  np.testing.assert_array_equal(got, 2.0 * x + y)
  np.testing.assert_array_equal(positive, x.sum(-1) > 0)
  batched, _ = jax.jit(jax.vmap(_call))(np.stack([x, -x]), np.stack([y, y]))
  np.testing.assert_array_equal(batched, np.stack([2.0 * x + y, -2.0 * x + y]))
  looped = jax.jit(lambda x: jax.lax.fori_loop(0, 3, lambda _, c: _call(c, y)[0], x))(x)
  np.testing.assert_allclose(looped, 8.0 * x + 7.0 * y, rtol=1e-5, atol=1e-5)
  empty, flags = jax.jit(_call)(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32))
  assert empty.shape == (0, 3) and flags.shape == (0,)


def test_an_error_in_the_function_names_the_target_and_the_error():
  def fails(x):
    raise ValueError('no such state')

  host_call.register('pachs_test_fails', fails)
  spec = (jax.ShapeDtypeStruct((2,), jnp.float32),)
  with pytest.raises(Exception, match="pachs_test_fails: ValueError: no such state"):
    jax.block_until_ready(jax.jit(lambda x: host_call.call('pachs_test_fails', spec, x))(
        jnp.ones(2)))
  host_call.register('pachs_test_short', lambda x: (x,))
  with pytest.raises(Exception, match='pachs_test_short: ValueError: gave 1 results, the call '
                     'takes 2'):
    jax.block_until_ready(jax.jit(lambda x: host_call.call('pachs_test_short', spec * 2, x))(
        jnp.ones(2)))


def test_programs_are_stored_by_the_persistent_cache(compilation_cache_dir):
  if compilation_cache_dir is None:
    pytest.skip('the compilation cache is off ($PACHS_COMPILATION_CACHE)')
  x = jnp.asarray(np.random.default_rng(1).normal(size=(7, 11)), jnp.float32)
  stored = lambda name: any(f.startswith(f'jit_{name}-') for f in os.listdir(compilation_cache_dir))

  def host_call_program_of_the_test(x):
    return _call(x, x)[0] * 3.0

  def pure_callback_program_of_the_test(x):
    spec = (jax.ShapeDtypeStruct(x.shape, jnp.float32), jax.ShapeDtypeStruct(x.shape[:1], bool))
    return jax.pure_callback(_scaled, spec, x, x)[0] * 3.0

  for fn in (host_call_program_of_the_test, pure_callback_program_of_the_test):
    jax.jit(fn).lower(x).compile()
  assert stored('host_call_program_of_the_test')
  # the control: the same function through jax.pure_callback is compiled but not stored
  assert not stored('pure_callback_program_of_the_test')
