"""NumPy functions called from jitted programs as XLA FFI custom calls on the CPU (a
`jax.pure_callback` elsewhere): programs that name a target, unlike those holding a callback,
are stored by JAX's persistent cache (docs/startup_and_caching.md). The handler speaks XLA's
FFI C API (xla/ffi/api/c_api.h, version 0.1) through ctypes."""

from __future__ import annotations

import ctypes
import threading
from typing import Callable, Dict, Sequence

import jax
import numpy as np

_EXECUTE = 3  # XLA_FFI_ExecutionStage_EXECUTE
_METADATA = 1  # XLA_FFI_Extension_Metadata
_INTERNAL = 13  # XLA_FFI_Error_Code_INTERNAL
_DTYPES = {1: np.bool_, 4: np.int32, 5: np.int64, 11: np.float32, 12: np.float64}  # XLA_FFI_DataType


class _Extension(ctypes.Structure):
  pass


_Extension._fields_ = [('struct_size', ctypes.c_size_t), ('type', ctypes.c_int),
                       ('next', ctypes.POINTER(_Extension))]


class _Version(ctypes.Structure):
  _fields_ = [('struct_size', ctypes.c_size_t), ('extension_start', ctypes.POINTER(_Extension)),
              ('major_version', ctypes.c_int), ('minor_version', ctypes.c_int)]


class _Metadata(ctypes.Structure):
  _fields_ = [('struct_size', ctypes.c_size_t), ('api_version', _Version),
              ('traits', ctypes.c_uint32), ('state_type_id', ctypes.c_int64)]


class _MetadataExtension(ctypes.Structure):
  _fields_ = [('extension_base', _Extension), ('metadata', ctypes.POINTER(_Metadata))]


class _Buffer(ctypes.Structure):
  _fields_ = [('struct_size', ctypes.c_size_t), ('extension_start', ctypes.POINTER(_Extension)),
              ('dtype', ctypes.c_int), ('data', ctypes.c_void_p), ('rank', ctypes.c_int64),
              ('dims', ctypes.POINTER(ctypes.c_int64))]


class _Operands(ctypes.Structure):  # XLA_FFI_Args and XLA_FFI_Rets share this layout
  _fields_ = [('struct_size', ctypes.c_size_t), ('extension_start', ctypes.POINTER(_Extension)),
              ('size', ctypes.c_int64), ('types', ctypes.POINTER(ctypes.c_int)),
              ('values', ctypes.POINTER(ctypes.POINTER(_Buffer)))]


class _Attrs(ctypes.Structure):
  _fields_ = [('struct_size', ctypes.c_size_t), ('extension_start', ctypes.POINTER(_Extension)),
              ('size', ctypes.c_int64), ('types', ctypes.c_void_p), ('names', ctypes.c_void_p),
              ('attrs', ctypes.c_void_p)]


class _ErrorArgs(ctypes.Structure):
  _fields_ = [('struct_size', ctypes.c_size_t), ('extension_start', ctypes.POINTER(_Extension)),
              ('message', ctypes.c_char_p), ('errc', ctypes.c_int)]


_ErrorCreate = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(_ErrorArgs))


class _Api(ctypes.Structure):  # the leading fields of XLA_FFI_Api, up to XLA_FFI_Error_Create
  _fields_ = [('struct_size', ctypes.c_size_t), ('extension_start', ctypes.POINTER(_Extension)),
              ('api_version', _Version), ('internal_api', ctypes.c_void_p),
              ('error_create', _ErrorCreate)]


class _CallFrame(ctypes.Structure):
  _fields_ = [('struct_size', ctypes.c_size_t), ('extension_start', ctypes.POINTER(_Extension)),
              ('api', ctypes.POINTER(_Api)), ('ctx', ctypes.c_void_p), ('stage', ctypes.c_int),
              ('args', _Operands), ('rets', _Operands), ('attrs', _Attrs),
              ('future', ctypes.c_void_p)]


_Handler = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(_CallFrame))

# this process's targets (XLA's table of them is per process): name -> the function behind
# it, and the ctypes handlers XLA holds. A name must fix what its function computes: a program
# stored by one process runs with the function registered under the name in another.
_functions: Dict[str, Callable] = {}
_handlers: Dict[str, object] = {}
_lock = threading.Lock()


def _array(buffer: _Buffer) -> np.ndarray:
  """The numpy view of an XLA buffer (no copy)."""
  dtype = _DTYPES.get(buffer.dtype)
  if dtype is None:
    raise TypeError(f'host_call: XLA data type {buffer.dtype} is not supported')
  shape = tuple(buffer.dims[i] for i in range(buffer.rank))
  if not buffer.data or 0 in shape:
    return np.empty(shape, dtype)
  size = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
  raw = (ctypes.c_char * size).from_address(buffer.data)
  return np.frombuffer(raw, dtype).reshape(shape)


def _handler(name: str):
  """The XLA FFI handler of target name: answers XLA's metadata query, then on each execution
  calls the function registered under name with the arguments and writes its results."""

  def handle(frame_pointer):
    frame = frame_pointer.contents
    extension = frame.extension_start
    if extension and extension.contents.type == _METADATA:
      metadata = ctypes.cast(extension, ctypes.POINTER(_MetadataExtension)).contents
      metadata.metadata.contents.api_version.major_version = 0
      metadata.metadata.contents.api_version.minor_version = 1
      return None
    if frame.stage != _EXECUTE:
      return None
    try:
      args = [_array(frame.args.values[i].contents) for i in range(frame.args.size)]
      outs = [_array(frame.rets.values[i].contents) for i in range(frame.rets.size)]
      for out, result in zip(outs, _results(name, args, [out.dtype for out in outs])):
        out[...] = result.reshape(out.shape)
      return None
    except Exception as e:  # pylint: disable=broad-except  (reported by XLA as the call's error)
      message = f'{name}: {type(e).__name__}: {e}'.encode()
      error = _ErrorArgs(ctypes.sizeof(_ErrorArgs), None, message, _INTERNAL)
      return frame.api.contents.error_create(ctypes.byref(error))

  return _Handler(handle)


def register(name: str, fn: Callable[..., object]) -> None:
  """Makes fn(*arrays) -> array or tuple of arrays the CPU target `name` of this process
  (again: fn replaces the function behind the name; it must compute the same). fn gets views
  of XLA's buffers, valid during the call only."""
  with _lock:
    _functions[name] = fn
    if name in _handlers:
      return
    _handlers[name] = handler = _handler(name)
  jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(handler), platform='cpu', api_version=1)


def _results(name: str, args: Sequence[np.ndarray], dtypes: Sequence) -> tuple:
  """The function behind name on host arrays, as arrays of the given dtypes."""
  out = _functions[name](*args)
  out = (out,) if len(dtypes) == 1 and not isinstance(out, tuple) else out
  if len(out) != len(dtypes):
    raise ValueError(f'gave {len(out)} results, the call takes {len(dtypes)}')
  return tuple(np.asarray(x, dtype) for x, dtype in zip(out, dtypes))


def call(name: str, results: Sequence[jax.ShapeDtypeStruct], *args) -> tuple:
  """The results of target name on args, from traced code; vmapped, one call takes the whole
  batch (leading axes on every argument and result). Lowered for the CPU it is the custom call;
  for another platform (whose buffers live on the device) a `jax.pure_callback` of the same
  function on host copies."""
  results = tuple(results)

  def on_cpu(*xs):
    return tuple(jax.ffi.ffi_call(name, results, vmap_method='broadcast_all')(*xs))

  def elsewhere(*xs):
    dtypes = [r.dtype for r in results]
    return tuple(jax.pure_callback(lambda *a: _results(name, a, dtypes), results, *xs,
                                   vmap_method='broadcast_all'))

  return jax.lax.platform_dependent(*args, cpu=on_cpu, default=elsewhere)
