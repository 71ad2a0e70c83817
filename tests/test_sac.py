"""SAC trainer, checkpoints, resumption and evaluator on the analytic point-mass task (CPU).

One trainer (one compilation of init and epoch) is shared by every test through module fixtures.
"""

import dataclasses
import importlib.util
import json
import os
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import trees_equal

from pachs_jax.envs.point_mass import PointMassConfig, PointMassEnv
from pachs_jax.sac import checkpoint, evaluator, learner_file, presets, train
from pachs_jax.sac.trainer import from_model, make_trainer

TOTAL_STEPS = 4000  # env steps of the shared training run (10 epochs of 400 after prefill)
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope='module')
def env():
  return PointMassEnv()


@pytest.fixture(scope='module')
def trainer(env):
  config = dataclasses.replace(presets.preset('point-mass'), eval_instances=0)
  return make_trainer(env, config)


@pytest.fixture(scope='module')
def trained(trainer, tmp_path_factory):
  run_dir = str(tmp_path_factory.mktemp('run'))
  result = train.train(trainer, run_dir, TOTAL_STEPS)
  return run_dir, result


@pytest.fixture(scope='module')
def eval_nodes(env):
  return env.initial_nodes(jax.random.split(jax.random.PRNGKey(2024), 256))


# ---------------------------------------------------------------------- environment ----

def test_point_mass_transition(env):
  node = env.node_from_positions(jnp.array([0.0, 0.0]), jnp.array([0.3, 0.0]))
  nodes = jax.tree.map(lambda x: jnp.stack([x, x, x]), node)
  actions = jnp.array([[1.0, 0.0], [2.0, 0.0], [jnp.nan, 0.0]])
  out = env.evaluate(nodes, actions)
  np.testing.assert_allclose(out.next_node.qpos[0], [0.1, 0.0], atol=1e-6)
  np.testing.assert_allclose(out.next_node.qpos[1], [0.1, 0.0], atol=1e-6)  # action clipped
  np.testing.assert_allclose(out.next_node.qpos[2], [0.0, 0.0])  # invalid: does not move
  np.testing.assert_allclose(out.cost[0], 0.2 + 0.01, atol=1e-6)
  assert out.is_valid.tolist() == [True, True, False]
  assert out.next_node.t.tolist() == [1, 1, 1]
  near = env.node_from_positions(jnp.array([0.26, 0.0]), jnp.array([0.3, 0.0]))
  assert bool(env.goal_reached(near)) and not bool(env.goal_reached(node))
  keys = env.lattice_key(jax.tree.map(lambda x: x[None], near))
  assert keys.tolist() == [[10, 0]]
  assert env.observation_size == 4 and env.action_size == 2
  state = env.step(env.reset(jax.random.PRNGKey(0)), jnp.zeros(2))
  assert float(state.reward) <= 0.0


def test_a_batch_step_is_the_single_step_vmapped(env):
  """`step_batch` (one `evaluate` call, how the trainer steps Warp and MuJoCo C) equals the
  vmapped single-environment `step`, done flags and truncation included."""
  states = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(3), 64))
  states = states.replace(pipeline_state=states.pipeline_state.replace(
      t=jnp.arange(64, dtype=states.pipeline_state.t.dtype) % (env.episode_length + 1)))
  actions = jax.random.uniform(jax.random.PRNGKey(4), (64, 2), minval=-2.0, maxval=2.0)
  actions = actions.at[0, 0].set(jnp.nan)
  batched = env.step_batch(states, actions)
  assert trees_equal(batched, jax.vmap(env.step)(states, actions))
  assert float(batched.done[0]) == 1.0 and 0 < float(jnp.sum(batched.info['truncation'])) < 64
  with pytest.raises(ValueError, match=r'actions must have shape \[B, 2\]'):
    env.step_batch(states, actions[:, :1])


# ------------------------------------------------------------------------- learning ----

def test_learns_point_mass(env, trainer, trained, eval_nodes):
  _, result = trained
  assert result.finished and result.env_steps >= TOTAL_STEPS
  rates = evaluator.success_rates(env, result.actor_critic, eval_nodes, jax.random.PRNGKey(1))
  assert rates['deterministic'] >= 0.9, rates
  assert rates['stochastic'] >= 0.8, rates
  untrained = train.actor_critic_from_state(trainer, trainer.init())
  before = evaluator.success_rates(env, untrained, eval_nodes, jax.random.PRNGKey(1))
  assert before['deterministic'] < 0.5, before


def test_critic_prefers_moving_toward_goal(env, trained, eval_nodes):
  ac = trained[1].actor_critic
  obs = env.observe(eval_nodes)
  direction = eval_nodes.goal - eval_nodes.qpos
  direction = direction / jnp.linalg.norm(direction, axis=-1, keepdims=True)
  actions = jnp.stack([direction, -direction], axis=1)  # [B, 2, A]: toward, away
  q = ac.q_values(obs, actions)
  assert q.shape == (256, 2) and q.dtype == jnp.float32
  assert float(jnp.mean(q[:, 0] > q[:, 1])) > 0.9
  assert float(jnp.mean(q)) < 0.0  # rewards are costs: Q is a negative cost-to-go


# ---------------------------------------------------------------------- checkpoints ----

def test_checkpoint_round_trip(env, trained, eval_nodes):
  run_dir, result = trained
  loaded = checkpoint.load_actor_critic(run_dir, env=env)
  direct = checkpoint.load_actor_critic(os.path.join(run_dir, 'model'), task='point-mass')
  ac = result.actor_critic
  assert loaded.config == ac.config == direct.config
  obs = env.observe(eval_nodes)
  key = jax.random.PRNGKey(7)
  samples = jax.jit(lambda a, k, o: a.sample_actions(k, o, 5))
  for other in (loaded, direct):
    s0, s1 = samples(ac, key, obs), samples(other, key, obs)
    assert s0.shape == (256, 5, 2)
    np.testing.assert_array_equal(s0, s1)
    np.testing.assert_array_equal(ac.q_values(obs, s0), other.q_values(obs, s0))
    np.testing.assert_array_equal(ac.deterministic_action(obs), other.deterministic_action(obs))
  s = samples(loaded, key, obs)
  assert float(jnp.max(jnp.abs(s))) <= 1.0
  assert not np.array_equal(s[:, 0], s[:, 1])  # independent samples per state


def test_checkpoint_errors(env, trained, tmp_path):
  run_dir, _ = trained
  with pytest.raises(ValueError, match='does not exist'):
    checkpoint.load_actor_critic(str(tmp_path / 'missing'))
  with pytest.raises(ValueError, match='not an actor-critic checkpoint'):
    checkpoint.load_actor_critic(str(tmp_path))
  with pytest.raises(ValueError, match="trained on task 'point-mass', not 'pusht-fixed'"):
    checkpoint.load_actor_critic(run_dir, task='pusht-fixed')
  with pytest.raises(ValueError, match='observation size 4 != .* observation size 6'):
    checkpoint.load_actor_critic(run_dir, env=PointMassEnv(PointMassConfig(dim=3)))
  # A config that does not describe the stored parameters.
  bad = str(tmp_path / 'bad')
  shutil.copytree(os.path.join(run_dir, 'model'), bad)
  config_path = os.path.join(bad, checkpoint.CONFIG_FILE)
  with open(config_path) as f:
    meta = json.load(f)
  meta['model']['critic_hidden'] = [64, 64]
  with open(config_path, 'w') as f:
    json.dump(meta, f)
  with pytest.raises(ValueError, match='changed after it was written'):  # the meta hash
    checkpoint.load_actor_critic(bad, env=env)
  meta[checkpoint.META_HASH_KEY] = checkpoint.meta_hash(meta)  # an edit recorded as intended
  with open(config_path, 'w') as f:
    json.dump(meta, f)
  with pytest.raises(ValueError, match='has shape .* needs'):
    checkpoint.load_actor_critic(bad, env=env)
  meta['format'] = 'something-else'
  with open(config_path, 'w') as f:
    json.dump(meta, f)
  with pytest.raises(ValueError, match='unknown checkpoint format'):
    checkpoint.load_actor_critic(bad)


def test_actor_critic_input_errors(trained):
  ac = trained[1].actor_critic
  with pytest.raises(ValueError, match=r'obs must have shape \[B, 4\]'):
    ac.deterministic_action(jnp.zeros((3, 5)))
  with pytest.raises(ValueError, match='num must be a positive'):
    ac.sample_actions(jax.random.PRNGKey(0), jnp.zeros((3, 4)), 0)
  with pytest.raises(ValueError, match='actions must have shape'):
    ac.q_values(jnp.zeros((3, 4)), jnp.zeros((3, 2)))


# ------------------------------------------------------------------------- resuming ----

class _Killed(Exception):
  pass


class _KillAfter:
  """A reporter that aborts the run at the row of epoch `epochs` (a kill)."""

  def __init__(self, epochs):
    self.epochs, self.seen = epochs, 0

  def start(self, env_steps, total_env_steps):
    pass

  def report(self, env_steps, metrics):
    self.seen += 1
    if self.seen >= self.epochs:
      raise _Killed()

  def close(self):
    pass


def test_resume_is_bit_exact(trainer, trained, tmp_path):
  _, uninterrupted = trained
  # Checkpoints every 2 epochs, killed while writing epoch 4's row: an epoch's checkpoint
  # comes after its row (else the resumed run would lack that row), so it resumes from epoch 2.
  killed = str(tmp_path / 'killed')
  with pytest.raises(_Killed):
    train.train(trainer, killed, TOTAL_STEPS, checkpoint_every_epochs=2, reporter=_KillAfter(4))
  assert train.read_run_config(killed)['epoch'] == 2
  resumed = train.train(trainer, killed, TOTAL_STEPS, resume=True)
  assert resumed.finished and resumed.epoch == uninterrupted.epoch
  assert trees_equal(resumed.state, uninterrupted.state)
  # A time budget that ends the first call after one epoch, then a resumed second call.
  chunked = str(tmp_path / 'chunked')
  first = train.train(trainer, chunked, TOTAL_STEPS, max_minutes=1e-4)
  assert not first.finished and first.epoch == 1
  second = train.train(trainer, chunked, TOTAL_STEPS, resume=True)
  assert second.finished
  assert trees_equal(second.state.policy_params, uninterrupted.state.policy_params)
  assert trees_equal(second.state, uninterrupted.state)


def test_a_learner_file_continues_a_run_with_a_buffer_its_policy_refills(trainer, trained,
                                                                         tmp_path):
  """A run moved through its learner file (no buffer, no env states) keeps its networks,
  optimisers, normaliser and counters, refills the buffer with its policy and runs on."""
  path = str(tmp_path / 'learner.npz')
  half = train.train(trainer, str(tmp_path / 'first'), TOTAL_STEPS // 2, learner_out=path)
  template = jax.eval_shape(trainer.init)
  tree, meta = learner_file.load(path, template)
  assert trees_equal(tree, learner_file.learner(half.state))
  assert meta['epoch'] == half.epoch and meta['task'] == 'point-mass'
  refilled = trainer.refill(tree)
  kept = [f for f in learner_file.LEARNER_FIELDS if f not in ('key', 'normalizer')]
  for field in kept:
    assert trees_equal(getattr(refilled, field), getattr(half.state, field)), field
  assert int(refilled.buffer_state.insert_position) == trainer.prefill_env_steps
  # the refill's observations entered the normaliser, as every collected step's do
  assert int(refilled.normalizer.count) > int(half.state.normalizer.count)
  moved = train.train(trainer, str(tmp_path / 'moved'), TOTAL_STEPS, learner_from=path)
  assert moved.finished and moved.start_epoch == half.epoch
  assert int(moved.state.gradient_steps) == int(trained[1].state.gradient_steps)


def test_learner_file_errors(env, trainer, trained, tmp_path):
  _, result = trained
  path = str(tmp_path / 'learner.npz')
  learner_file.save(path, result.state, {'task': 'point-mass'})
  template = jax.eval_shape(trainer.init)
  with pytest.raises(learner_file.LearnerFileError, match='does not exist'):
    learner_file.load(str(tmp_path / 'none.npz'), template)
  with open(path, 'rb') as f:
    data = f.read()
  truncated = str(tmp_path / 'truncated.npz')
  with open(truncated, 'wb') as f:
    f.write(data[:len(data) // 2])
  with pytest.raises(learner_file.LearnerFileError, match='not a complete learner file'):
    learner_file.load(truncated, template)
  wider = make_trainer(env, dataclasses.replace(trainer.config, actor_hidden=(48, 32)))
  with pytest.raises(learner_file.LearnerFileError, match='another task or network size'):
    learner_file.load(path, jax.eval_shape(wider.init))
  with np.load(path) as stored:
    arrays = {k: stored[k] for k in stored.files}
  arrays['leaf0003'] = arrays['leaf0003'] + 1
  damaged = str(tmp_path / 'damaged.npz')
  np.savez(damaged, **arrays)
  with pytest.raises(learner_file.LearnerFileError, match='do not match their hash'):
    learner_file.load(damaged, template)


def test_restored_state_compiles_like_the_live_one(trainer, trained):
  """A restored state must lower to the same program as the in-memory state (same shardings,
  dtypes, structure); a different program may round differently on a GPU."""
  run_dir, result = trained
  ckpts = checkpoint.TrainingCheckpoints(os.path.join(run_dir, train.STATE_SUBDIR))
  restored = ckpts.restore(ckpts.latest_epoch(), jax.eval_shape(trainer.init))
  ckpts.close()
  assert trees_equal(restored, result.state)
  assert trainer.epoch.lower(restored).as_text() == trainer.epoch.lower(result.state).as_text()


def test_resume_guards(env, trainer, trained):
  run_dir, _ = trained
  with pytest.raises(ValueError, match='already holds training checkpoints'):
    train.train(trainer, run_dir, TOTAL_STEPS)
  other = make_trainer(env, dataclasses.replace(trainer.config, seed=5))
  with pytest.raises(ValueError, match='seed'):
    train.train(other, run_dir, TOTAL_STEPS, resume=True)
  with pytest.raises(ValueError, match="trained on task 'point-mass'"):
    class Renamed(PointMassEnv):
      name = 'other-task'
    train.train(make_trainer(Renamed(), trainer.config), run_dir, TOTAL_STEPS, resume=True)


def test_cli_refuses_conflicts(trained):
  run_dir, _ = trained
  spec = importlib.util.spec_from_file_location('train_cli',
                                                os.path.join(REPO, 'experiments', 'train.py'))
  cli = importlib.util.module_from_spec(spec)
  spec.loader.exec_module(cli)
  args = ['--task', 'point-mass', '--steps', str(TOTAL_STEPS), '--out', run_dir,
          '--progress', 'none', '--nondeterministic']
  with pytest.raises(SystemExit, match='pass --resume'):
    cli.main(args)
  with pytest.raises(SystemExit, match='seed stored 0 vs flag 3'):
    cli.main(args + ['--resume', '--seed', '3'])
  fresh = ['--steps', '100', '--out', run_dir + '-new', '--progress', 'none']
  with pytest.raises(SystemExit, match="--physics-preset applies to the PushT tasks, not "
                     "'point-mass'"):
    cli.main(['--task', 'point-mass', '--physics-preset', 'faithful'] + fresh)
  with pytest.raises(SystemExit, match="--physics-preset: unknown physics preset 'stiff'"):
    cli.main(['--task', 'pusht-fixed', '--physics-preset', 'stiff'] + fresh)
  with pytest.raises(SystemExit, match='--learner-from .* is not a file'):
    cli.main(['--task', 'point-mass', '--learner-from', run_dir + '/none.npz'] + fresh)
  assert cli.overrides(cli.parse_args(args + ['--hidden', '64,64', '--lr', '1e-3'])) == {
      'actor_hidden': (64, 64), 'critic_hidden': (64, 64), 'actor_learning_rate': 1e-3,
      'critic_learning_rate': 1e-3, 'alpha_learning_rate': 1e-3}


class _AlwaysInvalid(PointMassEnv):
  def transition(self, node, action):
    out = super().transition(node, action)
    return out.replace(is_valid=jnp.zeros((), bool), is_goal=jnp.zeros((), bool))


def test_a_failed_episode_end_is_charged_the_failure_cost(trainer):
  """Every edge fails: each stored transition is terminal, its reward the env's minus
  failure_cost (else ending early is the cheapest episode where rewards are negative costs)."""
  small = dataclasses.replace(trainer.config, min_replay_size=64, failure_cost=0.0)
  plain = make_trainer(_AlwaysInvalid(), small).init()
  charged = make_trainer(_AlwaysInvalid(), dataclasses.replace(small, failure_cost=7.0)).init()
  n = int(plain.buffer_state.insert_position)
  assert n == 64
  # a stored row: observation (4), action (2), reward, discount, next observation (4)
  reward = lambda ts: np.asarray(ts.buffer_state.data)[:n, 6]
  discount = np.asarray(charged.buffer_state.data)[:n, 7]
  np.testing.assert_allclose(reward(charged), reward(plain) - 7.0, atol=1e-5)
  assert np.all(discount == 0.0) and np.all(reward(plain) < 0.0)
  # absorbing: the failed step's reward as if kept for ever, then the failure cost
  absorbing = make_trainer(_AlwaysInvalid(), dataclasses.replace(
      small, failure_cost=7.0, absorbing_failure=True)).init()
  np.testing.assert_allclose(reward(absorbing), reward(plain) / (1 - small.discount) - 7.0,
                             rtol=1e-5)
  with pytest.raises(ValueError, match='failure_cost must be a finite number >= 0'):
    dataclasses.replace(small, failure_cost=-1.0)
  with pytest.raises(ValueError, match='absorbing_failure needs discount < 1, got 1.0'):
    dataclasses.replace(small, absorbing_failure=True, discount=1.0)


def test_fine_tuning_starts_from_the_model(env, trainer, trained, tmp_path):
  """A fine-tuning run starts from the model's actor, critics (also as targets) and observation
  statistics, and runs its epochs; a model of other sizes is refused in one line."""
  model = trained[1].actor_critic
  tuned = from_model(trainer.init(), model.params, 1e6)
  assert trees_equal(tuned.policy_params, model.params.policy)
  assert trees_equal(tuned.q_params, model.params.q)
  assert trees_equal(tuned.target_q_params, model.params.q)
  np.testing.assert_allclose(tuned.normalizer.mean, model.params.normalizer['mean'])
  np.testing.assert_allclose(tuned.normalizer.std, model.params.normalizer['std'])
  stepped, _ = trainer.epoch(tuned)  # donates its state: the copies are its own buffers
  assert int(stepped.epoch) == 1
  run = train.train(trainer, str(tmp_path / 'tuned'), 1, init_from=model)
  assert run.finished and run.epoch == 1
  wider = make_trainer(env, dataclasses.replace(trainer.config, actor_hidden=(48, 32)))
  with pytest.raises(train.RunDirError, match=r'actor_hidden \(32, 32\), this run \(48, 32\)'):
    train.train(wider, str(tmp_path / 'wider'), 1, init_from=model)


# ------------------------------------------------------------------------ evaluator ----


def test_evaluator_stops_at_success_or_invalid(env, trained, eval_nodes):
  ac = trained[1].actor_critic
  # The first instance starts on its goal: success after zero edges.
  at_goal = eval_nodes.replace(goal=eval_nodes.goal.at[0].set(eval_nodes.qpos[0]))
  res = evaluator.make_rollout_fn(env)(ac, at_goal, jax.random.PRNGKey(0))
  assert bool(res.success[0]) and int(res.steps[0]) == 0 and float(res.cost[0]) == 0.0
  assert bool(jnp.all(env.is_goal(res.final_node) == res.success))
  assert bool(jnp.all(res.steps <= env.episode_length))
  # The rollout stops at the first success: compare with a plain step-by-step rollout.
  step = jax.jit(lambda n: env.evaluate(n, ac.deterministic_action(env.observe(n))))
  node, first = at_goal, jnp.full((256,), -1)
  for t in range(env.episode_length):
    out = step(node)
    node = out.next_node
    first = jnp.where((first < 0) & out.is_goal, t + 1, first)
  first = first.at[0].set(0)
  expected = jnp.where(first >= 0, first, env.episode_length)
  assert float(jnp.mean(res.success == (first >= 0))) >= 0.95
  assert float(jnp.mean(res.steps == expected)) >= 0.95
  bad = evaluator.make_rollout_fn(_AlwaysInvalid())(ac, eval_nodes, jax.random.PRNGKey(0))
  start_goal = env.is_goal(eval_nodes)  # a few random starts lie within the goal radius
  np.testing.assert_array_equal(bad.invalid, ~start_goal)
  np.testing.assert_array_equal(bad.success, start_goal)
  np.testing.assert_array_equal(bad.steps, jnp.where(start_goal, 0, 1))
  np.testing.assert_array_equal(bad.final_node.qpos, eval_nodes.qpos)  # invalid edge not taken


def test_a_chunked_evaluation_equals_one_call_and_stops_between_chunks(env, trained, eval_nodes):
  ac = trained[1].actor_critic
  key = jax.random.PRNGKey(3)
  whole = evaluator.make_rollout_fn(env, deterministic=False)(ac, eval_nodes, key)
  chunked = evaluator.make_rollout_fn(env, deterministic=False, chunk_steps=7)
  for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(chunked(ac, eval_nodes, key))):
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-6)
  asked = []
  stopped = chunked(ac, eval_nodes, key, stop=lambda: asked.append(1) or len(asked) >= 2)
  assert stopped is None and len(asked) == 2  # after the second chunk, not at the end
