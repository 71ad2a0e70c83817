"""JAX's persistent compilation cache, on by default in the user's cache directory, so that a
second run of a command skips XLA compilation, and beside it the traced search programs
(`jax.export`) and their compiled executables, so that it also skips Python tracing, lowering and
the cache lookup; a command line's executables can load at its start, beside its imports
(`Prefetch`)."""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import functools
import hashlib
import importlib.metadata
import logging
import os
import pickle
import threading
import time
from typing import Any, Callable, Iterator, List, Optional

import jax
from jax.experimental import serialize_executable
import numpy as np

LOGGER = logging.getLogger(__name__)
ENV_VAR = 'PACHS_COMPILATION_CACHE'  # a directory, or 0 / off / false to disable


def default_dir() -> Optional[str]:
  """The cache directory: $PACHS_COMPILATION_CACHE, else $XDG_CACHE_HOME/pachs_jax/jax (default
  ~/.cache); None when the variable disables it."""
  value = os.environ.get(ENV_VAR, '').strip()
  if value.lower() in ('0', 'off', 'false', 'no'):
    return None
  if value:
    return value
  base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
  return os.path.join(base, 'pachs_jax', 'jax')


def enable(path: Optional[str] = None) -> Optional[str]:
  """Points JAX's persistent compilation cache at path (None: `default_dir()`), caching every
  program however quick its compilation; returns the directory, or None when disabled or not
  writable (the command then runs without the cache)."""
  path = path or default_dir()
  if path is None:
    return None
  try:
    os.makedirs(path, exist_ok=True)
  except OSError:
    return None
  if not os.access(path, os.W_OK):
    return None
  jax.config.update('jax_compilation_cache_dir', path)
  jax.config.update('jax_persistent_cache_min_compile_time_secs', 0.0)
  jax.config.update('jax_persistent_cache_min_entry_size_bytes', 0)
  threading.Thread(target=drop_unreadable_entries, args=(path,), name='cache-check',
                   daemon=True).start()
  return path


CHECKED = 'pachs_checked.txt'  # the entries `drop_unreadable_entries` has read: name size mtime


def drop_unreadable_entries(path: str) -> List[str]:
  """Removes the entries of JAX's persistent compilation cache at path that do not decompress
  (garbage, a write cut short): JAX warns about such an entry on every run and never replaces
  it; removed, it is compiled and written anew. Entries read once are listed in path/CHECKED
  (name, size, mtime) and not read again. Returns the names removed; errors are ignored (the
  cache only saves time)."""
  try:
    from jax._src import compilation_cache as jax_cache  # how JAX compresses its entries
    decompress = jax_cache.decompress_executable
  except (ImportError, AttributeError):
    return []
  index = os.path.join(path, CHECKED)
  try:
    with open(index) as f:
      checked = set(f.read().splitlines())
  except OSError:
    checked = set()
  kept, removed = [], []
  try:
    entries = sorted(os.scandir(path), key=lambda e: e.name)
  except OSError:
    return []
  for entry in entries:
    if not entry.name.endswith('-cache') or not entry.is_file():
      continue
    try:
      stat = entry.stat()
      line = f'{entry.name} {stat.st_size} {stat.st_mtime_ns}'
      if line not in checked:
        with open(entry.path, 'rb') as f:
          decompress(f.read())
      kept.append(line)
    except OSError:
      continue
    except Exception:  # pylint: disable=broad-except  (any decompression error)
      try:
        os.remove(entry.path)
        removed.append(entry.name)
      except OSError:
        pass
  if set(kept) != checked:
    _write(index, ''.join(f'{line}\n' for line in kept).encode())
  return removed


@dataclasses.dataclass
class CompileLog:
  """What JAX logged inside a `compile_log` block: the names of the XLA programs it compiled
  ('jit(name)', one entry per compilation) and its persistent-cache hit messages."""

  compiled: List[str] = dataclasses.field(default_factory=list)
  cache_hits: List[str] = dataclasses.field(default_factory=list)


@contextlib.contextmanager
def compile_log() -> Iterator[CompileLog]:
  """Records JAX's compilations inside the block (`jax.log_compiles`, the 'jax' logger at
  DEBUG); the logger's level and handlers are restored afterwards."""
  log = CompileLog()

  class Record(logging.Handler):
    def emit(self, record):
      message = record.getMessage()
      if message.startswith('Compiling '):
        log.compiled.append(message.split(' ')[1])
      elif 'cache hit' in message.lower():
        log.cache_hits.append(message)

  logger, handler = logging.getLogger('jax'), Record()
  level = logger.level
  logger.addHandler(handler)
  logger.setLevel(logging.DEBUG)
  try:
    with jax.log_compiles(True):
      yield log
  finally:
    logger.removeHandler(handler)
    logger.setLevel(level)


TRACES = 'traces'  # the cache's subdirectory for exported programs and their executables


@functools.lru_cache(maxsize=None)
def source_digest() -> str:
  """sha256 of the package's Python sources: a stored program is valid for this code only."""
  digest = hashlib.sha256()
  root = os.path.dirname(os.path.abspath(__file__))
  for folder, dirs, files in sorted(os.walk(root)):
    dirs.sort()
    for name in sorted(files):
      if name.endswith('.py'):
        with open(os.path.join(folder, name), 'rb') as f:
          digest.update(name.encode() + f.read())
  return digest.hexdigest()


@functools.lru_cache(maxsize=None)
def library_versions() -> tuple:
  """Versions of the libraries whose code a traced program contains (jax and its physics and
  network libraries); a stored program is valid for these only."""
  versions = []
  for name in ('jax', 'jaxlib', 'mujoco', 'mujoco-mjx', 'flax', 'brax'):
    try:
      versions.append((name, importlib.metadata.version(name)))
    except importlib.metadata.PackageNotFoundError:
      versions.append((name, None))
  return tuple(versions)


@dataclasses.dataclass(frozen=True)
class Program:
  """A compiled program, called with its arguments' pytree structure.

  call: the compiled function. out_shapes: its outputs, a pytree of ShapeDtypeStructs (known
    without tracing when the program was stored).
  """

  call: Callable[..., Any]
  out_shapes: Any

  def __call__(self, *args):
    return self.call(*args)


def _compile(jitted, args: tuple) -> Program:
  compiled = jitted.lower(*args).compile()
  return Program(compiled, jax.tree.map(lambda s: jax.ShapeDtypeStruct(s.shape, s.dtype),
                                        compiled.out_info))


def compiled_program(jitted, args: tuple, fingerprint: Optional[str],
                     donate_argnums: tuple = (), prefetch: Optional['Prefetch'] = None
                     ) -> Program:
  """`jitted.lower(*args).compile()` as a `Program`, skipping Python tracing where it can.

  With a fingerprint and the compilation cache on (jax_compilation_cache_dir set), the
  traced program (`jax.export`) and its compiled executable are stored under
  `<cache>/traces/` on first use, keyed by fingerprint, the package sources,
  `library_versions`, the devices and the argument shapes; later processes load the
  executable (else compile the stored trace; the CPU stores no executables). Programs that
  cannot be exported (host callbacks) are remembered as such and compiled as usual.
  fingerprint: names everything jitted closes over (env, model parameters, config); None
    turns the store off. args: arrays or ShapeDtypeStructs. prefetch: a command line's
    `Prefetch`, which loads the executable ahead and records its use.
  """
  directory = jax.config.jax_compilation_cache_dir
  if fingerprint is None or not directory:
    return _compile(jitted, args)
  leaves, treedef = jax.tree.flatten(args)
  specs = [jax.ShapeDtypeStruct(np.shape(x), x.dtype) for x in leaves]
  devices = [(d.platform, d.device_kind) for d in jax.devices()]
  if jax.config.jax_default_device is not None:  # a program for one device of several
    devices.append(str(jax.config.jax_default_device))
  key = hashlib.sha256(repr((fingerprint, source_digest(), library_versions(), devices,
                             str(treedef),
                             [(s.shape, str(s.dtype)) for s in specs])).encode()).hexdigest()
  path = os.path.join(directory, TRACES, key[:32])
  if os.path.exists(path + '.unexportable'):
    return _compile(jitted, args)
  if prefetch is not None:  # in the order the command asks for them
    prefetch.used.append(path + '.executable')
  stored = _load(path + '.executable', _executable, prefetch)
  if stored is None:
    traced = _load(path + '.exported', _exported) or _export(jitted, treedef, specs, path)
    if traced is None:  # not exportable (e.g. host callbacks)
      return _compile(jitted, args)
    stored = _compile_trace(*traced, args, specs, donate_argnums, path)
  compiled, out_def, out_specs = stored
  return Program(lambda *xs: jax.tree.unflatten(out_def, compiled(*jax.tree.leaves(xs))),
                 jax.tree.unflatten(out_def, out_specs))


def _export(jitted, treedef, specs: list, path: str):
  """(jax.export.Exported of jitted on the flat specs, output treedef), also written to
  path.exported; None (and path.unexportable written) when it cannot be exported."""
  out_defs = []

  def flat(*xs):
    out = jitted(*jax.tree.unflatten(treedef, xs))
    out_defs.append(jax.tree.structure(out))
    return jax.tree.leaves(out)

  try:
    exported = jax.export.export(jax.jit(flat))(*specs)
    blob = exported.serialize()
  except Exception:  # pylint: disable=broad-except  (e.g. host callbacks)
    _write(path + '.unexportable', b'')
    return None
  _write(path + '.exported', pickle.dumps((blob, out_defs[0])))
  return exported, out_defs[0]


def _compile_trace(exported, out_def, args: tuple, specs: list, donate_argnums: tuple,
                   path: str):
  """(compiled, out_def, output ShapeDtypeStructs) of an exported program; the executable is
  written to path.executable where the platform serialises it. Not on the CPU: an XLA:CPU
  executable loaded back can lack its kernels ('Function ... not found')."""
  starts = np.cumsum([0] + [len(jax.tree.leaves(a)) for a in args])
  donated = tuple(j for i in donate_argnums for j in range(starts[i], starts[i + 1]))
  compiled = jax.jit(exported.call, donate_argnums=donated).lower(*specs).compile()
  out_specs = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in exported.out_avals]
  if jax.default_backend() != 'cpu':
    try:
      _write(path + '.executable', pickle.dumps((
          serialize_executable.serialize(compiled), out_def,
          [(s.shape, s.dtype.name) for s in out_specs])))
    except Exception:  # pylint: disable=broad-except  (a platform that cannot serialise)
      pass
  return compiled, out_def, out_specs


def _exported(blob: bytes):
  """(jax.export.Exported, output treedef) of an '.exported' file."""
  program, out_def = pickle.loads(blob)
  return jax.export.deserialize(bytearray(program)), out_def


def _executable(blob: bytes):
  """(loaded executable, output treedef, output ShapeDtypeStructs) of an '.executable' file."""
  (program, in_tree, flat_out), out_def, out_specs = pickle.loads(blob)
  compiled = serialize_executable.deserialize_and_load(program, in_tree, flat_out)
  return compiled, out_def, [jax.ShapeDtypeStruct(shape, dtype) for shape, dtype in out_specs]


def _read(path: str, parse):
  """parse(the bytes at path), or None when missing or unreadable; logs its time (debug)."""
  began = time.perf_counter()
  try:
    with open(path, 'rb') as f:
      return parse(f.read())
  except Exception:  # pylint: disable=broad-except
    return None
  finally:
    LOGGER.debug('read %s in %.3f s (%.3f-%.3f s, thread %s)', os.path.basename(path),
                 time.perf_counter() - began, began, time.perf_counter(),
                 threading.current_thread().name)


def _load(path: str, parse, prefetch: Optional['Prefetch'] = None):
  """parse(the bytes at path), or None when missing or unreadable (then rewritten); an
  executable that prefetch loads is taken from it."""
  loaded = prefetch.take(path) if prefetch is not None else None
  return loaded if loaded is not None else _read(path, parse)


def _write(path: str, blob: bytes):
  """Writes atomically (a parallel process never reads half a file); errors are ignored: the
  store only saves time."""
  try:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    temporary = f'{path}.{os.getpid()}.{threading.get_ident()}.tmp'
    with open(temporary, 'wb') as f:
      f.write(blob)
    os.replace(temporary, path)
  except OSError:
    pass


COMMANDS = 'commands'  # the traces' subdirectory: per command line, the executables it used
READY_SUFFIX = '.ready_s'  # beside a command line's index: its seconds until programs were ready


class Prefetch:
  """The stored executables of one command line, loaded ahead of their use.

  index: the file listing the executables the command line used last time (`command_index`).
  `load()` reads them (in a thread of the caller's, beside its imports and model load);
  `compiled_program(..., prefetch=this)` takes them from here and records what it uses;
  `finish()` cancels what is still unread and writes the index back, with `ready_s` (the
  seconds the command took until its programs were ready, when its caller set it) beside it;
  `last_ready_s()` reads that of the last time.
  """

  def __init__(self, index: str):
    self.index = index
    self.ready_s: Optional[float] = None
    self.loading: dict = {}  # path -> Future of `_executable`'s result
    self.used: list = []  # the paths asked for now, in order
    self._lock = threading.Lock()
    self._finished = False

  def load(self) -> None:
    """Reads the listed executables, in this thread, one after another."""
    try:
      with open(self.index) as f:
        paths = [line.strip() for line in f if line.strip()]
    except OSError:
      paths = []
    futures = {path: concurrent.futures.Future() for path in paths}
    with self._lock:
      if self._finished:
        return
      self.loading.update(futures)
    try:
      for path, future in futures.items():
        if future.set_running_or_notify_cancel():
          future.set_result(_read(path, _executable))
    finally:  # should this thread fail, nobody waits for the rest
      for future in futures.values():
        future.cancel()

  def last_ready_s(self) -> Optional[float]:
    """The seconds this command line took until its programs were ready last time (None:
    not recorded)."""
    try:
      with open(self.index + READY_SUFFIX) as f:
        return float(f.read())
    except (OSError, ValueError):
      return None

  def take(self, path: str):
    """The loaded executable at path, waiting for one being read (None: not listed)."""
    with self._lock:
      loading = self.loading.pop(path, None)
    if loading is None:
      return None
    try:  # loads are serialised inside XLA: wait rather than load beside it
      return loading.result()
    except concurrent.futures.CancelledError:
      return None

  def finish(self, write: bool = True) -> None:
    """Cancels the loads not begun and, with write, lists the executables asked for, in that
    order, in the index (when they changed)."""
    with self._lock:
      self._finished = True
      loading, self.loading = self.loading, {}
    for future in loading.values():
      future.cancel()
    if not write:
      return
    if self.ready_s is not None:
      _write(self.index + READY_SUFFIX, f'{self.ready_s:.3f}'.encode())
    listed = [path for path in dict.fromkeys(self.used) if os.path.exists(path)]
    try:
      with open(self.index) as f:
        if f.read().split() == listed:
          return
    except OSError:
      pass
    _write(self.index, ''.join(f'{path}\n' for path in listed).encode())


def command_index(words) -> Optional[str]:
  """The file that lists the stored executables a command line (its words and working
  directory) used last time; None when the cache is off."""
  directory = default_dir()
  if directory is None:
    return None
  key = hashlib.sha256(repr((list(words), os.getcwd(), source_digest(),
                             library_versions())).encode()).hexdigest()
  return os.path.join(directory, TRACES, COMMANDS, key[:32] + '.txt')


@contextlib.contextmanager
def prefetching(words) -> Iterator[Optional[Prefetch]]:
  """Yields the `Prefetch` of the command line's words (None when the cache is off), loading
  in a thread (jax is imported before it starts, so the two threads never import one module at
  once); afterwards writes the index and waits for the thread, or after an error only cancels
  what it has not begun."""
  index = command_index(words)
  if index is None:
    yield None
    return
  prefetch = Prefetch(index)

  def load():
    try:
      prefetch.load()
    except Exception:  # pylint: disable=broad-except  (it only saves time)
      pass

  thread = threading.Thread(target=load, name='prefetch', daemon=True)
  thread.start()
  try:
    yield prefetch
  except BaseException:
    prefetch.finish(write=False)  # (an error exits without waiting for the thread)
    raise
  prefetch.finish()
  thread.join()
