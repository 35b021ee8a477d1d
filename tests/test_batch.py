"""Batch cleaning of a folder: equal to one-file cleans, on a Dask cluster given by address and on the default
LocalCluster; failures reported and skipped; reruns skip up-to-date outputs."""

from __future__ import annotations

import csv
import gzip
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mocapnet.batch import FAILED, UP_TO_DATE, clean_folder, plan
from mocapnet.clean import CleanOptions, clean_file
from mocapnet.cli import main
from mocapnet.io import read_bvh, write_bvh
from mocapnet.parallel import Parallel
from tests.conftest import SAMPLE_BVH, SAMPLE_C3D_NAN

DASK = [sys.executable, "-m", "dask"]  # the `dask` command of this environment


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> Path:
    """Six short BVH files cut from the shipped clip, in nested folders (one .bvh.gz)."""
    root = tmp_path_factory.mktemp("archive")
    motion = read_bvh(SAMPLE_BVH)
    names = ["a.bvh", "b.bvh", "take/c.bvh", "take/d.bvh.gz", "take/deep/e.bvh", "f.bvh"]
    for i, name in enumerate(names):
        start = 200 * i
        write_bvh(root / name, motion.with_channels(motion.channels[start : start + 150 + 10 * i]))
    return root


def _one_file_cleans(archive: Path, out: Path, options: CleanOptions) -> None:
    for src, dst in plan(archive, out):
        clean_file(src, dst, options)


def _same_tree(a: Path, b: Path) -> None:
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    assert files_a == files_b and files_a
    for rel in files_a:
        assert _payload(a / rel) == _payload(b / rel), rel


def _payload(path: Path) -> bytes:
    """File bytes; for .gz the uncompressed bytes (a gzip header holds a time stamp and the temp file name)."""
    return gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else path.read_bytes()


def _start(args: list[str], log: Path) -> subprocess.Popen:
    return subprocess.Popen(args, stdout=log.open("w"), stderr=subprocess.STDOUT, env={**os.environ, "PYTHONPATH": ""})


def _scheduler_address(path, deadline: float) -> str:
    """The address in a dask scheduler file, once the scheduler has written it whole (it creates the file
    first and writes it afterwards, so a loaded machine can show an empty or partial file)."""
    while True:
        try:
            return json.loads(path.read_text())["address"]
        except (FileNotFoundError, json.JSONDecodeError, KeyError):
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


def test_folder_through_scheduler_address_equals_one_file_cleans(archive, tmp_path):
    """A scheduler and two workers on 127.0.0.1 (separate processes), reached by --scheduler tcp://…"""
    from distributed import Client

    scheduler_file = tmp_path / "scheduler.json"
    procs = [
        _start(
            [*DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--scheduler-file",
             str(scheduler_file)], tmp_path / "scheduler.log",
        )
    ]  # fmt: skip
    try:
        address = _scheduler_address(scheduler_file, deadline=time.monotonic() + 60)
        assert address.startswith("tcp://127.0.0.1:")
        for i in range(2):
            procs.append(
                _start(
                    [*DASK, "worker", address, "--nthreads", "1", "--no-dashboard", "--host", "127.0.0.1"],
                    tmp_path / f"worker{i}.log",
                )
            )
        with Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=120)
            assert len(client.scheduler_info()["workers"]) == 2
        out = tmp_path / "batch"
        rc = main(["clean", str(archive), "-o", str(out), "--method", "gaussian-58ms", "--scheduler", address,
                   "--quiet", "--report", str(tmp_path / "r.csv")])  # fmt: skip
        assert rc == 0
        _one_file_cleans(archive, tmp_path / "single", CleanOptions(method="gaussian-58ms"))
        _same_tree(out, tmp_path / "single")
        rows = list(csv.DictReader((tmp_path / "r.csv").open()))
        assert [r["status"] for r in rows] == ["cleaned"] * 6
        assert sum(int(r["frames"]) for r in rows) == sum(150 + 10 * i for i in range(6))
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            p.wait(timeout=30)


def test_folder_on_default_local_cluster_reports_failures_and_skips_up_to_date(archive, tmp_path, capsys):
    src = tmp_path / "in"
    shutil.copytree(archive, src)
    (src / "take" / "broken.bvh").write_text("HIERARCHY\nROOT a\n{\n")
    shutil.copy(SAMPLE_C3D_NAN, src / "take" / "serve.c3d")
    (src / "notes.txt").write_text("not a recording")
    out = tmp_path / "out"
    report = tmp_path / "report.json"
    assert main(["clean", str(src), "-o", str(out), "--method", "lerp", "--quiet", "--report", str(report)]) == 1
    printed = capsys.readouterr()
    assert "local worker processes" in printed.err
    assert "failed: " in printed.err and "broken.bvh" in printed.err
    rows = {Path(r["file"]).name: r for r in json.loads(report.read_text())}
    assert set(rows) == {"a.bvh", "b.bvh", "c.bvh", "d.bvh.gz", "e.bvh", "f.bvh", "broken.bvh", "serve.c3d"}
    assert rows["broken.bvh"]["status"] == FAILED and "broken.bvh" in rows["broken.bvh"]["error"]
    assert not (out / "take" / "broken.bvh").exists()
    assert rows["serve.c3d"]["status"] == "cleaned" and rows["serve.c3d"]["samples_filled"] > 0
    assert isinstance(rows["serve.c3d"]["details"], dict)
    single = tmp_path / "single"
    _one_file_cleans(archive, single, CleanOptions(method="lerp"))
    clean_file(src / "take" / "serve.c3d", single / "take" / "serve.c3d", CleanOptions(method="lerp"))
    _same_tree(out, single)

    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    again = clean_folder(src, out, CleanOptions(method="lerp"), Parallel(workers=0), progress=False)
    assert {r.status for r in again if not r.file.endswith("broken.bvh")} == {UP_TO_DATE}
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == before
    forced = clean_folder(src, out, CleanOptions(method="lerp"), Parallel(workers=0), force=True, progress=False)
    assert sum(r.status == "cleaned" for r in forced) == 7
    _same_tree(out, single)


def test_single_file_report_and_usage_errors(tmp_path, capsys):
    report = tmp_path / "one.csv"
    out = tmp_path / "o.bvh"
    assert main(["clean", str(SAMPLE_BVH), "-o", str(out), "--method", "lerp", "--report", str(report)]) == 0
    (row,) = list(csv.DictReader(report.open()))
    assert row["status"] == "cleaned" and row["method"] == "lerp" and int(row["frames"]) == 2752
    assert row["reason"] == ""  # the method was named, not chosen
    assert main(["clean", str(SAMPLE_BVH), "-o", str(tmp_path / "auto.bvh"), "--report", str(report), "--quiet"]) == 0
    (row,) = list(csv.DictReader(report.open()))
    assert row["method"] == "ebf" and row["reason"].startswith("EBF shipped for this skeleton")
    assert list(row)[-1] == "reason"  # appended: the older columns keep their places
    as_json = tmp_path / "one.json"
    assert main(["clean", str(SAMPLE_BVH), "-o", str(tmp_path / "auto2.bvh"), "--report", str(as_json), "--quiet"]) == 0
    assert json.loads(as_json.read_text())[0]["reason"] == row["reason"]
    folder = tmp_path / "f"
    folder.mkdir()
    assert main(["clean", str(folder), "-o", str(folder), "--workers", "0"]) == 2
    assert "output folder is the input folder" in capsys.readouterr().err
    assert main(["clean", str(folder), "-o", str(tmp_path / "x"), "--mask", "m.npy", "--workers", "0"]) == 2
    assert "cannot be used when cleaning a folder" in capsys.readouterr().err
    assert main(["clean", str(SAMPLE_BVH), "-o", str(tmp_path / "p.bvh"), "--method", "lerp", "--report", "r.txt"]) == 2
    assert "must end in .csv or .json" in capsys.readouterr().err
    assert not (tmp_path / "p.bvh").exists()
    with pytest.raises(SystemExit):
        main(["clean", "--help"])
    assert "dask-jobqueue" in capsys.readouterr().out


def test_outputs_inside_the_input_folder_are_not_inputs(archive, tmp_path):
    src = tmp_path / "in"
    shutil.copytree(archive, src)
    clean_folder(src, src / "cleaned", CleanOptions(method="lerp"), Parallel(workers=0), progress=False)
    assert len(plan(src, src / "cleaned")) == 6  # a rerun does not take its outputs for inputs
    assert len(plan(src, tmp_path / "elsewhere")) == 12  # elsewhere, in/cleaned/* are recordings like any


def test_relative_paths_are_made_absolute_for_workers_elsewhere(archive, tmp_path, monkeypatch):
    shutil.copytree(archive, tmp_path / "in")
    monkeypatch.chdir(tmp_path)
    reports = clean_folder("in", "out", CleanOptions(method="lerp"), Parallel(workers=0), progress=False)
    assert all(Path(r.file).is_absolute() and Path(r.output).is_absolute() for r in reports)
    assert sorted(p.name for p in (tmp_path / "out").rglob("*.bvh*")) == sorted(p.name for p in archive.rglob("*.bvh*"))
