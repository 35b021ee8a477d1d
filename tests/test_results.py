"""The results-file helpers every benchmark shares (``mocapnet.evaluate.results``)."""

from __future__ import annotations

import gzip
import json
import math

from mocapnet.evaluate.results import fmt, markdown_table, provenance, read_json, rounded, write_json, write_results


def test_fmt_and_markdown_table():
    assert fmt(None) == fmt(math.nan) == fmt(math.inf) == "—"
    assert fmt(1.23456) == "1.235" and fmt(2.0, 1) == "2.0"
    assert markdown_table(["a", "b"], [[1, "x"], [fmt(0.5, 2), ""]]) == [
        "| a | b |",
        "|---|---|",
        "| 1 | x |",
        "| 0.50 |  |",
    ]


def test_rounded_keeps_structure_and_rounds_floats_only():
    value = {"a": [1.23456789, 7, "x"], "b": {"c": 123456.789, "d": None}}
    assert rounded(value) == {"a": [1.23457, 7, "x"], "b": {"c": 123457.0, "d": None}}
    assert rounded(0.000123456, 2) == 0.00012


def test_write_json_gzip_is_reproducible_and_read_back(tmp_path):
    data = {"rows": [{"x": 1.5, "n": 3}], "name": "é"}
    write_json(tmp_path / "a.json", data)
    write_json(tmp_path / "a.json.gz", data)
    write_json(tmp_path / "b.json.gz", data)
    assert (tmp_path / "a.json.gz").read_bytes() == (tmp_path / "b.json.gz").read_bytes()
    assert gzip.decompress((tmp_path / "a.json.gz").read_bytes()) == (tmp_path / "a.json").read_bytes()
    assert read_json(tmp_path / "a.json.gz") == read_json(tmp_path / "a.json") == data
    write_json(tmp_path / "i.json", data, indent=1)
    assert (tmp_path / "i.json").read_text() == json.dumps(data, indent=1) + "\n"


def test_write_results_writes_both_files_and_prints(tmp_path, capsys):
    write_results(tmp_path / "new" / "bench", {"k": 1}, "# title\n", json_suffix=".json.gz")
    assert read_json(tmp_path / "new" / "bench.json.gz") == {"k": 1}
    assert (tmp_path / "new" / "bench.md").read_text() == "# title\n"
    assert "# title" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "new").iterdir()) == ["bench.json.gz", "bench.md"]  # no temp left


def test_provenance_names_the_command_and_machine():
    info = provenance(["--quick", "a b"])
    assert info["command"].endswith("--quick 'a b'")
    assert "CPUs" in info["machine"] and "NumPy" in info["machine"]
    assert info["git_commit"]
