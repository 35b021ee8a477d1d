"""The training-speed benchmark's parts that need no GPU (``mocapnet.evaluate.train_speed``)."""

from __future__ import annotations

import math

import pytest

from mocapnet.evaluate.train_speed import markdown, step_rates


def test_step_rates_time_the_steps_after_the_warm_up_and_the_table_divides_by_the_cpu_row():
    rows = step_rates((("cpu", "cpu", 4, 1, 0), ("cpu", "cpu", 4, 1, 1)), steps=8)
    assert [r["workers"] for r in rows] == [0, 1] and all(r["steps_per_s"] > 0 for r in rows)
    assert rows[0]["batch"] == 4 and math.isfinite(rows[0]["steps_per_s"]) and rows[0]["steps_per_s"] > 0
    assert rows[0]["crops_per_s"] == pytest.approx(4 * rows[0]["steps_per_s"])
    gpu = {"label": "gpu", "batch": 8, "threads": 1, "workers": 4, "steps_per_s": rows[0]["steps_per_s"],
           "crops_per_s": 2 * rows[0]["crops_per_s"]}  # fmt: skip
    result = {"command": "c", "git_commit": "g", "load": "0", "machine": "m", "device": "d", "smoke": [],
              "rates": [*rows, gpu]}  # fmt: skip
    text = markdown(result)
    assert "| cpu | 4 | 1 | 0 |" in text and "| gpu | 8 | 1 | 4 |" in text and text.rstrip().endswith("| 2.0 |")
    assert "Smoke run" not in text  # the --cpu form has no smoke runs
    with pytest.raises(ValueError, match="untimed"):
        step_rates((("cpu", "cpu", 4, 1, 0),), steps=5)
