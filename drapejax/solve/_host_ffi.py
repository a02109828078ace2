"""Host functions called from compiled programs as XLA FFI targets, so the programs can be cached.

The direct solver's sparse factorisations and the host eigenvalue clamp run in NumPy/CHOLMOD on
the host. Called through ``jax.pure_callback`` they make every program that holds them
uncacheable: JAX's persistent compilation cache refuses executables with host callbacks,
because such a callback is a Python object of the process that compiled it. Every drape,
estimate and diagnosis then compiled its programs again in each new process (54 programs,
about 30 s, for a 30 mm ``drapejax simulate``).

Here the same host functions are registered as named foreign-function targets of XLA's typed
FFI (the stable C ABI of ``xla/ffi/api/c_api.h``), with a handler written in ``ctypes``: a
compiled program refers to its host function by name only, so it can be written to the cache,
and a later process that traces the same program registers the same name (names are derived
from what the function is bound to: its kind, its settings and the sparsity pattern's hash)
before the cached executable runs.

The handler decodes the call frame (buffers: dtype, data, dims), wraps them as NumPy arrays
without copying, calls the Python function with the GIL held (ctypes takes it) and writes the
results into XLA's result buffers. It answers XLA's metadata query with the FFI version of the
header it follows. It never returns an error: a Python exception fills the results with NaN,
which every caller already reads as a failed solve, so that a batched run reports a status
instead of aborting.
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import threading
from collections.abc import Callable

import jax
import numpy as np

_log = logging.getLogger(__name__)

_FFI_API_MAJOR, _FFI_API_MINOR = 0, 3
_EXTENSION_METADATA = 1
_STAGE_EXECUTE = 3
_DTYPES = {1: np.bool_, 2: np.int8, 3: np.int16, 4: np.int32, 5: np.int64, 6: np.uint8, 7: np.uint16, 8: np.uint32,
           9: np.uint64, 10: np.float16, 11: np.float32, 12: np.float64}


class _ExtensionBase(ctypes.Structure):
    pass


_ExtensionBase._fields_ = [("struct_size", ctypes.c_size_t), ("type", ctypes.c_int),
                           ("next", ctypes.POINTER(_ExtensionBase))]


class _ApiVersion(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p),
                ("major_version", ctypes.c_int), ("minor_version", ctypes.c_int)]


class _Metadata(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("api_version", _ApiVersion), ("traits", ctypes.c_uint32),
                ("state_type_id", ctypes.c_int64)]


class _MetadataExtension(ctypes.Structure):
    _fields_ = [("extension_base", _ExtensionBase), ("metadata", ctypes.POINTER(_Metadata))]


class _Buffer(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p), ("dtype", ctypes.c_int),
                ("data", ctypes.c_void_p), ("rank", ctypes.c_int64), ("dims", ctypes.POINTER(ctypes.c_int64))]


class _List(ctypes.Structure):
    """``XLA_FFI_Args`` and ``XLA_FFI_Rets`` (same layout)."""

    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p), ("size", ctypes.c_int64),
                ("types", ctypes.POINTER(ctypes.c_int)), ("items", ctypes.POINTER(ctypes.c_void_p))]


class _Attrs(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.c_void_p), ("size", ctypes.c_int64),
                ("types", ctypes.c_void_p), ("names", ctypes.c_void_p), ("attrs", ctypes.c_void_p)]


class _CallFrame(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_size_t), ("extension_start", ctypes.POINTER(_ExtensionBase)),
                ("api", ctypes.c_void_p), ("ctx", ctypes.c_void_p), ("stage", ctypes.c_int), ("args", _List),
                ("rets", _List), ("attrs", _Attrs), ("future", ctypes.c_void_p)]


_HANDLER = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(_CallFrame))


def _array(pointer) -> np.ndarray:
    """The XLA buffer at ``pointer`` as a NumPy array over the same memory (no copy)."""
    buf = ctypes.cast(pointer, ctypes.POINTER(_Buffer)).contents
    dtype = np.dtype(_DTYPES[buf.dtype])
    shape = tuple(buf.dims[i] for i in range(buf.rank))
    size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if size == 0:
        return np.zeros(shape, dtype)
    raw = (ctypes.c_char * size).from_address(buf.data)
    return np.frombuffer(raw, dtype).reshape(shape)


def _handler(name: str, fn: Callable):
    """A typed-FFI handler that calls ``fn(*args) -> tuple of results`` on NumPy views."""

    def call(frame_pointer):
        frame = frame_pointer.contents
        if frame.extension_start and frame.extension_start.contents.type == _EXTENSION_METADATA:
            meta = ctypes.cast(frame.extension_start, ctypes.POINTER(_MetadataExtension)).contents.metadata.contents
            meta.api_version.struct_size = ctypes.sizeof(_ApiVersion)
            meta.api_version.extension_start = None
            meta.api_version.major_version = _FFI_API_MAJOR
            meta.api_version.minor_version = _FFI_API_MINOR
            meta.traits = 0
            meta.state_type_id = 0
            return None
        if frame.stage != _STAGE_EXECUTE:
            return None
        outs = [_array(frame.rets.items[i]) for i in range(frame.rets.size)]
        try:
            args = [_array(frame.args.items[i]) for i in range(frame.args.size)]
            results = fn(*args)
            for out, res in zip(outs, results, strict=True):
                out[...] = np.asarray(res, out.dtype).reshape(out.shape)
        except Exception:  # the caller reads NaN as a failed solve; XLA cannot take a Python error
            _log.exception("host function %s failed; its results are NaN", name)
            for out in outs:
                if np.issubdtype(out.dtype, np.floating):
                    out[...] = np.nan
        return None

    return _HANDLER(call)


_TARGETS: dict[str, object] = {}
_LOCK = threading.Lock()


def target_name(kind: str, *keys) -> str:
    """A target name for host function ``kind`` bound to ``keys`` (arrays hashed by their bytes,
    other values by their ``repr``): the same in every process that binds the same things."""
    digest = hashlib.sha1()
    for key in keys:
        if isinstance(key, np.ndarray):
            digest.update(str((key.dtype.str, key.shape)).encode())
            digest.update(np.ascontiguousarray(key).tobytes())
        else:
            digest.update(repr(key).encode())
    return f"drapejax_{kind}_{digest.hexdigest()[:20]}"


def register(name: str, fn: Callable) -> str:
    """Register ``fn(*numpy arrays) -> tuple of arrays`` as the CPU FFI target ``name`` (once per
    process; a name already registered keeps its first function)."""
    with _LOCK:
        if name not in _TARGETS:
            handler = _handler(name, fn)
            jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(handler), platform="cpu")
            _TARGETS[name] = handler
    return name


def host_call(name: str, fn: Callable, result_shapes, *args, vmap_method: str = "sequential"):
    """``fn`` on the host from a compiled program, like ``jax.pure_callback`` but cacheable.

    ``fn`` takes NumPy arrays and returns one array for a single ``jax.ShapeDtypeStruct``
    ``result_shapes``, else a tuple with one array per entry; ``name`` (``target_name``) must
    identify ``fn`` and everything it is bound to. The result has the structure of ``result_shapes``.
    """
    single = isinstance(result_shapes, jax.ShapeDtypeStruct)
    register(name, (lambda *a: (fn(*a),)) if single else fn)
    shapes = (result_shapes,) if single else tuple(result_shapes)
    out = jax.ffi.ffi_call(name, shapes, vmap_method=vmap_method)(*args)
    return out[0] if single else tuple(out)


__all__ = ["host_call", "register", "target_name"]
