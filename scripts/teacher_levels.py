"""Do the teachers hold their level? Each teacher's final return over its dataset's, per seed, with a
95% t-interval over training seeds, from a run's (or a record's) ``results/teachers/metrics``.

Issue 36's criterion: every deterministic teacher reaches >= 0.9 of its dataset's return over >= 3 seeds.
This reads what the train_teachers stages wrote, so it works on a run the report has not reached yet.

    python scripts/teacher_levels.py record/evidence    # or a study's root, or record
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mop_core.statistics import RETURN_BOUNDS, seed_interval  # noqa: E402

CRITERION = 0.9


def teacher_table(root: Path) -> str:
    metrics = root / "results" / "teachers" / "metrics"
    ratios: dict[tuple, dict[int, float]] = defaultdict(dict)
    for group in sorted(metrics.iterdir()) if metrics.is_dir() else []:
        for file in sorted(group.glob("*.json")):
            run = json.loads(file.read_text())
            if "return_ratio" in run:  # data-sharing teachers: group name says which (ds-/oqs-)
                ratios[(group.name, run["task"])][int(run["seed"])] = float(run["return_ratio"])
    if not ratios:
        raise SystemExit(f"error: {metrics}: no teacher metrics (expected <group>/<run>.json with return_ratio)")
    lines = ["| teachers | task | return / dataset return, per seed | mean [95% CI over seeds] | n | >= 0.9 |",
             "|---|---|---|---|---|---|"]
    for (group, task), by_seed in sorted(ratios.items()):
        ci = seed_interval(list(by_seed.values()), bounds=RETURN_BOUNDS)  # a ratio of returns: >= 0
        interval = "no interval (< 3 seeds)" if ci["ci_low"] is None else f"[{ci['ci_low']:.2f}, {ci['ci_high']:.2f}]"
        held = "yes" if ci["ci_low"] is not None and ci["ci_low"] >= CRITERION else (
            "no" if ci["ci_high"] is not None and ci["ci_high"] < CRITERION else "inconclusive")
        seeds = ", ".join(f"{by_seed[s]:.2f}" for s in sorted(by_seed))
        lines.append(f"| {group} | {task} | {seeds} | {ci['mean']:.2f} {interval} | {ci['n']} | {held} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="a study's root or a record directory (holding results/)")
    print(teacher_table(parser.parse_args().root))


if __name__ == "__main__":
    main()
