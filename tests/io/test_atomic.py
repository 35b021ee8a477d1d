"""All-or-nothing outputs: bad output paths refused, hidden temporary names, clean-up on error and SIGTERM."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from mocapnet.clean import check_output_name
from mocapnet.io import MocapFileError, read_c3d, write_c3d
from mocapnet.io.atomic import atomic_output
from tests.conftest import SAMPLE_C3D_NAN

READER_GLOBS = ("*.c3d", "*.C3D", "*.bvh", "*.bvh.gz", "*.gz")


def unwritable_folder(tmp_path: Path) -> Path:
    """A folder this process cannot write in: a read-only folder, or ``/sys`` for root (who ignores modes)."""
    folder = tmp_path / "locked"
    folder.mkdir()
    folder.chmod(0o500)
    if os.access(folder, os.W_OK):
        folder.chmod(0o700)
        folder = Path("/sys")
        try:
            probe = folder / f".mocapnet-probe-{os.getpid()}"
            probe.write_bytes(b"")
            probe.unlink()
            pytest.skip("no folder here refuses writes to this user")
        except OSError:
            pass
    return folder


@pytest.mark.parametrize("name", ["out.c3d", "out.C3D", "walk.bvh", "walk.bvh.gz"])
def test_temporary_name_is_hidden_and_matched_by_no_reader_glob(tmp_path, name):
    with atomic_output(tmp_path / name) as tmp:
        tmp.write_bytes(b"partial")
        assert tmp.parent == tmp_path and tmp.name.startswith(f".{name}.") and tmp.name.endswith(".partial")
        for pattern in READER_GLOBS:
            assert list(tmp_path.rglob(pattern)) == []
    assert [p.name for p in tmp_path.iterdir()] == [name]


def test_failure_inside_the_block_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError), atomic_output(tmp_path / "x.c3d") as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("writer failed")
    assert list(tmp_path.iterdir()) == []


def test_previous_sigterm_handler_restored(tmp_path):
    before = signal.getsignal(signal.SIGTERM)
    with atomic_output(tmp_path / "x.bvh") as tmp:
        assert signal.getsignal(signal.SIGTERM) is not before
        tmp.write_text("x")
    assert signal.getsignal(signal.SIGTERM) is before


@pytest.mark.parametrize("kind", ["empty", "directory", "directory with slash", "parent is a file", "unwritable"])
def test_bad_output_paths_refused_with_one_line_and_nothing_written(tmp_path, kind):
    markers = read_c3d(SAMPLE_C3D_NAN)
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    out = {
        "empty": "",
        "directory": str(tmp_path / "adir"),
        "directory with slash": str(tmp_path / "newdir") + "/",
        "parent is a file": str(tmp_path / "afile" / "out.c3d"),
        "unwritable": str(unwritable_folder(tmp_path) / "out.c3d"),
    }[kind]
    before = sorted(p.name for p in tmp_path.rglob("*"))
    for source in (None, SAMPLE_C3D_NAN):
        with pytest.raises(MocapFileError) as err:
            write_c3d(out, markers, source=source)
        assert "\n" not in str(err.value)
        assert sorted(p.name for p in tmp_path.rglob("*")) == before
    assert not Path(out or "nonexistent").is_file()


@pytest.mark.parametrize("out", ["out", "out.bvh", "out.bvh.gz", "out.c3d.txt"])
def test_output_name_must_be_c3d_for_a_c3d_input(tmp_path, out):
    with pytest.raises(MocapFileError, match="output name must end in .c3d"):
        check_output_name(SAMPLE_C3D_NAN, tmp_path / out)
    check_output_name(SAMPLE_C3D_NAN, tmp_path / "out.C3D")  # the extension's case does not matter


def test_output_same_as_source_refused(tmp_path):
    src = tmp_path / "take.c3d"
    src.write_bytes(SAMPLE_C3D_NAN.read_bytes())
    with pytest.raises(MocapFileError, match="same as the input"):
        write_c3d(src, read_c3d(src), source=src)
    assert src.read_bytes() == SAMPLE_C3D_NAN.read_bytes()


CHILD = textwrap.dedent(
    """
    import signal, sys, time
    from pathlib import Path
    from mocapnet.io.atomic import atomic_output

    out = Path(sys.argv[1])
    if sys.argv[2] == "handler":
        signal.signal(signal.SIGTERM, lambda *a: print("own handler ran", flush=True))
    try:
        with atomic_output(out) as tmp:
            tmp.write_bytes(b"half a file")
            print("writing", tmp, flush=True)
            for _ in range(600):  # short sleeps: a signal taken by another thread (BLAS) wakes no long sleep
                time.sleep(0.05)
    except Exception as exc:
        print(type(exc).__name__, exc, flush=True)
        sys.exit(3)
    """
)


@pytest.mark.parametrize("previous", ["default", "handler"])
def test_sigterm_during_a_write_leaves_no_temporary_file(tmp_path, previous):
    out = tmp_path / "take.c3d"
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(out), previous], stdout=subprocess.PIPE, text=True, cwd=Path.cwd()
    )
    line = child.stdout.readline()
    assert line.startswith("writing")
    assert Path(line.split(" ", 1)[1].strip()).exists()
    child.send_signal(signal.SIGTERM)
    rest = child.communicate(timeout=20)[0]
    if previous == "default":
        assert child.returncode == -signal.SIGTERM  # the signal was handed on: the process ended by it
    else:
        assert child.returncode == 3 and "own handler ran" in rest and "interrupted by SIGTERM" in rest
    assert list(tmp_path.iterdir()) == []
