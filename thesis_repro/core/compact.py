"""Compact, lossless storage of an entry's arrays (``arrays.npz``): the same arrays back, bit for bit, in fewer bytes.

A training run's ``arrays.npz`` holds its curves (``curve_*``) and every finished episode (``episode_*``): float64
and int64 arrays that plain deflate compresses poorly. :func:`write_compact` stores each array with the first of
these lossless steps that applies, then deflates it:

* a 1-D integer array equal to the running sum of another one (``episode_timesteps`` of a one-env run is
  ``cumsum(episode_lengths)``) is stored as that reference alone;
* float64 values that float32 holds exactly (episode returns: VecMonitor sums rewards in float32) are stored as
  float32 (compared bit for bit, NaN payloads included);
* a 1-D integer array is stored as its first differences when that narrows it (step counters), then in the
  narrowest integer type that holds it;
* the bytes are shuffled into byte planes (all first bytes, then all second bytes, ...), which deflate
  compresses far better for numbers whose high bytes repeat.

The file stays a zip: one deflated member per array (``z/<name>``, raw bytes) and ``z/codec.json``, which holds
per array its dtype, shape, steps and the SHA-256 of its original bytes. :func:`read_arrays` reads both this
format and the plain ``.npz`` that :func:`thesis_repro.core.cache.save_arrays` writes, and checks every decoded array
against its digest: a compact file that does not decode to what was stored is an error, never silently other
numbers. :func:`write_compact` decodes what it wrote before it returns, so a codec bug cannot lose a number.

>>> import tempfile, pathlib
>>> p = pathlib.Path(tempfile.mkdtemp()) / "arrays.npz"
>>> lengths = np.array([20, 31, 12])
>>> arrays = {"episode_lengths": lengths, "episode_timesteps": np.cumsum(lengths), "r": np.array([1.5, np.nan])}
>>> write_compact(p, arrays)
>>> back = read_arrays(p)
>>> all(back[k].dtype == v.dtype and back[k].tobytes() == v.tobytes() for k, v in arrays.items())
True
>>> is_compact(p)
True
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

#: Version of the compact layout (``codec.json``'s ``format``); a reader refuses any other.
FORMAT = 1
#: The members of a compact file: ``PREFIX + name`` per array, and the codec.
PREFIX = "z/"
CODEC = PREFIX + "codec.json"
_INTS = (np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32, np.int64)


class CompactError(ValueError):
    """A compact arrays file that does not decode to the arrays it recorded (corrupt, or an unknown format)."""


def _digest(a: np.ndarray) -> str:
    h = hashlib.sha256(f"{a.dtype.str}|{list(a.shape)}|".encode())
    h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _shuffle(raw: bytes, itemsize: int) -> bytes:
    if itemsize == 1 or not raw:
        return raw
    return np.frombuffer(raw, np.uint8).reshape(-1, itemsize).T.tobytes()


def _unshuffle(raw: bytes, itemsize: int) -> bytes:
    if itemsize == 1 or not raw:
        return raw
    return np.frombuffer(raw, np.uint8).reshape(itemsize, -1).T.tobytes()


def _narrowest(a: np.ndarray) -> np.dtype:
    lo, hi = (int(a.min()), int(a.max())) if a.size else (0, 0)
    for t in _INTS:
        info = np.iinfo(t)
        if info.min <= lo and hi <= info.max:
            return np.dtype(t)
    return a.dtype  # unsigned beyond int64: as is


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def same_arrays(x: Mapping[str, np.ndarray], y: Mapping[str, np.ndarray]) -> bool:
    """Whether ``x`` and ``y`` hold the same named arrays, bit for bit (dtype, shape and bytes).

    >>> a = {"r": np.array([1.0, np.nan])}
    >>> same_arrays(a, {"r": np.array([1.0, np.nan])}), same_arrays(a, {"r": np.array([1.0, np.nan], "f4")})
    (True, False)
    """
    return set(x) == set(y) and all(_same_bits(x[k], y[k]) for k in x)


def _encode(name: str, a: np.ndarray, plain_ints: Mapping[str, np.ndarray]) -> tuple[dict[str, Any], bytes | None]:
    """(spec, stored bytes) of one array; ``plain_ints``: the 1-D integer arrays stored as themselves so far."""
    spec: dict[str, Any] = {"dtype": a.dtype.str, "shape": list(a.shape), "sha256": _digest(a)}
    if a.dtype.kind in "iu" and a.ndim == 1 and a.dtype.itemsize == 8:
        for ref, r in plain_ints.items():
            if len(r) == len(a) and np.array_equal(np.cumsum(r, dtype=np.int64), a):
                return {**spec, "cumsum_of": ref}, None
    stored, delta = a, False
    if a.dtype == np.float64 and a.size:
        f32 = a.astype(np.float32)
        if _same_bits(f32.astype(np.float64), a):
            stored = f32
    elif a.dtype.kind in "iu" and a.dtype.itemsize <= 8 and a.size:
        stored = a.astype(_narrowest(a))
        if a.ndim == 1 and a.dtype.kind == "i" and len(a) > 1:
            d = np.diff(a.astype(np.int64), prepend=np.int64(0))
            if _narrowest(d).itemsize < stored.dtype.itemsize:
                stored, delta = d.astype(_narrowest(d)), True
    stored = np.ascontiguousarray(stored)
    spec.update(store=stored.dtype.str, delta=delta)
    return spec, _shuffle(stored.tobytes(), stored.dtype.itemsize)


def _decode(spec: Mapping[str, Any], raw: bytes | None, done: Mapping[str, np.ndarray]) -> np.ndarray:
    dtype, shape = np.dtype(spec["dtype"]), tuple(spec["shape"])
    if "cumsum_of" in spec:
        ref = done[spec["cumsum_of"]]
        return np.cumsum(ref, dtype=np.int64).astype(dtype).reshape(shape)
    store = np.dtype(spec["store"])
    if raw is None or len(raw) % max(store.itemsize, 1):
        raise CompactError("stored bytes do not fit the stored type")
    a = np.frombuffer(_unshuffle(raw, store.itemsize), store)
    if spec.get("delta"):
        a = np.cumsum(a, dtype=np.int64)
    return a.astype(dtype).reshape(shape)


def write_compact(path: str | Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Write ``arrays`` to ``path`` in the compact format (bytes depend on the arrays only); checks that the file
    reads back bit for bit before returning (``CompactError`` otherwise)."""
    path = Path(path)
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    specs: dict[str, Any] = {}
    blobs: dict[str, bytes] = {}
    plain_ints: dict[str, np.ndarray] = {}
    for name in sorted(arrays, key=lambda k: (k != "episode_lengths", k)):  # the reference first
        if "/" in name:
            raise ValueError(f"array name {name!r} has a '/'")
        a = arrays[name]
        if a.dtype.kind not in "fiub" or a.dtype.byteorder == ">":
            raise ValueError(f"cannot store array {name!r} of dtype {a.dtype} compactly; valid kinds are: f, i, u, b")
        spec, raw = _encode(name, a, plain_ints)
        specs[name] = spec
        if raw is not None:
            blobs[name] = raw
            if a.dtype.kind in "iu" and a.ndim == 1 and a.dtype.itemsize == 8:
                plain_ints[name] = a
    codec = {"format": FORMAT, "order": list(specs), "arrays": specs}
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
        for member, data in [(CODEC, json.dumps(codec, sort_keys=True).encode())] + [
            (PREFIX + k, v) for k, v in blobs.items()
        ]:
            info = zipfile.ZipInfo(member, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, data, compresslevel=9)
    back = read_arrays(path)
    if not same_arrays(back, arrays):
        raise CompactError(f"{path} does not read back bit for bit")  # pragma: no cover - a codec bug


def is_compact(path: str | Path) -> bool:
    """Is ``path`` an arrays file in the compact format (else a plain ``.npz``)?"""
    with zipfile.ZipFile(path) as zf:
        return CODEC in zf.namelist()


def read_arrays(path: str | Path) -> dict[str, np.ndarray]:
    """The arrays of ``path``, compact or plain ``.npz``; ``CompactError`` if a compact file does not decode to
    the arrays it recorded."""
    with zipfile.ZipFile(path) as zf:
        names = zf.namelist()
        if CODEC not in names:
            with np.load(path, allow_pickle=False) as npz:
                return {k: npz[k] for k in npz.files}
        codec = json.loads(zf.read(CODEC))
        if codec.get("format") != FORMAT:
            raise CompactError(f"{path}: compact format {codec.get('format')!r}; this kit reads format {FORMAT}")
        out: dict[str, np.ndarray] = {}
        for name in codec["order"]:
            spec = codec["arrays"][name]
            raw = zf.read(PREFIX + name) if PREFIX + name in names else None
            try:
                a = _decode(spec, raw, out)
            except (KeyError, ValueError, TypeError) as err:
                raise CompactError(f"{path}: array {name!r} cannot be decoded ({err})") from err
            if _digest(a) != spec["sha256"]:
                raise CompactError(f"{path}: array {name!r} does not match its recorded digest")
            out[name] = a
    return out
