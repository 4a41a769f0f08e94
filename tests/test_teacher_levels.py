"""scripts/teacher_levels.py: a teacher group holds its level only if its interval over seeds does."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

from teacher_levels import teacher_table  # noqa: E402


def _write(root: Path, group: str, task: str, ratios: list[float]) -> None:
    folder = root / "results" / "teachers" / "metrics" / group
    folder.mkdir(parents=True, exist_ok=True)
    for seed, ratio in enumerate(ratios):
        (folder / f"{task}-{seed}.json").write_text(json.dumps({"task": task, "seed": seed, "return_ratio": ratio}))


def test_the_verdict_follows_the_interval_over_seeds(tmp_path):
    _write(tmp_path, "expert-deterministic", "stand", [0.95, 0.97, 0.96])
    _write(tmp_path, "expert-deterministic", "walk", [0.40, 0.45, 0.42])
    _write(tmp_path, "medium-deterministic", "walk", [0.5, 1.5, 1.0])
    _write(tmp_path, "medium_replay-deterministic", "stand", [1.2])
    rows = {tuple(cell.strip() for cell in line.split("|")[1:3]): line for line in teacher_table(tmp_path).splitlines()}
    assert rows[("expert-deterministic", "stand")].endswith("| 3 | yes |")
    assert rows[("expert-deterministic", "walk")].endswith("| 3 | no |")
    assert rows[("medium-deterministic", "walk")].endswith("| 3 | inconclusive |")
    assert "no interval (< 3 seeds)" in rows[("medium_replay-deterministic", "stand")]


def test_no_metrics_is_a_clear_error(tmp_path):
    with pytest.raises(SystemExit, match="no teacher metrics"):
        teacher_table(tmp_path)
