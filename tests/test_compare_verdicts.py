"""scripts/compare_verdicts.py: two runs' verdicts side by side, on the committed quick record."""

from __future__ import annotations

import json
import sys

import pytest
from conftest import ROOT

sys.path.insert(0, str(ROOT / "scripts"))
from compare_verdicts import VERDICTS, comparison_table, load_findings  # noqa: E402


def test_a_changed_verdict_is_marked_and_the_counts_are_each_runs(tmp_path):
    quick = load_findings(ROOT / "record")
    other = tmp_path / "other"
    (other / VERDICTS).parent.mkdir(parents=True)
    record = json.loads((ROOT / "record" / VERDICTS).read_text())
    key = sorted(record["findings"])[0]
    flipped = "reproduced" if record["findings"][key]["verdict"] != "reproduced" else "contradicted"
    record["findings"][key]["verdict"] = flipped
    del record["findings"][sorted(record["findings"])[-1]]  # a finding only the first run has
    (other / VERDICTS).write_text(json.dumps(record))
    table = comparison_table(quick, load_findings(other), ("quick", "other"))
    rows = {line.split(" | ")[0].lstrip("| "): line for line in table.splitlines() if line.startswith("| ")}
    assert f"| {flipped} (changed) |" in rows[key]
    assert rows[sorted(quick)[-1]].split(" | ")[2] == "-"
    assert sum(1 for k in quick if k in rows) == len(quick)
    counts = {v: sum(f["verdict"] == v for f in quick.values()) for v in ("contradicted", "inconclusive", "reproduced")}
    assert "quick: " + ", ".join(f"{v} {n}" for v, n in counts.items() if n) in table


def test_a_run_without_its_report_is_named(tmp_path):
    with pytest.raises(SystemExit, match=rf"error: {tmp_path}/results/verdicts.json: not found"):
        load_findings(tmp_path)
    (tmp_path / VERDICTS).parent.mkdir(parents=True)
    (tmp_path / VERDICTS).write_text("[]")
    with pytest.raises(SystemExit, match="expected the report's verdict record"):
        load_findings(tmp_path)
