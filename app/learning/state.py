"""Learner state as a self-describing document: plain JSON types, no pickle.

::

    {"format": "attune.learner-state", "format_version": 1,
     "algorithm": "hri", "params": {...},
     "mission": {"name": "office", "fingerprint": "sha256:..."},
     "version": 412, "episodes": 87,
     "arrays": {"visits": {"dtype": "<i8", "shape": [16, 30], "encoding": "zlib+base64",
                           "data": "..."}, ...},
     "pending": [[episode, context, state, action, reward, next_state, signal], ...]}

Arrays are stored little-endian, zlib-compressed and base64-encoded: exact (an imported learner
is bit-for-bit the exported one) and small (the tables are mostly zeros). Every way a document can
be wrong raises :class:`StateFormatError` with a sentence naming the field.
"""

from __future__ import annotations

import base64
import binascii
import zlib
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "StateFormatError",
    "decode_array",
    "encode_array",
    "same_state",
]

FORMAT = "attune.learner-state"
FORMAT_VERSION = 1
_DTYPES = {"<f8": np.float64, "<i8": np.int64, "|i1": np.int8}


class StateFormatError(ValueError):
    """An exported learner state that cannot be imported, with the reason."""


def encode_array(array: np.ndarray) -> dict[str, Any]:
    dtype = array.dtype.newbyteorder("<").str
    if dtype not in _DTYPES:
        raise TypeError(f"cannot export arrays of dtype {array.dtype}")
    raw = np.ascontiguousarray(array, dtype=dtype).tobytes()
    return {
        "dtype": dtype,
        "shape": list(array.shape),
        "encoding": "zlib+base64",
        # Level 1: the tables are mostly zeros, so it compresses about as well as the default
        # level at a fraction of the time (every model update stores the state).
        "data": base64.b64encode(zlib.compress(raw, 1)).decode("ascii"),
    }


def decode_array(
    doc: object, *, name: str, dtype: np.dtype[Any], shape: tuple[int, ...]
) -> np.ndarray:
    """Decode one array field, checking dtype, shape and finiteness against what is expected."""
    where = f"arrays.{name}"
    if not isinstance(doc, Mapping):
        raise StateFormatError(f"{where} must be an object with dtype, shape, encoding and data.")
    want = np.dtype(dtype).newbyteorder("<").str
    if doc.get("dtype") != want:
        raise StateFormatError(f"{where}.dtype must be {want!r}, got {doc.get('dtype')!r}.")
    if not isinstance(doc.get("shape"), list) or doc["shape"] != list(shape):
        raise StateFormatError(
            f"{where}.shape must be {list(shape)} for this mission, got {doc.get('shape')!r}."
        )
    if doc.get("encoding") != "zlib+base64":
        raise StateFormatError(f"{where}.encoding must be 'zlib+base64'.")
    data = doc.get("data")
    if not isinstance(data, str):
        raise StateFormatError(f"{where}.data must be a base64 string.")
    expected = int(np.prod(shape, dtype=np.int64)) * np.dtype(want).itemsize
    try:
        inflater = zlib.decompressobj()
        # Never inflate more than the array can hold (a small document must not become gigabytes).
        raw = inflater.decompress(
            base64.b64decode(data.encode("ascii"), validate=True), expected + 1
        )
    except (binascii.Error, zlib.error, UnicodeEncodeError, ValueError):
        raise StateFormatError(f"{where}.data is not valid zlib+base64.") from None
    if len(raw) != expected:
        raise StateFormatError(f"{where}.data holds {len(raw)} bytes, expected {expected}.")
    array = np.frombuffer(raw, dtype=want).reshape(shape).astype(dtype, copy=True)
    if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
        raise StateFormatError(f"{where} contains NaN or infinite values.")
    return array


def _raw(doc: Mapping[str, Any]) -> tuple[Any, Any, bytes]:
    data = doc.get("data")
    raw = zlib.decompress(base64.b64decode(data)) if isinstance(data, str) else b""
    return doc.get("dtype"), doc.get("shape"), raw


def same_state(a: Mapping[str, Any], b: Mapping[str, Any]) -> bool:
    """Whether two state documents hold the same learner: equal field for field, with arrays
    compared by their contents (one array can be compressed into different bytes)."""
    if {k: v for k, v in a.items() if k != "arrays"} != {
        k: v for k, v in b.items() if k != "arrays"
    }:
        return False
    arrays_a, arrays_b = a.get("arrays"), b.get("arrays")
    if not isinstance(arrays_a, Mapping) or not isinstance(arrays_b, Mapping):
        return arrays_a == arrays_b
    if set(arrays_a) != set(arrays_b):
        return False
    try:
        return all(_raw(arrays_a[n]) == _raw(arrays_b[n]) for n in arrays_a)
    except (binascii.Error, zlib.error, ValueError, TypeError, AttributeError):
        return False
