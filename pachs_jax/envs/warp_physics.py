"""PushT with MJX's MuJoCo Warp implementation (`impl='warp'`) as its physics: the same node
state, cost, coverage and observation code as `pusht.PushTEnv`, with a Warp step; edges whose
contacts or constraints overflow Warp's buffers are invalid and counted by `overflowed`."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from pachs_jax.envs import base, pusht, warp_import

mjx = warp_import.quiet_mjx()  # mujoco.mjx, without its stdout line about a missing warp-lang


def rebuild(host_data):
  """A Warp Data from its host values (numpy leaves) inside a trace: uniform leaves as
  `jnp.full`, so that large buffers are no constants of the program."""
  def leaf(x):
    if x.size and np.all(x == x.flat[0]):
      return jnp.full(x.shape, x.flat[0], x.dtype)
    return jnp.asarray(x)
  return jax.tree.map(leaf, host_data)


def data_overflowed(data: mjx.Data) -> jax.Array:
  """[] bool (or batched): Warp Data `data` overflowed a buffer (contacts, constraints,
  collision) in its last step; the solver's iteration limits do not count."""
  return (data._impl.overflow & _capacity_overflow_mask()) != 0  # pylint: disable=protected-access


def _capacity_overflow_mask() -> int:
  """Warp's `OverflowType` bits for buffers too small (contacts, constraints, collision);
  the solver's iteration limits, which the few Newton iterations reach by design, left out."""
  from mujoco.mjx.warp import mjwp_types  # pylint: disable=g-import-not-at-top
  kind = mjwp_types.OverflowType
  return int(kind.ALL & ~(kind.ITERATIONS | kind.LS_ITERATIONS))


class WarpPushTEnv(pusht.PushTEnv):
  """PushT whose edges step MuJoCo Warp (through MJX) instead of MJX's JAX implementation.

  config: the `pusht.PushTConfig`.
  contacts_per_world: Warp's contact buffer per simulated edge (naconmax = this x batch).
  constraints_per_world: Warp's constraint rows per edge (njmax).
  An edge whose physics overflowed either buffer (Warp Data's `overflow` bits) is invalid;
  `overflowed(nodes, actions)` returns those edges (a full contact buffer marks every edge of
  the call, since Warp counts contacts for the whole batch; constraints count per edge). Batches go through `evaluate`: a vmapped
  `transition` shares one world's contact buffer.
  """

  physics = 'warp'

  def __init__(self, config: pusht.PushTConfig = pusht.PushTConfig(),
               contacts_per_world: int = 32, constraints_per_world: int = 160):
    warp_import.require()
    for name, value in (('contacts_per_world', contacts_per_world),
                        ('constraints_per_world', constraints_per_world)):
      if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f'{name} must be a positive int, got {value!r}')
    super().__init__(config)
    warp_import.announce_kernel_compile()
    self.contacts_per_world = contacts_per_world
    self.constraints_per_world = constraints_per_world
    self._overflow_mask = _capacity_overflow_mask()
    model = mjx.put_model(self.mj_model, impl='warp')
    # Warp's kernels print a line per world for each overflow they find: buffer overflows
    # stay printed, the solver's iteration limits (reached by design) do not
    option = model.opt._impl.replace(warn_overflow=self._overflow_mask)  # pylint: disable=protected-access
    self.warp_model = model.replace(opt=model.opt.replace(_impl=option))
    self._warp_templates = {}  # edges per call -> Data template (host values)

  @property
  def fingerprint(self) -> str:
    return (f'{type(self).__qualname__}({self.config!r}, contacts={self.contacts_per_world}, '
            f'constraints={self.constraints_per_world})')

  def _template(self, worlds: int) -> mjx.Data:
    """A Warp Data for a call of `worlds` edges; constant leaves are built inside the trace
    (no large constants in the program)."""
    if worlds not in self._warp_templates:
      with jax.ensure_compile_time_eval():  # concrete values also when called in a trace
        data = mjx.make_data(self.mj_model, impl='warp',
                             naconmax=self.contacts_per_world * worlds,
                             njmax=self.constraints_per_world)
      self._warp_templates[worlds] = jax.tree.map(np.asarray, data)
    return rebuild(self._warp_templates[worlds])

  def _simulate(self, nodes: base.NodeState, actions: jax.Array):
    """(EdgeOutcome [B], [B] bool overflowed) of edges nodes [B], actions [B, A]."""
    base.check_actions(actions, self.action_size, batched=True)
    template = self._template(int(actions.shape[0]))

    def one(node, action):
      data, action_ok = self._actuated(node, action, template)
      # a loop, not unrolled: one Warp call in the program, traced and lowered once
      data = jax.lax.fori_loop(0, self.config.substeps,
                               lambda _, d: mjx.step(self.warp_model, d), data)
      over = data_overflowed(data)
      return self._outcome(node, data, action_ok & ~over), over

    return jax.vmap(one)(nodes, actions)

  def evaluate(self, nodes: base.NodeState, actions: jax.Array) -> base.EdgeOutcome:
    """B edges, nodes [B], actions [B, A], stepped in one Warp call per substep."""
    return self._simulate(nodes, actions)[0]

  def overflowed(self, nodes: base.NodeState, actions: jax.Array) -> jax.Array:
    """[B] bool: the edges of `evaluate(nodes, actions)` whose contacts or constraints did not
    fit Warp's buffers (they are invalid there, not simulated wrongly)."""
    return self._simulate(nodes, actions)[1]

  def transition(self, node: base.NodeState, action: jax.Array) -> base.EdgeOutcome:
    """One edge of a single node (`evaluate` with B = 1)."""
    out = self.evaluate(jax.tree.map(lambda x: jnp.asarray(x)[None], node),
                        jnp.asarray(action)[None])
    return jax.tree.map(lambda x: x[0], out)
