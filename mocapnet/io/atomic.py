"""Shared error type and all-or-nothing output for the file formats.

An output is written to a hidden temporary file beside it, ``.NAME.<random>.partial`` (a name no ``*.c3d``,
``*.bvh`` or ``*.bvh.gz`` glob matches), and moved onto ``NAME`` only when complete. The temporary file is
removed on any error, on Ctrl-C and on SIGTERM; only SIGKILL can leave one behind, and no reader picks it up.
"""

from __future__ import annotations

import os
import signal
import tempfile
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

PARTIAL_SUFFIX = ".partial"


class MocapFileError(ValueError):
    """A mocap file could not be read or written; the message names the file (and line or frame)."""


class _Terminated(BaseException):
    """SIGTERM arrived while an output was being written."""


def _raise_terminated(signum: int, frame: object) -> None:
    raise _Terminated(signum)


@contextmanager
def _sigterm_cleans_up() -> Iterator[None]:
    """While the block runs, SIGTERM unwinds it (so ``finally`` clauses run) and is then handed on.

    After the block is unwound the previous handler is restored and the signal sent again, so the process
    still ends (default handler) or the caller's own handler still runs. Outside the main thread, or when
    SIGTERM is ignored, nothing is installed.
    """
    previous = signal.getsignal(signal.SIGTERM)
    if previous in (signal.SIG_IGN, None) or threading.current_thread() is not threading.main_thread():
        yield  # ignored on purpose, set outside Python, or a thread (only the main thread may set handlers)
        return
    signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    except _Terminated:
        signal.signal(signal.SIGTERM, previous)
        os.kill(os.getpid(), signal.SIGTERM)
        raise MocapFileError("interrupted by SIGTERM; nothing was written") from None
    finally:
        signal.signal(signal.SIGTERM, previous)


def check_output_path(path: str | os.PathLike, inputs: Sequence[str | os.PathLike] = ()) -> Path:
    """Refuse an output path that cannot become a file: empty, a directory, equal to an input, or in a
    folder that cannot be created or written. Returns the path; raises ``MocapFileError`` with one line."""
    if not str(path).strip():
        raise MocapFileError("output path is empty; give a file name")
    out = Path(path)
    if out.is_dir() or str(path).endswith(("/", os.sep)):
        raise MocapFileError(f"{out}: is a directory; give a file name inside it")
    for src in inputs:
        if Path(src).resolve() == out.resolve():
            raise MocapFileError(f"{out}: output path is the same as the input; choose another output file")
    if out.parent.exists() and not out.parent.is_dir():
        raise MocapFileError(f"{out}: {out.parent} is a file, not a folder")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise MocapFileError(f"{out}: cannot create the folder {out.parent} ({exc.strerror or exc})") from None
    if not os.access(out.parent, os.W_OK | os.X_OK):
        raise MocapFileError(f"{out}: the folder {out.parent} is not writable")
    return out


@contextmanager
def atomic_output(path: str | os.PathLike, inputs: Sequence[str | os.PathLike] = ()) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` only if the block succeeds.

    The temporary name is ``.NAME.<random>.partial``: hidden, and matched by no ``*.c3d`` / ``*.bvh`` glob.
    Refuses (``MocapFileError``, nothing written) an output path that is empty, a directory, the same as
    one of ``inputs``, or in a folder that cannot be written. Nothing is left behind on failure, Ctrl-C or
    SIGTERM (the signal is handed on after the clean-up).
    """
    out = check_output_path(path, inputs)
    with _sigterm_cleans_up():
        tmp_path: Path | None = None
        try:
            try:
                fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=PARTIAL_SUFFIX, dir=out.parent)
            except OSError as exc:
                raise MocapFileError(f"{out}: cannot write in {out.parent} ({exc.strerror or exc})") from None
            os.close(fd)
            tmp_path = Path(tmp)
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual permissions
            yield tmp_path
            try:
                os.replace(tmp_path, out)
            except OSError as exc:
                raise MocapFileError(f"{out}: cannot move the finished file into place ({exc.strerror})") from None
        finally:
            if tmp_path is not None and tmp_path.exists():
                tmp_path.unlink()
