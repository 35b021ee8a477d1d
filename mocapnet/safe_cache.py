"""On-disk caches that are data, never code: ``.npz`` arrays plus a JSON header, a SHA-256 checksum over both,
read with ``allow_pickle=False``; keys are content hashes of the source files (not sizes or times).

A cache file that is missing, truncated, tampered with, of another version or holding object arrays raises
``CacheError``; callers rebuild it with a warning. Writes are atomic (temporary name, then rename) and a cache
folder that cannot be written only costs a warning.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import warnings
import zipfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

_META = "__meta__"
_CHUNK = 1 << 20


class CacheError(ValueError):
    """A cache entry cannot be trusted; rebuild it."""


def cache_dir() -> Path:
    """``$MOCAPNET_CACHE``, default ``~/.cache/mocapnet``."""
    return Path(os.environ.get("MOCAPNET_CACHE", Path.home() / ".cache" / "mocapnet"))


def content_hash(files: Iterable[str | os.PathLike], salt: str = "") -> str:
    """Hex SHA-256 over ``salt`` and, per file, its name and every byte of its content."""
    h = hashlib.sha256(salt.encode())
    for f in files:
        path = Path(f)
        h.update(f"\0{path.name}\0".encode())
        with open(path, "rb") as fh:
            while chunk := fh.read(_CHUNK):
                h.update(chunk)
    return h.hexdigest()


def _checksum(meta_text: str, arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256(meta_text.encode())
    for name in sorted(arrays):
        arr = np.ascontiguousarray(arrays[name])
        h.update(f"\0{name}\0{arr.dtype.str}\0{arr.shape}\0".encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def write_cache(path: str | os.PathLike, arrays: dict[str, np.ndarray], meta: dict) -> bool:
    """Write ``arrays`` (numeric or fixed-width string dtypes only) and a JSON-able ``meta`` to ``path``.

    Returns False (with a warning) when the cache folder cannot be written; the caller goes on uncached.
    """
    path = Path(path)
    for name, arr in arrays.items():
        if np.asarray(arr).dtype.hasobject:
            raise TypeError(f"cache array {name!r} has dtype object; only plain arrays are cached")
    meta_text = json.dumps(meta, sort_keys=True)
    header = json.dumps({"meta": meta_text, "checksum": _checksum(meta_text, arrays)})
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as fh:
                np.savez(fh, **{_META: np.array(header)}, **arrays)
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    except OSError as exc:
        warnings.warn(f"{path}: cannot write the cache ({exc.strerror or exc}); continuing without it", stacklevel=2)
        return False
    return True


def read_cache(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Read a cache written by ``write_cache``: ``(arrays, meta)``; ``CacheError`` if it cannot be trusted."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            if _META not in npz.files:
                raise CacheError(f"{path}: not a mocapnet cache (no header)")
            header = json.loads(str(npz[_META]))
            arrays = {name: npz[name] for name in npz.files if name != _META}
    except CacheError:
        raise
    except (OSError, ValueError, EOFError, KeyError, TypeError, zipfile.BadZipFile, json.JSONDecodeError) as exc:
        raise CacheError(f"{path}: unreadable cache ({type(exc).__name__}: {str(exc)[:80]})") from exc
    if not isinstance(header, dict) or not isinstance(header.get("meta"), str):
        raise CacheError(f"{path}: malformed cache header")
    if _checksum(header["meta"], arrays) != header.get("checksum"):
        raise CacheError(f"{path}: checksum mismatch (damaged or edited cache)")
    return arrays, json.loads(header["meta"])
