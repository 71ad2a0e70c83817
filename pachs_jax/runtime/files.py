"""Atomic file writes: a reader (or a run after a kill or a full disk) finds the old file or the
whole new one, never a part."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from typing import Any, IO, Iterator


class WriteError(OSError):
  """A file that could not be written (one line naming it and the reason); the old file, if
  any, is left as it was. str() is that line; errno is the cause's."""

  def __str__(self) -> str:
    return str(self.strerror)


@contextlib.contextmanager
def atomic_open(path: str, mode: str = 'w', **kwargs: Any) -> Iterator[IO]:
  """Opens a temporary file beside `path` ('w' text or 'wb' binary; kwargs go to open); on a
  clean exit it is flushed, fsynced and renamed over `path`, then the directory is fsynced. On
  any error it is removed and `path` is left as it was; an OSError becomes a WriteError. A
  `path` that exists as something else than a regular file (a directory, a device) is a
  WriteError before anything is written."""
  if mode not in ('w', 'wb'):
    raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
  path = os.fspath(path)
  if os.path.exists(path) and not os.path.isfile(path):
    raise WriteError(None, f'cannot write {path}: not a regular file')
  directory = os.path.dirname(os.path.abspath(path))
  try:
    fd, tmp = tempfile.mkstemp(prefix=f'.{os.path.basename(path)}.', suffix='.tmp',
                               dir=directory)
  except OSError as e:
    raise WriteError(e.errno, f'cannot write {path}: {e.strerror}') from None
  try:
    with os.fdopen(fd, mode, **kwargs) as f:
      yield f
      f.flush()
      os.fsync(f.fileno())
    os.chmod(tmp, _mode_for(path))  # mkstemp's 0600 would hide the file from others
    os.replace(tmp, path)
  except BaseException as e:
    with contextlib.suppress(OSError):
      os.remove(tmp)
    if isinstance(e, OSError) and not isinstance(e, WriteError):
      raise WriteError(e.errno, f'cannot write {path}: {e.strerror or e}') from None
    raise
  fsync_directory(directory)


def _mode_for(path: str) -> int:
  """The permission bits `path` keeps (an existing file's), or those a new file gets under the
  process's umask."""
  if os.path.exists(path):
    return os.stat(path).st_mode & 0o777
  mask = os.umask(0)
  os.umask(mask)
  return 0o666 & ~mask


def fsync_directory(directory: str) -> None:
  """Makes renames in `directory` durable (a no-op where directories cannot be opened)."""
  try:
    fd = os.open(directory, os.O_RDONLY)
  except OSError:
    return
  try:
    os.fsync(fd)
  except OSError:
    pass
  finally:
    os.close(fd)


def write_text(path: str, text: str) -> None:
  """Writes `text` to `path` atomically (atomic_open)."""
  with atomic_open(path, 'w') as f:
    f.write(text)


def write_bytes(path: str, data: bytes) -> None:
  """Writes `data` to `path` atomically (atomic_open)."""
  with atomic_open(path, 'wb') as f:
    f.write(data)


def write_json(path: str, data: Any, indent: int = 2) -> None:
  """Writes `data` as JSON (indented, newline-terminated) to `path` atomically; the data is
  serialized before the file is touched, so unserializable data leaves `path` untouched."""
  write_text(path, json.dumps(data, indent=indent) + '\n')
