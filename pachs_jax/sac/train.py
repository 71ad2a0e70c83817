"""SAC training runs: the epoch loop with checkpoints, bit-exact resumption, time budgets and
evaluation (run directory layout: docs/sac.md)."""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import sys
import tempfile
import threading
import time
from typing import Any, Callable, Dict, Optional, Protocol

import jax
import numpy as np

from pachs_jax.envs import backends, mujoco_c
from pachs_jax.sac import checkpoint
from pachs_jax.sac import evaluator
from pachs_jax.sac import learner_file
from pachs_jax.sac.actor_critic import ActorCriticParams, ModelConfig, SacActorCritic
from pachs_jax.sac.config import SACConfig, config_from_dict, config_to_dict
from pachs_jax.sac.trainer import Trainer, TrainingState, from_model, make_trainer

__all__ = ['SACConfig', 'Trainer', 'TrainingState', 'make_trainer', 'train', 'TrainResult',
           'actor_critic_from_state', 'read_run_config', 'check_run_dir', 'RunDirError',
           'STATE_SUBDIR']

STATE_SUBDIR = 'state'
TRAINING_FORMAT = 'pachs_jax.sac_training/1'
# What a run writes into run_dir: directories, then files (reporting.RunReporter and
# experiments/train.py write the last three).
RUN_DIRS = (STATE_SUBDIR, checkpoint.MODEL_SUBDIR, 'tensorboard')
RUN_FILES = ('metrics.csv', 'status.json')
STOP_SIGNALS = ('SIGINT', 'SIGTERM')


class RunDirError(ValueError):
  """A run directory that cannot be used as asked (one line naming it): not writable, holding
  a run when a new one is asked for, holding none when --resume is, or another run's."""


class Reporter(Protocol):
  """Receives progress: start once, then one report per epoch, then close; a reporter with a
  `note(line)` method also gets one-line notes (what an epoch and an evaluation cost here, an
  evaluation skipped for the time budget)."""

  def start(self, env_steps: int, total_env_steps: int) -> None:
    ...

  def report(self, env_steps: int, metrics: Dict[str, float]) -> None:
    ...

  def close(self) -> None:
    ...


@dataclasses.dataclass
class TrainResult:
  """state: the final TrainingState; actor_critic: its exported networks; finished: the run
  reached total_env_steps (False when the time budget or a signal stopped it first);
  start_epoch: the epoch this call started from; interrupted: the name of the signal that
  stopped it ('SIGINT', 'SIGTERM'), else None."""

  state: TrainingState
  actor_critic: SacActorCritic
  epoch: int
  env_steps: int
  finished: bool
  start_epoch: int = 0
  interrupted: Optional[str] = None


def model_config(trainer: Trainer) -> ModelConfig:
  """The ModelConfig of the actor-critics a trainer exports."""
  env, config = trainer.env, trainer.config
  return ModelConfig(task=env.name, observation_size=env.observation_size,
                     action_size=env.action_size, actor_hidden=config.actor_hidden,
                     critic_hidden=config.critic_hidden, activation=config.activation,
                     normalize_observations=config.normalize_observations,
                     discount=config.discount, reward_scaling=config.reward_scaling,
                     episode_length=env.episode_length)


def actor_critic_from_state(trainer: Trainer, state: TrainingState) -> SacActorCritic:
  """The actor-critic (actor, twin critic, observation statistics) of a training state."""
  model = model_config(trainer)
  normalizer = {'mean': state.normalizer.mean, 'std': state.normalizer.std}
  params = ActorCriticParams(normalizer=normalizer, policy=state.policy_params,
                             q=state.q_params)
  return SacActorCritic(params=params, config=model)


def read_run_config(run_dir: str) -> Optional[Dict[str, Any]]:
  """Metadata (task, sizes, 'sac_config' dict, epoch, env_steps) of a run directory's latest
  training checkpoint, or None when it has none."""
  directory = os.path.join(run_dir, STATE_SUBDIR)
  if not os.path.isdir(directory):
    return None
  ckpts = checkpoint.TrainingCheckpoints(directory)
  try:
    latest = ckpts.latest_epoch()
    return None if latest is None else ckpts.read_meta(latest)
  finally:
    ckpts.close()


def check_run_dir(run_dir: str) -> None:
  """Raises RunDirError unless run_dir (created if missing) and every path a run writes in it
  can be written: a file where a directory belongs, or a read-only one, fails here, before any
  training instead of at the first checkpoint."""
  if os.path.exists(run_dir) and not os.path.isdir(run_dir):
    raise RunDirError(f'run directory {run_dir}: is a file, not a directory')
  try:
    os.makedirs(run_dir, exist_ok=True)
  except OSError as e:
    raise RunDirError(f'run directory {run_dir}: cannot be created ({e.strerror})') from None
  for name in RUN_DIRS + RUN_FILES:
    path = os.path.join(run_dir, name)
    if not os.path.exists(path):
      continue
    if (name in RUN_DIRS) != os.path.isdir(path):
      kind = 'a directory' if name in RUN_DIRS else 'a file'
      raise RunDirError(f'run directory {run_dir}: {name} must be {kind}')
  probes = [run_dir] + [os.path.join(run_dir, d) for d in RUN_DIRS
                        if os.path.isdir(os.path.join(run_dir, d))]
  for directory in probes:
    try:
      fd, probe = tempfile.mkstemp(prefix='.write-test-', dir=directory)
      os.close(fd)
      os.remove(probe)
    except OSError as e:
      raise RunDirError(f'run directory {run_dir}: cannot write in {directory} '
                        f'({e.strerror})') from None
  for name in RUN_FILES:
    path = os.path.join(run_dir, name)
    if os.path.exists(path):
      try:
        with open(path, 'a'):
          pass
      except OSError as e:
        raise RunDirError(f'run directory {run_dir}: cannot write {path} ({e.strerror})') from None


class _StopSignals:
  """While active (main thread only): the first SIGINT/SIGTERM asks the run to stop after the
  current epoch (`requested` holds its name); a second one ends the process at once with one
  line and exit status 128 + signal number, without saving (no Python exception: one raised
  inside JAX's compiler or runtime can crash the interpreter's exit). A signal this process
  inherited as ignored stays ignored."""

  def __init__(self, enabled: bool, run_dir: str):
    self.requested: Optional[str] = None
    self._enabled = enabled and threading.current_thread() is threading.main_thread()
    self._run_dir = run_dir
    self._previous: Dict[int, Any] = {}
    self._notice: Optional[threading.Timer] = None

  def _handle(self, signum: int, frame: Any) -> None:
    del frame
    name = signal.Signals(signum).name
    if self.requested is not None:
      sys.stdout.flush()
      print(f'stopped by {name} without saving; {self._run_dir} keeps its latest checkpoint',
            file=sys.stderr, flush=True)
      os._exit(128 + signum)  # pylint: disable=protected-access
    self.requested = name
    # A note only if the epoch in flight (or the first compilation) takes a while.
    self._notice = threading.Timer(3.0, lambda: print(
        f'{name}: saving a checkpoint after the current epoch (signal again to stop without '
        'saving)', file=sys.stderr, flush=True))
    self._notice.daemon = True
    self._notice.start()

  def __enter__(self) -> '_StopSignals':
    if self._enabled:
      for name in STOP_SIGNALS:
        signum = getattr(signal, name)
        if signal.getsignal(signum) is not signal.SIG_IGN:
          self._previous[signum] = signal.signal(signum, self._handle)
    return self

  def acknowledge(self) -> None:
    if self._notice is not None:
      self._notice.cancel()

  def __exit__(self, *exc: Any) -> None:
    self.acknowledge()
    for signum, handler in self._previous.items():
      signal.signal(signum, handler)


def _check_meta(trainer: Trainer, meta: Dict[str, Any], where: str) -> None:
  env = trainer.env
  if meta.get('format') != TRAINING_FORMAT:
    raise checkpoint.CheckpointError(f'{where}: unknown training checkpoint format '
                                     f'{meta.get("format")!r}')
  missing = [k for k in ('task', 'observation_size', 'action_size', 'sac_config', 'epoch',
                         'env_steps') if k not in meta]
  if missing:
    raise checkpoint.CheckpointError(f'{where}: its meta lacks {missing} (file damaged?)')
  if meta['task'] != env.name:
    raise RunDirError(f'{where} was trained on task {meta["task"]!r}, not {env.name!r}')
  if (meta['observation_size'], meta['action_size']) != (env.observation_size, env.action_size):
    raise RunDirError(f'{where}: observation/action sizes {meta["observation_size"]}/'
                      f'{meta["action_size"]} != env {env.name!r} sizes '
                      f'{env.observation_size}/{env.action_size}')
  try:
    stored = config_from_dict(SACConfig, meta['sac_config'])
  except (TypeError, ValueError) as e:
    raise checkpoint.CheckpointError(f'{where}: invalid stored sac_config ({e})') from None
  diff = stored.differences(trainer.config)
  if diff:
    lines = ', '.join(f'{k}: checkpoint {a!r} vs requested {b!r}' for k, (a, b) in diff.items())
    raise RunDirError(f'{where}: the run was started with a different SACConfig ({lines}); '
                      'resume with the stored config (see read_run_config)')


FINE_TUNE_OBSERVATIONS = 1e6  # weight of a fine-tuned model's observation statistics


def _check_model(trainer: Trainer, model: SacActorCritic) -> None:
  """RunDirError, one line, unless `model` has the trainer's task and network sizes."""
  want = model_config(trainer)
  have = model.config
  for name in ('task', 'observation_size', 'action_size', 'actor_hidden', 'critic_hidden',
               'activation', 'normalize_observations'):
    if getattr(have, name) != getattr(want, name):
      raise RunDirError(f'the model to fine-tune has {name} {getattr(have, name)!r}, this run '
                        f'{getattr(want, name)!r}')


def _host_metrics(metrics: Dict[str, Any]) -> Dict[str, float]:
  m = {k: float(v) for k, v in jax.device_get(metrics).items()}
  episodes = m.get('episodes', 0.0)
  m['episode_return'] = m['episode_return_sum'] / episodes if episodes > 0 else math.nan
  m['success_rate'] = m['successes'] / episodes if episodes > 0 else math.nan
  return m


POLL_SECONDS = 0.05


def wait_ready(tree: Any) -> Any:
  """The tree once all its arrays are computed, waiting in short sleeps: signal handlers run
  between them, and with one computation in flight at a time the next dispatch never queues
  inside XLA (where a handler would wait for the queue)."""
  leaves = [x for x in jax.tree.leaves(tree) if isinstance(x, jax.Array)]
  while not all(x.is_ready() for x in leaves):
    time.sleep(POLL_SECONDS)
  return tree


def evaluation_env(trainer: Trainer):
  """The env of the evaluation rollouts: the trainer's, with MuJoCo C physics for PushT when
  JAX runs on the CPU (`backends.make_backend` 'auto')."""
  if isinstance(trainer.env, mujoco_c.MujocoCEnv):
    return trainer.env
  return backends.make_backend(trainer.env, 'auto')


def evaluation_env_steps(trainer: Trainer) -> int:
  """Env steps of one evaluation at most: a deterministic and a stochastic rollout of an
  episode from each of eval_instances start nodes."""
  return 2 * trainer.config.eval_instances * trainer.env.episode_length


EVALUATION_CHUNK_STEPS = 10  # steps per jitted call of an evaluation rollout (stop checked between)


def _make_evaluation(trainer: Trainer):
  """fn(state, stop) -> eval metrics over a fixed set of start nodes ({} once stop() turns
  True, checked every EVALUATION_CHUNK_STEPS steps), or None when disabled."""
  count = trainer.config.eval_instances
  if count == 0:
    return None
  env = evaluation_env(trainer)
  key = jax.random.fold_in(jax.random.PRNGKey(trainer.config.seed), 0x5EED)
  nodes = wait_ready(jax.jit(env.initial_nodes)(jax.random.split(key, count)))
  det = evaluator.make_rollout_fn(env, deterministic=True,
                                  chunk_steps=EVALUATION_CHUNK_STEPS)
  sto = evaluator.make_rollout_fn(env, deterministic=False,
                                  chunk_steps=EVALUATION_CHUNK_STEPS)

  def evaluate(state: TrainingState, stop: Callable[[], bool]) -> Dict[str, float]:
    ac = actor_critic_from_state(trainer, state)
    d = det(ac, nodes, key, stop)
    s = sto(ac, nodes, key, stop) if d is not None else None
    if s is None:
      return {}
    wait_ready((d, s))
    return {'eval_success_deterministic': float(np.mean(d.success)),
            'eval_success_stochastic': float(np.mean(s.success)),
            'eval_cost_deterministic': float(np.mean(d.cost))}

  return evaluate


class _Timing:
  """What epochs, saves and evaluations have cost in this call (seconds)."""

  def __init__(self, trainer: Trainer, evaluates: bool):
    self.trainer = trainer
    self.evaluates = evaluates
    self.epochs: list = []
    self.save_seconds = 0.0
    self.evaluation_seconds: Optional[float] = None

  def add_epoch(self, seconds: float, note, epoch: int) -> None:
    self.epochs.append(seconds)
    t = self.trainer
    if len(self.epochs) == 1:
      note(f'epoch {epoch}: {t.env_steps_per_epoch} env steps and '
           f'{t.config.steps_per_epoch * t.config.grad_updates_per_step} gradient updates took '
           f'{seconds:.1f} s here (compilation included)')
    elif len(self.epochs) == 2:
      line = f'an epoch takes about {seconds:.2g} s here'
      if self.evaluates and self.evaluation_seconds is None:
        line += f'; an evaluation about {self.evaluation_estimate():.0f} s (estimated)'
      note(line)

  def next_epoch(self) -> float:
    """Seconds to budget for one more epoch and the save after it, with its evaluation once
    two epochs tell the compilation from the work."""
    recent = self.epochs[-1] if len(self.epochs) < 2 else min(self.epochs[-2:])
    known = self.evaluation_seconds is not None or len(self.epochs) >= 2
    return 1.2 * recent + self.save_seconds + (self.evaluation_estimate() if self.evaluates
                                               and known else 0.0)

  def evaluation_estimate(self) -> float:
    """The last evaluation's time; before the first, its env steps at the fastest epoch's rate
    plus the first epoch's compilation time (as a stand-in for the rollouts' own)."""
    if self.evaluation_seconds is not None:
      return self.evaluation_seconds
    if not self.epochs:
      return 0.0
    fastest = min(self.epochs)
    per_step = fastest / self.trainer.env_steps_per_epoch
    return per_step * evaluation_env_steps(self.trainer) + (self.epochs[0] - fastest)


def train(trainer: Trainer, run_dir: str, total_env_steps: int, *, resume: bool = False,
          start_if_missing: bool = False, max_minutes: Optional[float] = None,
          checkpoint_minutes: float = 5.0, checkpoint_every_epochs: int = 0,
          keep_checkpoints: int = 3, reporter: Optional[Reporter] = None,
          handle_signals: bool = False, started_at: Optional[float] = None,
          learner_from: Optional[str] = None, learner_out: Optional[str] = None,
          init_from: Optional[SacActorCritic] = None) -> TrainResult:
  """Trains until total_env_steps (rounded up to whole epochs), the time budget or a signal.

  resume: continue from run_dir's latest checkpoint; a run_dir without one is a RunDirError
    unless start_if_missing (then it starts a new run). Without resume, a run_dir that already
    holds checkpoints is a RunDirError.
  max_minutes: wall-time budget of this call, evaluations included: it stops before an epoch
    that would overrun it (judged by the last epoch's time), checkpoints and returns
    (finished=False); an evaluation that would overrun it is skipped (a note says so). The first
    epoch (with its compilation) is the unit it cannot split. The budget counts from
    started_at (a `time.time()`, e.g. when a command began, its start-up then included;
    None: this call).
  checkpoint_minutes / checkpoint_every_epochs: save when either is due (0 disables the latter);
    the second epoch and the end of the call always save.
  handle_signals: (main thread) the first SIGINT or SIGTERM (handled at once, also while
    XLA computes: results are awaited in short sleeps) stops the run after the current epoch;
    it saves that epoch like the time budget does and returns (finished=False,
    interrupted='SIGINT'/'SIGTERM'); a second signal ends the process at once (os._exit with
    128 + signal number, one line on stderr), without saving.
  learner_from: a new run (run_dir without checkpoints) continues the learner of this
    `learner_file` (its epoch and counters), with fresh environments and a replay buffer
    refilled by its policy; ignored when run_dir holds a checkpoint to resume.
  init_from: a new run (no checkpoint, no learner_from) fine-tunes this actor-critic (same
    task and network sizes): its actor, critics and observation statistics replace the fresh
    ones after the random prefill (`trainer.from_model`).
  learner_out: every save also writes the learner to this file (a run that moves between
    machines through files of a few MB).
  Damaged checkpoints raise checkpoint.CheckpointError, bad learner files
  learner_file.LearnerFileError; all three errors are ValueErrors.
  """
  if total_env_steps < 1:
    raise ValueError(f'total_env_steps must be >= 1, got {total_env_steps}')
  if max_minutes is not None and max_minutes <= 0:
    raise ValueError(f'max_minutes must be > 0, got {max_minutes}')
  start_time = time.time() if started_at is None else started_at
  deadline = None if max_minutes is None else start_time + 60.0 * max_minutes
  check_run_dir(run_dir)
  stop = _StopSignals(handle_signals, run_dir)
  with stop:
    return _train(trainer, run_dir, total_env_steps, resume, start_if_missing, start_time,
                  deadline, checkpoint_minutes, checkpoint_every_epochs, keep_checkpoints,
                  reporter, stop, learner_from, learner_out, init_from)


def _train(trainer: Trainer, run_dir: str, total_env_steps: int, resume: bool,
           start_if_missing: bool, start_time: float, deadline: Optional[float],
           checkpoint_minutes: float, checkpoint_every_epochs: int, keep_checkpoints: int,
           reporter: Optional[Reporter], stop: _StopSignals, learner_from: Optional[str],
           learner_out: Optional[str], init_from: Optional[SacActorCritic]) -> TrainResult:
  env, config = trainer.env, trainer.config
  ckpts = checkpoint.TrainingCheckpoints(os.path.join(run_dir, STATE_SUBDIR),
                                         keep=keep_checkpoints)
  latest = ckpts.latest_epoch()
  if latest is not None and not resume:
    ckpts.close()
    raise RunDirError(f'{run_dir!r} already holds training checkpoints (latest epoch {latest}); '
                      'pass resume=True (--resume) to continue it or choose another directory')
  if latest is None and resume and not start_if_missing:
    ckpts.close()
    raise RunDirError(f'{run_dir!r} holds no training run to resume (no checkpoint in '
                      f'{STATE_SUBDIR}/); drop resume (--resume) to start one, or pass '
                      'start_if_missing (--start-if-missing)')
  try:
    if latest is not None:
      _check_meta(trainer, ckpts.read_meta(latest), os.path.join(run_dir, STATE_SUBDIR))
      state = ckpts.restore(latest, jax.eval_shape(trainer.init))
      epoch = latest
    elif learner_from is not None:
      tree, meta = learner_file.load(learner_from, jax.eval_shape(trainer.init))
      _check_meta(trainer, dict(meta, format=TRAINING_FORMAT), learner_from)
      init_start = time.time()
      state = wait_ready(trainer.refill(tree))
      init_seconds = time.time() - init_start
      epoch = int(meta['epoch'])
    else:
      init_start = time.time()
      state = wait_ready(trainer.init())
      if init_from is not None:
        _check_model(trainer, init_from)
        state = from_model(state, init_from.params, FINE_TUNE_OBSERVATIONS)
      init_seconds = time.time() - init_start
      epoch = 0
  except BaseException:
    ckpts.close()
    raise
  start_epoch = epoch
  num_epochs = trainer.num_epochs(total_env_steps)
  reporter_ = reporter
  note = getattr(reporter_, 'note', None) or (lambda line: None)
  if latest is None and trainer.prefill_env_steps:
    how = 'policy' if learner_from is not None else 'random'
    note(f'prefill: {trainer.prefill_env_steps} {how} env steps in {init_seconds:.1f} s '
         '(compilation included)')
  evaluate = _make_evaluation(trainer)
  if reporter_ is not None:
    reporter_.start(trainer.env_steps(epoch), trainer.env_steps(num_epochs))
  timing = _Timing(trainer, evaluate is not None)

  def evaluation(state: TrainingState, epoch: int) -> Dict[str, float]:
    """The evaluation's metrics at a save, or {} when it would not fit in the time budget
    (with the save after it) or a signal asked to stop."""
    if evaluate is None or stop.requested is not None:
      return {}
    estimate = timing.evaluation_estimate()
    if deadline is not None and time.time() + estimate + timing.save_seconds > deadline:
      note(f'epoch {epoch}: evaluation skipped (about {estimate:.0f} s, past the time budget)')
      return {}
    t = time.time()
    result = evaluate(state, lambda: stop.requested is not None)
    if not result:  # a signal stopped it: the epoch is saved without it
      return {}
    first = timing.evaluation_seconds is None
    timing.evaluation_seconds = time.time() - t
    if first:
      note(f'an evaluation ({evaluation_env_steps(trainer)} env steps at most) took '
           f'{timing.evaluation_seconds:.1f} s here (compilation included)')
    return result

  def save(state: TrainingState, epoch: int) -> None:
    """Saves the training checkpoint and the model of the epoch."""
    env_steps = trainer.env_steps(epoch)
    meta = {'format': TRAINING_FORMAT, 'task': env.name,
            'observation_size': env.observation_size, 'action_size': env.action_size,
            'sac_config': config_to_dict(config), 'epoch': epoch, 'env_steps': env_steps}
    t = time.time()
    ckpts.save(epoch, state, meta)
    if learner_out is not None:
      learner_file.save(learner_out, state, dict(meta, physics=checkpoint.physics_record(env)))
    checkpoint.save_actor_critic(os.path.join(run_dir, checkpoint.MODEL_SUBDIR),
                                 actor_critic_from_state(trainer, state),
                                 extra={'sac_config': config_to_dict(config), 'epoch': epoch,
                                        'env_steps': env_steps,
                                        'physics': checkpoint.physics_record(env)})
    timing.save_seconds = time.time() - t

  saved_epoch, last_save_time = epoch, time.time()
  try:
    while epoch < num_epochs:
      now = time.time()
      if stop.requested is not None:
        stop.acknowledge()
        break
      if deadline is not None and timing.epochs and now + timing.next_epoch() > deadline:
        break
      state, metrics = trainer.epoch(state)
      epoch += 1
      metrics = _host_metrics(wait_ready(metrics))
      epoch_seconds = time.time() - now
      timing.add_epoch(epoch_seconds, note, epoch)
      metrics.update(epoch=float(epoch), sps=trainer.env_steps_per_epoch / epoch_seconds,
                     walltime=time.time() - start_time)
      # The second epoch of a call saves too: from then on what a save and an evaluation cost
      # here is measured, not guessed.
      due = ((checkpoint_every_epochs > 0 and epoch % checkpoint_every_epochs == 0)
             or time.time() - last_save_time >= 60.0 * checkpoint_minutes
             or epoch == num_epochs or stop.requested is not None or len(timing.epochs) == 2)
      if not due and deadline is not None:
        due = time.time() + timing.next_epoch() > deadline
      if due:
        metrics.update(evaluation(state, epoch))
      # The epoch's row before its checkpoint: a run killed between the two resumes at the
      # earlier checkpoint and drops the rows past it, so each epoch keeps one row.
      if reporter_ is not None:
        reporter_.report(trainer.env_steps(epoch), metrics)
      if due:
        save(state, epoch)
        saved_epoch, last_save_time = epoch, time.time()
    if saved_epoch != epoch:
      save(state, epoch)
  finally:
    ckpts.close()
    if reporter_ is not None:
      reporter_.close()
  return TrainResult(state=state, actor_critic=actor_critic_from_state(trainer, state),
                     epoch=epoch, env_steps=trainer.env_steps(epoch),
                     finished=epoch >= num_epochs, start_epoch=start_epoch,
                     interrupted=stop.requested)
