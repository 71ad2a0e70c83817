"""MuJoCo Playground tasks as PACHS tasks: `from_playground(env, ...)` wraps a Playground
`MjxEnv` (MJX's JAX or Warp implementation) into `base.Env` (docs/own_task.md).

Needs the optional extra: pip install -e '.[playground]'. Playground is imported lazily here,
so the core package imports without it."""

from __future__ import annotations

import dataclasses
import functools
import os
from typing import Any, Callable, Dict, Mapping, Optional, Sequence, Union

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pachs_jax.envs import base, protocol, warp_import, warp_physics

PREFIX = 'playground:'  # task names 'playground:NAME' (NAME: a Playground registry name)
INSTALL = "pip install -e '.[playground]'"
MENAGERIE_ENV = 'PACHS_MENAGERIE_DIR'  # a MuJoCo Menagerie checkout, for the Menagerie tasks

# The mjx.Data fields that restore a simulation exactly (MuJoCo's integration state: state,
# control, mocap and user data); every other field is recomputed by the next mjx.step.
STATE_FIELDS = ('time', 'qpos', 'qvel', 'act', 'history', 'qacc_warmstart', 'plugin_state',
                'ctrl', 'qfrc_applied', 'xfrc_applied', 'eq_active', 'mocap_pos',
                'mocap_quat', 'userdata')

GoalRule = Union[str, Callable[[Any], jax.Array]]
VELOCITY_STEPS = 5  # the default lattice's velocity cell: one position cell per 5 control steps


@struct.dataclass
class PlaygroundNode:
  """One search node of a Playground task (a leading batch axis is optional).

  qpos: [..., nq], qvel: [..., nv] of mjx.Data (the default lattice and the finiteness checks
    read them).
  sim: dict of the other non-empty `STATE_FIELDS` of mjx.Data (time, ctrl, qacc_warmstart,
    act, mocap_pos, ...), as the env's Data holds them.
  obs: the observation the env returned with this state (an array or the env's dict).
  reward, done: [...] float32 of the env's State that produced this node.
  metrics, info: the env State's dicts (info carries the env's own PRNG key and counters).
  success: [...] bool the goal rule held when this state was produced.
  t: [...] int32 control steps since the episode start.
  """

  qpos: jax.Array
  qvel: jax.Array
  sim: Dict[str, jax.Array]
  obs: Any
  reward: jax.Array
  done: jax.Array
  metrics: Dict[str, jax.Array]
  info: Dict[str, Any]
  success: jax.Array
  t: jax.Array


@dataclasses.dataclass(frozen=True)
class PlaygroundConfig:
  """How a Playground task becomes a PACHS task.

  is_goal: the goal rule: a metric name of the env's State.metrics, or 'reward' (success when
    the value >= goal_threshold), or a callable (Playground State) -> [] bool. It is evaluated
    on the State that env.reset / env.step returns.
  goal_threshold: the threshold of a metric or reward goal rule.
  reward_max: an upper bound of the env's per-step reward; edge cost = reward_max - reward
    (>= 0; 1.0 for the dm_control tasks, whose rewards lie in [0, 1]). A reward above it
    gives a negative cost, which `protocol.check_task` reports when its random steps meet one.
  termination_cost: added to the cost of an edge that ends in the env's `done` (a failure
    termination, e.g. NaN physics); such an edge is also invalid for the search. None:
    reward_max * episode_length (as expensive as running out the clock).
  episode_length: control steps of a training episode and of a rollout (None: the env
    config's episode_length).
  lattice: None (positions and velocities, [qpos, qvel]), 'positions' (qpos only: for
    quasi-static tasks; from rest, a dynamic body's first steps stay in its cell) or a
    callable (PlaygroundNode) -> [L] float coordinates.
  lattice_resolution: [L] cell sizes; required with a callable lattice. None: per qpos
    coordinate 1/50 of the joint's range where limited, else 0.05 (m or rad); per velocity
    that cell size per `VELOCITY_STEPS` control steps (m/s or rad/s).
  obs_key: the entry the networks see when the env's observation is a dict.
  """

  is_goal: GoalRule = 'reward'
  goal_threshold: float = 1.0
  reward_max: float = 1.0
  termination_cost: Optional[float] = None
  episode_length: Optional[int] = None
  lattice: Union[None, str, Callable[[PlaygroundNode], jax.Array]] = None
  lattice_resolution: Optional[Sequence[float]] = None
  obs_key: str = 'state'

  def __post_init__(self):
    if not (isinstance(self.is_goal, str) or callable(self.is_goal)):
      raise ValueError(f'is_goal must be a metric name, \'reward\' or a callable, got '
                       f'{self.is_goal!r}')
    if not np.isfinite(self.reward_max):
      raise ValueError(f'reward_max must be finite, got {self.reward_max}')
    if self.episode_length is not None and self.episode_length < 1:
      raise ValueError(f'episode_length must be >= 1, got {self.episode_length}')
    if self.termination_cost is not None and not self.termination_cost >= 0:
      raise ValueError(f'termination_cost must be >= 0, got {self.termination_cost}')
    if isinstance(self.lattice, str) and self.lattice != 'positions':
      raise ValueError(f"lattice must be None, 'positions' or a callable, got {self.lattice!r}")
    if callable(self.lattice) and self.lattice_resolution is None:
      raise ValueError('a callable lattice needs lattice_resolution (its [L] cell sizes)')


def require_playground():
  """The `mujoco_playground` module; ImportError with the install command when it is missing."""
  try:
    import mujoco_playground  # pylint: disable=import-outside-toplevel
  except ImportError as e:
    raise ImportError(f'MuJoCo Playground is not installed ({e}); install the extra: '
                      f'{INSTALL}') from None
  return mujoco_playground


def _use_menagerie_dir(registry_module) -> None:
  """Points Playground at the Menagerie checkout in $PACHS_MENAGERIE_DIR, if set; otherwise a
  missing checkout is a clear error instead of Playground's `git clone` (it needs GitHub)."""
  from mujoco_playground._src import mjx_env  # pylint: disable=import-outside-toplevel
  del registry_module
  given = os.environ.get(MENAGERIE_ENV)
  if given:
    if not os.path.isdir(given):
      raise ValueError(f'{MENAGERIE_ENV}={given} is not a directory')
    mjx_env.MENAGERIE_PATH = type(mjx_env.MENAGERIE_PATH)(given)
  if not mjx_env.MENAGERIE_PATH.exists():
    raise ValueError('this Playground task needs MuJoCo Menagerie assets, which are not on '
                     f'PyPI (Playground clones them from GitHub; the mujoco-menagerie package '
                     f'downloads them from GitHub releases): set {MENAGERIE_ENV} to a '
                     'mujoco_menagerie checkout')


def check_name(name: str) -> None:
  """ValueError unless `name` is a Playground registry env: the name in its case where only
  the case differs, else some valid names."""
  require_playground()
  from mujoco_playground import registry  # pylint: disable=import-outside-toplevel
  if name in registry.ALL_ENVS:
    return
  same = [n for n in registry.ALL_ENVS if n.lower() == name.lower()]
  if same:
    raise ValueError(f'unknown Playground env {name!r}; did you mean {same[0]!r} (names are '
                     'case-sensitive)?')
  listed = ', '.join(registry.ALL_ENVS[:12])
  raise ValueError(f'unknown Playground env {name!r}; valid names include {listed}, ... '
                   f'({len(registry.ALL_ENVS)} in mujoco_playground.registry.ALL_ENVS)')


def load_env(name: str, **config_overrides):
  """Playground's registry env `name` with the JAX implementation (impl='jax'), as a raw
  `MjxEnv`; ValueError listing some valid names for an unknown one."""
  check_name(name)
  from mujoco_playground import registry  # pylint: disable=import-outside-toplevel
  from mujoco_playground._src import locomotion, manipulation  # pylint: disable=g-import-not-at-top
  if name in manipulation.ALL_ENVS or name in locomotion.ALL_ENVS:
    _use_menagerie_dir(registry)
  overrides = dict({'impl': 'jax'}, **config_overrides)
  return registry.load(name, config_overrides=overrides)


class PlaygroundEnv(base.Env):
  """A Playground `MjxEnv` as a PACHS task (see `PlaygroundConfig` for the rules).

  A node holds the integration state of mjx.Data (`STATE_FIELDS`), the observation, the
  env's info and metrics, the goal flag and t; an edge restores the node into an mjx.Data
  and calls the env's own `step`, so restore-then-step reproduces it bit for bit
  (`restore_mismatches` checks this). Nodes: `PlaygroundNode`.
  """

  def __init__(self, env, config: PlaygroundConfig = PlaygroundConfig(),
               name: Optional[str] = None):
    impl = getattr(env.mjx_model, 'impl', None)
    self.impl = str(getattr(impl, 'value', impl) or 'jax')
    if self.impl not in ('jax', 'warp'):
      raise ValueError(f'{type(env).__name__} uses the {self.impl!r} MJX implementation; '
                       "PACHS takes impl='jax' or impl='warp'")
    self.physics = 'mjx' if self.impl == 'jax' else 'warp'
    self.playground_env = env
    self.config = config
    self.name = name or f'{PREFIX}{type(env).__name__}'
    env_config = getattr(env, '_config', None)
    length = config.episode_length or int(getattr(env_config, 'episode_length', 1000))
    self.episode_length = int(length)
    self.goal_size = 0
    self._termination_cost = (config.reward_max * self.episode_length
                              if config.termination_cost is None else config.termination_cost)
    self._data_spec = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).data
    # empty fields (no mocap bodies, no activations, ...) stay in the zeros template: orbax
    # cannot save zero-size arrays, and they hold nothing
    self._fields = tuple(f for f in STATE_FIELDS if hasattr(self._data_spec, f)
                         and int(np.prod(getattr(self._data_spec, f).shape)) > 0)
    self._warp_template = None
    if self.impl == 'warp':  # private Warp buffers (contacts, constraints) from a real reset
      warp_import.require("a Playground env with impl='warp'")
      self._warp_template = jax.tree.map(np.asarray,
                                         jax.jit(env.reset)(jax.random.PRNGKey(0)).data)
    model = env.mj_model
    self._resolution = self._lattice_resolution(model)
    self._extent = self._qpos_extent(model)

  # ---- the node <-> Playground State ----

  def node_from_state(self, state, t: jax.Array) -> PlaygroundNode:
    """The node of a Playground State (no batch axis) at control step t."""
    data = state.data
    sim = {f: getattr(data, f) for f in self._fields if f not in ('qpos', 'qvel')}
    return PlaygroundNode(
        qpos=data.qpos, qvel=data.qvel, sim=sim, obs=state.obs,
        reward=jnp.asarray(state.reward, jnp.float32), done=jnp.asarray(state.done, jnp.float32),
        metrics=dict(state.metrics), info=dict(state.info),
        success=self.goal_of_state(state), t=jnp.asarray(t, jnp.int32))

  def state_from_node(self, node: PlaygroundNode):
    """The Playground State a node restores (no batch axis): its integration state in an
    mjx.Data whose other fields are zeros (mjx.step recomputes them from the state); with
    impl='warp', Warp's buffers of one reset (shared by a vmapped batch, as in Playground)."""
    from mujoco_playground import State  # pylint: disable=import-outside-toplevel
    if self._warp_template is not None:
      data = warp_physics.rebuild(self._warp_template)
    else:
      data = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), self._data_spec)
    data = data.replace(qpos=node.qpos, qvel=node.qvel, **node.sim)
    return State(data=data, obs=node.obs, reward=node.reward, done=node.done,
                 metrics=dict(node.metrics), info=dict(node.info))

  def goal_of_state(self, state) -> jax.Array:
    """[] bool the goal rule on a Playground State."""
    rule = self.config.is_goal
    if callable(rule):
      return jnp.asarray(rule(state), bool).reshape(())
    if rule == 'reward':
      value = state.reward
    elif rule in state.metrics:
      value = state.metrics[rule]
    else:
      raise ValueError(f'{self.name}: goal metric {rule!r} is not in the env\'s metrics '
                       f'({", ".join(sorted(state.metrics)) or "none"}) nor \'reward\'')
    return jnp.asarray(value, jnp.float32).reshape(()) >= self.config.goal_threshold

  # ---- base.Env ----

  @property
  def action_size(self) -> int:
    return int(self.playground_env.action_size)

  @property
  def default_lattice_resolution(self) -> jax.Array:
    return jnp.asarray(self._resolution, jnp.float32)

  @property
  def lattice_extent(self):
    return self._extent if self.config.lattice == 'positions' else None

  def sample_instance(self, key: jax.Array) -> PlaygroundNode:
    return self.node_from_state(self.playground_env.reset(key), 0)

  def canonical_instances(self, num: int = 30, seed: int = 0) -> PlaygroundNode:
    """[num] start nodes fixed by seed: the env's reset with keys split from PRNGKey(seed)."""
    keys = jax.random.split(jax.random.PRNGKey(seed), num)
    return jax.jit(self.initial_nodes)(keys)

  def transition(self, node: PlaygroundNode, action: jax.Array) -> base.EdgeOutcome:
    clean, ok = base.sanitize_actions(action)
    stepped = self.playground_env.step(self.state_from_node(node), clean)
    new = self.node_from_state(stepped, node.t + 1)
    reward = jnp.asarray(stepped.reward, jnp.float32)
    finite = (jnp.all(jnp.isfinite(new.qpos)) & jnp.all(jnp.isfinite(new.qvel))
              & jnp.isfinite(reward))
    valid = ok & finite & ~(jnp.asarray(stepped.done) > 0)
    if self._warp_template is not None:  # Warp's buffers overflowed: not simulated right
      valid = valid & ~warp_physics.data_overflowed(stepped.data)
    cost = self.config.reward_max - reward
    cost = jnp.where(valid, cost, self.config.reward_max + self._termination_cost)
    keep = lambda a, b: jnp.where(valid, a, b)
    next_node = jax.tree.map(keep, new, node).replace(t=node.t + 1)
    return base.EdgeOutcome(next_node, cost.astype(jnp.float32), new.success & valid, valid)

  def observation(self, node: PlaygroundNode) -> jax.Array:
    obs = node.obs
    if isinstance(obs, Mapping):
      if self.config.obs_key not in obs:
        raise ValueError(f'{self.name}: observation dict has no {self.config.obs_key!r} '
                         f'(keys {", ".join(sorted(obs))}); set PlaygroundConfig.obs_key')
      obs = obs[self.config.obs_key]
    return jnp.asarray(obs, jnp.float32).reshape(-1)

  def lattice_coords(self, node: PlaygroundNode, resolution: jax.Array) -> jax.Array:
    rule = self.config.lattice
    if rule is None:
      values = jnp.concatenate([node.qpos, node.qvel])
    elif rule == 'positions':
      values = node.qpos
    else:
      values = rule(node)
    return jnp.floor(jnp.asarray(values, jnp.float32) / resolution).astype(jnp.int32)

  def goal_reached(self, node: PlaygroundNode) -> jax.Array:
    return node.success

  # ---- the exactness check (protocol.check_task calls it) ----

  @functools.cached_property
  def restore_rollout(self):
    """Jitted, one program per env and shapes: (keys [B, 2], actions [T, B, A]) -> (the env's
    own States [T, B], this adapter's `EdgeOutcome`s [T, B]) along rollouts of the actions
    from the env's resets with keys, stepped by the env's own step and, beside it, by
    `evaluate` (restore, then step); exact when each next node restores its State bit for
    bit."""
    env = self.playground_env

    def restore_rollout(keys, actions):
      states = jax.vmap(env.reset)(keys)

      def body(carry, action):
        states, nodes = carry
        want = jax.vmap(env.step)(states, action)
        got = self.evaluate(nodes, action)
        return (want, got.next_node), (want, got)

      nodes = jax.vmap(lambda state: self.node_from_state(state, 0))(states)
      return jax.lax.scan(body, (states, nodes), actions)[1]

    return jax.jit(restore_rollout)

  def restore_mismatches(self, num_steps: int = 8, num_rollouts: int = 4, seed: int = 0) -> list:
    """Names of the Playground State fields where `transition` differs bit for bit from the
    env's own step along num_rollouts random-action rollouts of num_steps (`restore_rollout`);
    [] when exact."""
    keys = jax.random.split(jax.random.PRNGKey(seed), num_rollouts + 1)
    actions = jax.random.uniform(keys[0], (num_steps, num_rollouts, self.action_size),
                                 jnp.float32, -1, 1)
    want, out = self.restore_rollout(keys[1:], actions)
    got = out.next_node
    restored = jax.vmap(jax.vmap(self.state_from_node))(got)
    pairs = {f'data.{k}': (getattr(want.data, k), getattr(restored.data, k))
             for k in STATE_FIELDS if hasattr(want.data, k)}
    pairs.update({'obs': (want.obs, got.obs), 'reward': (want.reward, got.reward),
                  'done': (want.done, got.done), 'metrics': (want.metrics, got.metrics),
                  'info': (want.info, got.info)})
    bad = []
    for name, (a, b) in pairs.items():
      la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
      if len(la) != len(lb) or any(np.asarray(x).astype(np.asarray(y).dtype).tobytes()
                                   != np.asarray(y).tobytes() for x, y in zip(la, lb)):
        bad.append(name)
    return bad

  # ---- defaults from the model ----

  def _lattice_resolution(self, model) -> np.ndarray:
    if self.config.lattice_resolution is not None:
      return np.asarray(self.config.lattice_resolution, np.float32).reshape(-1)
    position = np.full((model.nq,), 0.05, np.float64)
    velocity = np.full((model.nv,), 0.05, np.float64)
    for j in range(model.njnt):
      if model.jnt_type[j] in (2, 3):  # slide, hinge: one qpos, one dof
        if model.jnt_limited[j]:
          low, high = model.jnt_range[j]
          position[model.jnt_qposadr[j]] = (high - low) / 50.0
        velocity[model.jnt_dofadr[j]] = position[model.jnt_qposadr[j]]
    velocity /= VELOCITY_STEPS * float(self.playground_env.dt)
    if self.config.lattice == 'positions':
      return position.astype(np.float32)
    return np.concatenate([position, velocity]).astype(np.float32)

  def _qpos_extent(self, model):
    """[nq] largest |qpos| when every joint is a limited slide or hinge, else None."""
    if model.njnt == 0 or model.nq != model.njnt:
      return None
    extent = np.zeros((model.nq,), np.float64)
    for j in range(model.njnt):
      if model.jnt_type[j] not in (2, 3) or not model.jnt_limited[j]:
        return None
      extent[model.jnt_qposadr[j]] = np.abs(model.jnt_range[j]).max()
    return tuple(float(x) for x in extent)


# Goal rules and lengths of the Playground tasks that `make('playground:NAME')` knows; any
# other Playground name gets PlaygroundConfig's defaults (goal: reward >= 1).
KNOWN: Dict[str, Dict[str, Any]] = {
    # within the target: the reward's near_target term is 1 inside the target's radius
    'PointMass': dict(is_goal='reward/near_target', goal_threshold=1.0, episode_length=200),
    # the fingertip within the target: the reward is 1 inside the summed radii
    'ReacherEasy': dict(is_goal='reward', goal_threshold=1.0, episode_length=200),
    'ReacherHard': dict(is_goal='reward', goal_threshold=1.0, episode_length=200),
}


def from_playground(env, is_goal: Optional[GoalRule] = None, lattice=None,
                    lattice_resolution: Optional[Sequence[float]] = None,
                    check: bool = True, name: Optional[str] = None,
                    **options) -> PlaygroundEnv:
  """A Playground env (an `MjxEnv` object, or a registry name such as 'PointMass') as a PACHS
  task; `protocol.check_task` runs on it unless check=False.

  is_goal, lattice, lattice_resolution and `options` (reward_max, goal_threshold,
  termination_cost, episode_length, obs_key): `PlaygroundConfig` fields; None takes the
  defaults of a known task (`KNOWN`), else PlaygroundConfig's.
  name: the task name checkpoints record (default 'playground:' + the env's name).
  """
  if isinstance(env, str):
    env_name = env
    env = load_env(env_name)
  else:
    env_name = type(env).__name__
    reg = getattr(env, '_pachs_registry_name', None)
    env_name = reg or env_name
  values = dict(KNOWN.get(env_name, {}))
  given = dict(is_goal=is_goal, lattice=lattice, lattice_resolution=lattice_resolution,
               **options)
  unknown = sorted(set(given) - {f.name for f in dataclasses.fields(PlaygroundConfig)})
  if unknown:
    raise ValueError(f'from_playground has no option {", ".join(unknown)}')
  values.update({k: v for k, v in given.items() if v is not None})
  wrapped = PlaygroundEnv(env, PlaygroundConfig(**values), name=name or f'{PREFIX}{env_name}')
  if check:
    protocol.check_task(wrapped)
  return wrapped


def make(name: str, check: bool = True, **options) -> PlaygroundEnv:
  """The task 'playground:NAME' (or NAME): Playground's registry env with impl='jax', wrapped
  by `from_playground` with the defaults of `KNOWN`."""
  env_name = name[len(PREFIX):] if name.startswith(PREFIX) else name
  return from_playground(env_name, check=check, **options)
