"""The wire format of `pachs serve` and its client: msgpack maps whose NumPy arrays travel as
{'__ndarray__': True, 'dtype', 'shape', 'data'} with dtypes from an allow-list. Decoding
builds arrays and plain values only: nothing on the wire is unpickled or run
(docs/serving.md)."""

from __future__ import annotations

from typing import Any

import msgpack
import numpy as np

# the dtypes an array may have on the wire (names as NumPy spells them, little-endian)
DTYPES = ('bool', 'uint8', 'int32', 'int64', 'uint32', 'float32', 'float64')

# the largest message either side decodes (bytes)
MAX_MESSAGE_BYTES = 64 * 1024 * 1024

ARRAY_TAG = '__ndarray__'


class WireError(ValueError):
  """A message that is no valid msgpack of the allowed values (one line)."""


def _encode(value: Any) -> Any:
  if isinstance(value, np.ndarray) or (hasattr(value, '__array__') and hasattr(value, 'dtype')
                                       and not isinstance(value, np.generic)):
    array = np.ascontiguousarray(np.asarray(value))
    name = array.dtype.newbyteorder('<').name if array.dtype.byteorder == '>' \
        else array.dtype.name
    if name not in DTYPES:
      raise WireError(f'arrays of dtype {array.dtype} do not travel; use one of '
                      f'{", ".join(DTYPES)}')
    return {ARRAY_TAG: True, 'dtype': name, 'shape': list(array.shape),
            'data': array.astype(array.dtype.newbyteorder('<'), copy=False).tobytes()}
  if isinstance(value, np.generic):
    return value.item()
  raise TypeError(f'cannot encode {type(value).__name__}')


def _decode(obj: dict) -> Any:
  if ARRAY_TAG not in obj:
    return obj
  dtype, shape, data = obj.get('dtype'), obj.get('shape'), obj.get('data')
  if set(obj) != {ARRAY_TAG, 'dtype', 'shape', 'data'}:
    raise WireError(f'an array must hold dtype, shape and data only, got {sorted(obj)}')
  if dtype not in DTYPES:
    raise WireError(f'array dtype {dtype!r} is not allowed; use one of {", ".join(DTYPES)}')
  if (not isinstance(shape, list) or len(shape) > 8
      or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape)):
    raise WireError(f'array shape must be a list of at most 8 sizes >= 0, got {shape!r}')
  if not isinstance(data, bytes):
    raise WireError('array data must be bytes')
  want = np.dtype(dtype).newbyteorder('<')
  if int(np.prod(shape, dtype=np.float64)) * want.itemsize != len(data):
    raise WireError(f'array of shape {shape} and dtype {dtype} needs '
                    f'{int(np.prod(shape)) * want.itemsize} bytes, got {len(data)}')
  return np.frombuffer(data, want).astype(want.newbyteorder('='), copy=True).reshape(shape)


def pack(message: dict) -> bytes:
  """The bytes of message: a map of msgpack values, NumPy arrays and scalars."""
  return msgpack.packb(message, default=_encode, use_bin_type=True)


def unpack(data: bytes) -> dict:
  """The map encoded in data, its arrays as NumPy arrays; WireError for anything else."""
  if not isinstance(data, (bytes, bytearray, memoryview)):
    raise WireError('messages are binary msgpack, not text')
  if len(data) > MAX_MESSAGE_BYTES:
    raise WireError(f'message of {len(data)} bytes exceeds {MAX_MESSAGE_BYTES}')
  try:
    message = msgpack.unpackb(bytes(data), object_hook=_decode, raw=False,
                              strict_map_key=True)
  except WireError:
    raise
  except Exception as err:  # pylint: disable=broad-except  (msgpack's many error types)
    raise WireError(f'not a msgpack message ({type(err).__name__}: '
                    f'{" ".join(str(err).split())[:120]})') from None
  if not isinstance(message, dict):
    raise WireError(f'a message must be a map, got {type(message).__name__}')
  return message
