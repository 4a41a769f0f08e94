"""Two runs' verdicts side by side, finding by finding (e.g. the quick record next to the evidence record).

    python scripts/compare_verdicts.py record record/evidence     # or any two study roots after `dvc repro`

Each run must have reached its report stage (record/evidence/ holds a verdict table only once the
evidence run has).

Reads each run's ``results/verdicts.json`` (the report stage's record: mop_core/report/verdict_section.py) and
prints a markdown table: per finding, each run's verdict and its first cell (effect [95% CI], n and unit),
then the verdict counts. A finding only one run decides shows ``-`` for the other.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

VERDICTS = Path("results") / "verdicts.json"


def load_findings(root: Path) -> dict[str, dict]:
    path = root / VERDICTS
    if not path.is_file():
        raise SystemExit(f"error: {path}: not found (has the run reached its report stage?)")
    record = json.loads(path.read_text())
    if not isinstance(record, dict) or not isinstance(record.get("findings"), dict):
        raise SystemExit(f"error: {path}: expected the report's verdict record (an object with 'findings')")
    return record["findings"]


def first_cell(finding: dict) -> str:
    """The finding's first cell as ``name: value [low, high] (n unit)``; ``name: no data`` without a value."""
    cells = finding.get("cells") or {}
    if not cells:
        return ""
    name, cell = next(iter(cells.items()))
    if cell.get("value") is None:
        return f"{name}: no data"
    interval = "" if cell.get("ci_low") is None else f" [{cell['ci_low']:.3g}, {cell['ci_high']:.3g}]"
    return f"{name}: {cell['value']:.3g}{interval} (n={cell.get('n')} {cell.get('unit', '')})".rstrip()


def comparison_table(a: dict[str, dict], b: dict[str, dict], names: tuple[str, str]) -> str:
    lines = [f"| finding | {names[0]} | {names[1]} | {names[1]}: first cell |", "|---|---|---|---|"]
    for key in sorted(set(a) | set(b)):
        verdicts = [runs[key]["verdict"] if key in runs else "-" for runs in (a, b)]
        changed = " (changed)" if "-" not in verdicts and verdicts[0] != verdicts[1] else ""
        lines.append(f"| {key} | {verdicts[0]} | {verdicts[1]}{changed} | {first_cell(b.get(key, {}))} |")
    for name, runs in zip(names, (a, b)):
        counts: dict[str, int] = {}
        for finding in runs.values():
            counts[finding["verdict"]] = counts.get(finding["verdict"], 0) + 1
        lines.append(f"\n{name}: " + ", ".join(f"{v} {n}" for v, n in sorted(counts.items())))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=Path, help="a run's root (holding results/verdicts.json), e.g. record")
    parser.add_argument("second", type=Path, help="the other run's root, e.g. record/evidence")
    args = parser.parse_args(argv)
    print(comparison_table(load_findings(args.first), load_findings(args.second),
                           (str(args.first), str(args.second))))


if __name__ == "__main__":
    sys.exit(main())
