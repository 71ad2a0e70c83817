"""The jitted SAC learner: vmapped environments with auto-reset, a device replay buffer and
gradient updates, all inside `lax.scan`."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Dict, Tuple

import jax
import jax.numpy as jnp
import optax
from brax.training import replay_buffers
from brax.training import types as brax_types
from brax.training.acme import running_statistics
from flax import struct

from pachs_jax import trees
from pachs_jax.envs import base
from pachs_jax.sac import losses as sac_losses
from pachs_jax.sac import networks as sac_networks
from pachs_jax.sac.config import SACConfig

Metrics = Dict[str, jax.Array]


@struct.dataclass
class TrainingState:
  """Everything a SAC run needs to continue; env-batch arrays have leading axis num_envs (N).

  policy_params / q_params / target_q_params: network parameters (q holds both critics).
  *_optimizer_state: Adam states; log_alpha: [] log entropy temperature.
  normalizer: running observation statistics.
  env_state: base.State [N] current environment states (already auto-reset).
  episode_return: [N] float32 reward summed since each environment's episode start.
  buffer_state: the replay buffer (data on the device, its own sampling key).
  key: PRNG key of the run; epoch / gradient_steps: [] int32 counters.
  """

  policy_params: Any
  policy_optimizer_state: Any
  q_params: Any
  target_q_params: Any
  q_optimizer_state: Any
  log_alpha: jax.Array
  alpha_optimizer_state: Any
  normalizer: running_statistics.RunningStatisticsState
  env_state: base.State
  episode_return: jax.Array
  buffer_state: replay_buffers.ReplayBufferState
  key: jax.Array
  epoch: jax.Array
  gradient_steps: jax.Array


@dataclasses.dataclass(frozen=True)
class Trainer:
  """Jitted init and epoch functions of one (env, config) pair, and step bookkeeping.

  init() -> TrainingState: fresh parameters and environments, the replay buffer prefilled with
    uniform random actions (deterministic given config.seed).
  refill(learner) -> TrainingState: a run continued from a learner (`learner_file.LEARNER_FIELDS`
    by name): fresh environments, the replay buffer prefilled by the learner's own policy.
  epoch(state) -> (state, metrics): config.steps_per_epoch training steps, each one vmapped env
    step of config.num_envs environments followed by config.grad_updates_per_step updates.
  """

  env: base.Env
  config: SACConfig
  networks: sac_networks.SACNetworks
  init: Callable[[], TrainingState]
  refill: Callable[[Dict[str, Any]], TrainingState]
  epoch: Callable[[TrainingState], Tuple[TrainingState, Metrics]]
  prefill_env_steps: int
  env_steps_per_epoch: int

  def env_steps(self, epoch: int) -> int:
    """Environment steps taken after `epoch` epochs (prefill included)."""
    return self.prefill_env_steps + int(epoch) * self.env_steps_per_epoch

  def num_epochs(self, total_env_steps: int) -> int:
    """Epochs needed to take at least total_env_steps environment steps (at least one)."""
    remaining = max(0, int(total_env_steps) - self.prefill_env_steps)
    return max(1, -(-remaining // self.env_steps_per_epoch))


def _strong_types(tree: Any) -> Any:
  """The tree with weakly typed arrays made strong, so restored checkpoints match exactly."""
  return jax.tree.map(lambda x: jnp.asarray(x).astype(jnp.asarray(x).dtype), tree)


def _check_env(env: base.Env) -> None:
  """Raises a clear error when the env's reset and step states do not match in structure."""
  key = jax.random.PRNGKey(0)
  reset = jax.eval_shape(env.reset, key)
  stepped = jax.eval_shape(env.step, reset, jnp.zeros((env.action_size,), jnp.float32))
  if jax.tree.structure(reset) != jax.tree.structure(stepped):
    raise ValueError(f'env {env.name!r}: reset and step return States of different structure '
                     '(metrics/info keys must match for auto-reset)')
  for name, tree in (('metrics', stepped.metrics), ('info', stepped.info)):
    want = 'success' if name == 'metrics' else 'truncation'
    if want not in tree:
      raise ValueError(f"env {env.name!r}: State.{name} must contain '{want}'")
  if stepped.obs.shape != (env.observation_size,):
    raise ValueError(f'env {env.name!r}: obs shape {stepped.obs.shape} != '
                     f'({env.observation_size},)')


def from_model(state: TrainingState, params: Any, observations: float) -> TrainingState:
  """`state` (a fresh run's) fine-tuning an exported actor-critic: its actor, critics (also as
  the target critics) and observation statistics, weighted as `observations` observations.

  params: `actor_critic.ActorCriticParams` of the same network sizes.
  """
  # own buffers: the epoch donates its state, which must not delete the model's arrays
  copy = lambda tree: jax.tree.map(lambda x: jnp.array(x, jnp.float32, copy=True), tree)
  mean, std = copy(params.normalizer['mean']), copy(params.normalizer['std'])
  normalizer = state.normalizer.replace(
      count=brax_types.UInt64(hi=0, lo=int(observations)), mean=mean, std=std,
      summed_variance=jnp.square(std) * float(observations))
  return _strong_types(state.replace(policy_params=copy(params.policy), q_params=copy(params.q),
                                     target_q_params=copy(params.q), normalizer=normalizer))


def _make_optimizer(learning_rate: float, max_grad_norm: float) -> optax.GradientTransformation:
  """Adam, after a global-norm clip of the gradients when max_grad_norm > 0."""
  if max_grad_norm > 0:
    return optax.chain(optax.clip_by_global_norm(max_grad_norm), optax.adam(learning_rate))
  return optax.adam(learning_rate)


def make_trainer(env: base.Env, config: SACConfig) -> Trainer:
  """The jitted learner of `config` on `env` (a single-environment base.Env, vmapped here)."""
  _check_env(env)
  num_envs = config.num_envs
  obs_size, action_size = env.observation_size, env.action_size
  nets = sac_networks.make_sac_networks(obs_size, action_size, config.actor_hidden,
                                        config.critic_hidden, config.activation,
                                        config.normalize_observations)
  alpha_loss_fn, critic_loss_fn, actor_loss_fn = sac_losses.make_losses(
      nets, config.reward_scaling, config.discount,
      config.target_entropy_per_action * action_size)
  policy_opt = _make_optimizer(config.actor_learning_rate, config.max_grad_norm)
  q_opt = _make_optimizer(config.critic_learning_rate, config.max_grad_norm)
  alpha_opt = optax.adam(config.alpha_learning_rate)

  zeros_obs = jnp.zeros((obs_size,), jnp.float32)
  dummy = sac_losses.Transition(observation=zeros_obs,
                                action=jnp.zeros((action_size,), jnp.float32),
                                reward=jnp.zeros((), jnp.float32),
                                discount=jnp.zeros((), jnp.float32),
                                next_observation=zeros_obs)
  buffer = replay_buffers.UniformSamplingQueue(
      max_replay_size=config.replay_capacity, dummy_data_sample=dummy,
      sample_batch_size=config.batch_size * config.grad_updates_per_step)
  v_reset = jax.vmap(env.reset)
  v_step = env.step_batch  # the physics of all envs in one call (Warp, MuJoCo C)
  num_prefill_steps = -(-config.min_replay_size // num_envs)

  def collect(ts: TrainingState, key: jax.Array, random_actions: bool
              ) -> Tuple[TrainingState, Metrics]:
    """One vmapped env step with auto-reset; the transitions go into the replay buffer."""
    k_act, k_reset = jax.random.split(key)
    state = ts.env_state
    obs = state.obs
    if random_actions:
      actions = jax.random.uniform(k_act, (num_envs, action_size), jnp.float32, -1.0, 1.0)
    else:
      actions = sac_networks.sample_actions(nets, ts.normalizer, ts.policy_params, k_act, obs)
    stepped = v_step(state, actions)
    done = stepped.done
    terminal = done * (1.0 - stepped.info['truncation'])
    failure = terminal * (1.0 - stepped.metrics['success'])
    reward = stepped.reward
    if config.absorbing_failure:
      reward = jnp.where(failure > 0, reward / (1.0 - config.discount), reward)
    reward = reward - config.failure_cost * failure
    transitions = sac_losses.Transition(observation=obs, action=actions, reward=reward,
                                        discount=1.0 - terminal,
                                        next_observation=stepped.obs)
    fresh = v_reset(jax.random.split(k_reset, num_envs))
    ret = ts.episode_return + stepped.reward
    metrics = {
        'episodes': jnp.sum(done),
        'episode_return_sum': jnp.sum(ret * done),
        'successes': jnp.sum(stepped.metrics['success'] * done),
        'reward_mean': jnp.mean(stepped.reward),
    }
    ts = ts.replace(
        env_state=trees.where(done > 0, fresh, stepped),
        episode_return=ret * (1.0 - done),
        normalizer=sac_networks.update_normalizer(ts.normalizer, obs),
        buffer_state=buffer.insert(ts.buffer_state, transitions))
    return ts, metrics

  def sgd_step(carry: Tuple[TrainingState, jax.Array], batch: sac_losses.Transition):
    """One update of temperature, critics (then target critics) and actor."""
    ts, key = carry
    key, k_alpha, k_critic, k_actor = jax.random.split(key, 4)
    alpha = jnp.exp(ts.log_alpha)
    alpha_loss, g = jax.value_and_grad(alpha_loss_fn)(ts.log_alpha, ts.policy_params,
                                                      ts.normalizer, batch, k_alpha)
    upd, alpha_os = alpha_opt.update(g, ts.alpha_optimizer_state, ts.log_alpha)
    log_alpha = optax.apply_updates(ts.log_alpha, upd)
    critic_loss, g = jax.value_and_grad(critic_loss_fn)(
        ts.q_params, ts.policy_params, ts.normalizer, ts.target_q_params, alpha, batch, k_critic)
    upd, q_os = q_opt.update(g, ts.q_optimizer_state, ts.q_params)
    q_params = optax.apply_updates(ts.q_params, upd)
    actor_loss, g = jax.value_and_grad(actor_loss_fn)(ts.policy_params, ts.normalizer,
                                                      q_params, alpha, batch, k_actor)
    upd, policy_os = policy_opt.update(g, ts.policy_optimizer_state, ts.policy_params)
    policy_params = optax.apply_updates(ts.policy_params, upd)
    target = jax.tree.map(lambda t, q: (1.0 - config.tau) * t + config.tau * q,
                          ts.target_q_params, q_params)
    ts = ts.replace(policy_params=policy_params, policy_optimizer_state=policy_os,
                    q_params=q_params, target_q_params=target, q_optimizer_state=q_os,
                    log_alpha=log_alpha, alpha_optimizer_state=alpha_os,
                    gradient_steps=ts.gradient_steps + 1)
    metrics = {'critic_loss': critic_loss, 'actor_loss': actor_loss, 'alpha_loss': alpha_loss,
               'alpha': alpha}
    return (ts, key), metrics

  def training_step(ts: TrainingState, _) -> Tuple[TrainingState, Metrics]:
    key, k_collect, k_sgd = jax.random.split(ts.key, 3)
    ts, env_metrics = collect(ts.replace(key=key), k_collect, random_actions=False)
    buffer_state, batch = buffer.sample(ts.buffer_state)
    batch = jax.tree.map(
        lambda x: jnp.reshape(x, (config.grad_updates_per_step, config.batch_size)
                              + x.shape[1:]), batch)
    (ts, _), sgd_metrics = jax.lax.scan(sgd_step, (ts.replace(buffer_state=buffer_state),
                                                   k_sgd), batch)
    return ts, dict(env_metrics, **jax.tree.map(jnp.mean, sgd_metrics))

  def epoch(ts: TrainingState) -> Tuple[TrainingState, Metrics]:
    ts, metrics = jax.lax.scan(training_step, ts, None, length=config.steps_per_epoch)
    summed = ('episodes', 'episode_return_sum', 'successes')
    out = {k: (jnp.sum(v) if k in summed else jnp.mean(v)) for k, v in metrics.items()}
    out['buffer_size'] = buffer.size(ts.buffer_state)
    return _strong_types(ts.replace(epoch=ts.epoch + 1)), out

  def fresh_envs(k_env: jax.Array, k_t: jax.Array) -> base.State:
    """[num_envs] new episodes (with desync_episodes, at random time steps)."""
    env_state = v_reset(jax.random.split(k_env, num_envs))
    if config.desync_episodes:
      t0 = jax.random.randint(k_t, (num_envs,), 0, env.episode_length, jnp.int32)
      node = env_state.pipeline_state
      env_state = env_state.replace(pipeline_state=node.replace(t=t0.astype(node.t.dtype)))
    return env_state

  def prefill(ts: TrainingState, key: jax.Array, random_actions: bool) -> TrainingState:
    """ts after min_replay_size env steps into its buffer (uniform random or policy actions)."""
    def step(carry, step_key):
      carry, _ = collect(carry, step_key, random_actions=random_actions)
      return carry, None

    if num_prefill_steps > 0:
      ts, _ = jax.lax.scan(step, ts, jax.random.split(key, num_prefill_steps))
    return ts

  def init() -> TrainingState:
    key = jax.random.PRNGKey(config.seed)
    k_policy, k_q, k_env, k_buffer, k_prefill, k_run, k_t = jax.random.split(key, 7)
    env_state = fresh_envs(k_env, k_t)
    policy_params = nets.policy_init(k_policy)
    q_params = nets.q_init(k_q)
    log_alpha = jnp.log(jnp.asarray(config.init_alpha, jnp.float32))
    ts = TrainingState(
        policy_params=policy_params, policy_optimizer_state=policy_opt.init(policy_params),
        q_params=q_params, target_q_params=q_params, q_optimizer_state=q_opt.init(q_params),
        log_alpha=log_alpha, alpha_optimizer_state=alpha_opt.init(log_alpha),
        normalizer=sac_networks.init_normalizer(obs_size),
        env_state=env_state,
        episode_return=jnp.zeros((num_envs,), jnp.float32),
        buffer_state=buffer.init(k_buffer), key=k_run,
        epoch=jnp.zeros((), jnp.int32), gradient_steps=jnp.zeros((), jnp.int32))

    return _strong_types(prefill(ts, k_prefill, random_actions=True))

  def refill(learner: Dict[str, Any]) -> TrainingState:
    k_run, k_env, k_buffer, k_fill, k_t = jax.random.split(learner['key'], 5)
    ts = TrainingState(**dict(learner, key=k_run), env_state=fresh_envs(k_env, k_t),
                       episode_return=jnp.zeros((num_envs,), jnp.float32),
                       buffer_state=buffer.init(k_buffer))

    return _strong_types(prefill(ts, k_fill, random_actions=False))

  return Trainer(env=env, config=config, networks=nets, init=jax.jit(init),
                 refill=jax.jit(refill),
                 epoch=jax.jit(epoch, donate_argnums=0),
                 prefill_env_steps=num_prefill_steps * num_envs,
                 env_steps_per_epoch=num_envs * config.steps_per_epoch)
