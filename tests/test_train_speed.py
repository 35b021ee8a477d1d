"""The training-speed benchmark's parts that need no GPU (``mocapnet.evaluate.train_speed``)."""

from __future__ import annotations

import math

import pytest

from mocapnet.evaluate.train_speed import markdown, step_rates


def test_step_rates_time_the_steps_after_the_warm_up_and_the_table_divides_by_the_cpu_row():
    rows = step_rates((("cpu", "cpu", 4, 1),), steps=8)
    assert (
        len(rows) == 1
        and rows[0]["batch"] == 4
        and math.isfinite(rows[0]["steps_per_s"])
        and rows[0]["steps_per_s"] > 0
    )
    assert rows[0]["crops_per_s"] == pytest.approx(4 * rows[0]["steps_per_s"])
    result = {"command": "c", "git_commit": "g", "load": "0", "machine": "m", "device": "d", "smoke": [],
              "rates": rows + [{"label": "gpu", "batch": 8, "threads": 1, "steps_per_s": rows[0]["steps_per_s"],
                                "crops_per_s": 2 * rows[0]["crops_per_s"]}]}  # fmt: skip
    text = markdown(result)
    assert "| cpu | 4 | 1 |" in text and text.rstrip().endswith("| 2.0 |")
    with pytest.raises(ValueError, match="untimed"):
        step_rates((("cpu", "cpu", 4, 1),), steps=5)
