"""Shared error type and all-or-nothing output for the file formats."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path


class MocapFileError(ValueError):
    """A mocap file could not be read or written; the message names the file (and line or frame)."""


@contextmanager
def atomic_output(path: str | os.PathLike, inputs: Sequence[str | os.PathLike] = ()) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` only if the block succeeds.

    Refuses an output path equal to any of ``inputs`` so a cleaning run never overwrites its source.
    Nothing is left behind on failure.
    """
    out = Path(path)
    for src in inputs:
        if Path(src).resolve() == out.resolve():
            raise MocapFileError(f"{out}: output path is the same as the input; choose another output file")
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=out.suffix, dir=out.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual permissions
    try:
        yield tmp_path
        os.replace(tmp_path, out)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()
