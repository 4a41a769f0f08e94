"""Does TF32 change what the study decides? One profile run twice on CUDA, ``study.cuda_matmul`` fp32 and
tf32, and the two results compared (issue 39: "where TF32 is used, test that the study's numbers stay
within their intervals"):

    python benchmarks/tf32_check.py run --profile profiles/evidence.yaml --out /scratch/tf32   # a GPU machine
    python benchmarks/tf32_check.py compare FP32/results TF32/results                          # two finished runs

``run`` copies the project twice under ``--out`` (fp32/, tf32/), sets the profile's ``study.cuda_matmul`` and
``study.device`` (default cuda), runs ``dvc repro`` in each, one after the other, then compares; the
comparison is written to ``--out``/tf32_check.md and printed.

``compare`` reads each run's ``verdicts.json`` and ``eval/metrics.json`` and says, for the TF32 run against
the fp32 one:
- every finding's verdict (reproduced, contradicted, inconclusive): the same or not. **The check passes when
  every verdict is the same**: TF32 then changed nothing the study decides.
- every finding cell's effect and every evaluated group's mean over runs (``ci_unit`` training_seed, n >= 3):
  inside the fp32 run's 95% interval or not (cells only where their interval is over training runs). Numbers,
  not the verdict: TF32 rounds differently from the first update, so the two runs drift apart; where they
  drift as far as runs of another seed would (both studies use the same seeds: if they stay correlated, the
  share inside runs high, which errs towards passing numbers, not verdicts), another draw of a mean of n
  runs lands inside the first draw's Student-t 95% interval with probability P(|t_{n-1}| < t_{n-1,0.975} /
  sqrt(2)) (the difference of two independent means has sqrt(2) times a mean's spread): 0.91 at n = 3, 0.88
  at n = 5, 0.83 as n grows. The report prints that expectation beside the share found; a share far under it
  says TF32 moved the numbers beyond run-to-run noise (for a cell whose interval is not a t interval over n
  runs it is a guide only).
- what each study trained in, from its timing records: a study on the CPU, or a pair that is not fp32 then
  tf32 on CUDA (a collect step reused from the other precision, say), is "not a TF32 check" and fails.
A flipped verdict can be noise too (a finding near its threshold): rerun the fp32 study with another
``study.seed`` to see whether it flips as often without TF32.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
PRECISIONS = ("fp32", "tf32")


@dataclass(frozen=True)
class Placed:
    """One TF32 number against the fp32 run's 95% interval over ``n`` runs."""

    name: str
    value: float
    low: float
    high: float
    n: int

    @property
    def inside(self) -> bool:
        return self.low <= self.value <= self.high


def redraw_inside(n: int) -> float:
    """P(another independent draw of a mean of ``n`` runs lies inside the first draw's Student-t 95% interval):
    (mean2 - mean1) / (s1 sqrt(2 / n)) is t with n - 1 degrees of freedom, the interval's half-width is
    t_{n-1,0.975} s1 / sqrt(n), so the probability is P(|t_{n-1}| < t_{n-1,0.975} / sqrt(2))."""
    from scipy import stats

    if n < 2:
        raise ValueError(f"n: expected at least 2 runs, got {n}")
    return float(2 * stats.t.cdf(stats.t.ppf(0.975, n - 1) / 2 ** 0.5, n - 1) - 1)


# finding cells whose interval is over training runs retrained in both studies (a cell against "the one run"
# holds that run fixed, and TF32 retrains it too; episode-level cells are not over runs)
RUN_UNITS = ("training seeds", "paired training seeds", "training seeds (paired)",
             "training seeds per side (unpaired)", "training seeds (each student with itself)")
TRAINING_RECORDS = ("collect.json", "teachers", "multitask", "students")  # results/timings/: what trained


@dataclass
class Comparison:
    """The TF32 run against the fp32 run: what each trained in (``precisions``: cpu, fp32, tf32 from the
    timing records), verdicts ``(finding, fp32, tf32)``, and the numbers of finding cells (over training
    runs) and evaluated groups placed in the fp32 run's intervals; ``unplaced``: cells with another unit."""

    precisions: tuple[set[str], set[str]] = (set(), set())
    verdicts: list[tuple[str, str, str]] = field(default_factory=list)
    cells: list[Placed] = field(default_factory=list)
    groups: list[Placed] = field(default_factory=list)
    unplaced: int = 0

    @property
    def flipped(self) -> list[tuple[str, str, str]]:
        return [v for v in self.verdicts if v[1] != v[2]]

    @property
    def a_tf32_check(self) -> bool:
        """The first study trained in fp32 on CUDA only, the second in TF32 only."""
        return self.precisions == ({"fp32"}, {"tf32"})

    @property
    def passed(self) -> bool:
        return self.a_tf32_check and bool(self.verdicts) and not self.flipped


def _read(results: Path, name: str) -> dict:
    path = results / name
    if not path.is_file():
        raise SystemExit(f"{path}: missing; expected a finished study's results directory (dvc repro's results/)")
    return json.loads(path.read_text())


def trained_in(results: Path) -> set[str]:
    """How the study's training stages multiplied matrices, from their timing records: ``cpu``, or on CUDA
    the record's ``cuda_matmul`` (fp32 or tf32; ``unrecorded`` in records from before it was written)."""
    timings = results / "timings"
    records = [path for name in TRAINING_RECORDS for path in
               ([timings / name] if name.endswith(".json") else sorted((timings / name).rglob("*.json")))
               if path.is_file()]
    if not records:
        raise SystemExit(f"{timings}: no timing record of a training stage; expected a finished study's results")
    out = set()
    for path in records:
        record = json.loads(path.read_text())
        cuda = str(record.get("device", "cpu")).startswith("cuda")
        out.add(record.get("cuda_matmul", "unrecorded") if cuda else "cpu")
    return out


def _placed(name: str, value: float | None, interval: dict) -> Placed | None:
    low, high, n = interval.get("ci_low"), interval.get("ci_high"), interval.get("n")
    if value is None or low is None or high is None or not isinstance(n, int) or n < 3:
        return None  # no interval over runs (fewer than 3) or no value: nothing to place
    return Placed(name, float(value), float(low), float(high), n)


def compare(fp32: Path, tf32: Path) -> Comparison:
    """Verdicts, finding cells and evaluated groups of ``tf32`` (a results directory) against ``fp32``'s."""
    out = Comparison(precisions=(trained_in(fp32), trained_in(tf32)))
    a, b = _read(fp32, "verdicts.json")["findings"], _read(tf32, "verdicts.json")["findings"]
    if set(a) != set(b):
        raise SystemExit(f"{tf32}/verdicts.json: expected the findings of {fp32}/verdicts.json (the same profile), "
                         f"got {sorted(set(a) ^ set(b))} in one only")
    for finding in sorted(a):
        out.verdicts.append((finding, a[finding]["verdict"], b[finding]["verdict"]))
        for cell, interval in a[finding].get("cells", {}).items():
            if interval.get("unit") not in RUN_UNITS:
                out.unplaced += 1
                continue
            placed = _placed(f"{finding}: {cell}", b[finding].get("cells", {}).get(cell, {}).get("value"), interval)
            out.cells += [placed] if placed else []
    a, b = _read(fp32, "eval/metrics.json"), _read(tf32, "eval/metrics.json")
    for task, groups in a.items():
        for group, summary in groups.items():
            other = b.get(task, {}).get(group)
            if isinstance(summary, dict) and summary.get("ci_unit") == "training_seed" and isinstance(other, dict):
                placed = _placed(f"{task}: {group}", other.get("mean"), summary)
                out.groups += [placed] if placed else []
    return out


def _share(rows: list[Placed]) -> str:
    if not rows:
        return "none (no interval over 3 or more runs)"
    inside, expected = sum(row.inside for row in rows), sum(redraw_inside(row.n) for row in rows) / len(rows)
    return f"{inside} of {len(rows)} ({inside / len(rows):.0%}; another draw of the runs: ~{expected:.0%})"


def report(result: Comparison) -> str:
    """The comparison as markdown: the check's outcome, the flipped verdicts, the shares inside."""
    outcome = "passed" if result.passed else "FAILED"
    fp32, tf32 = (", ".join(sorted(p)) for p in result.precisions)
    lines = [f"# TF32 against fp32: {outcome}", ""]
    if not result.a_tf32_check:
        lines += [f"- **not a TF32 check**: the first study trained in {fp32}, the second in {tf32} (timing "
                  "records); expected fp32 and tf32, both on CUDA", ""]
    lines += [f"- verdicts the same: {len(result.verdicts) - len(result.flipped)} of {len(result.verdicts)} findings",
              f"- finding effects over training runs inside the fp32 run's 95% interval: {_share(result.cells)} "
              f"({result.unplaced} cells of other units not placed)",
              f"- evaluated groups' means (over runs) inside the fp32 run's 95% interval: {_share(result.groups)}", ""]
    if result.flipped:
        lines += ["| finding | fp32 | tf32 |", "|---|---|---|"]
        lines += [f"| {name} | {x} | {y} |" for name, x, y in result.flipped] + [""]
    outside = [row for row in result.cells + result.groups if not row.inside]
    if outside:
        lines += ["| outside | tf32 | fp32 interval | n |", "|---|---|---|---|"]
        lines += [f"| {r.name} | {r.value:.3g} | [{r.low:.3g}, {r.high:.3g}] | {r.n} |" for r in outside]
    return "\n".join(lines).rstrip() + "\n"


def _project(profile: Path, precision: str, device: str, target: Path) -> Path:
    """A committed copy of the project whose params.yaml is ``profile`` in ``precision`` on ``device``."""
    sys.path.insert(0, str(ROOT / "scripts"))
    from bad_inputs import committed_project

    params = yaml.safe_load(profile.read_text())
    params["study"] |= {"cuda_matmul": precision, "device": device}
    committed_project(ROOT, target)  # the code, DAG and profiles in a new git repository
    (target / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    return target


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="run a profile in fp32 and in tf32 on CUDA, then compare")
    run.add_argument("--profile", type=Path, required=True, help="a params file, e.g. profiles/evidence.yaml")
    run.add_argument("--out", type=Path, required=True, help="a new directory: fp32/, tf32/, tf32_check.md")
    run.add_argument("--device", default="cuda", help="study.device of both runs (cpu: a dry run of the "
                                                      "orchestration, which fails as not a TF32 check)")
    pair = commands.add_parser("compare", help="compare two finished studies' results directories")
    pair.add_argument("fp32", type=Path)
    pair.add_argument("tf32", type=Path)
    args = parser.parse_args(argv)
    if args.command == "compare":
        text = report(compare(args.fp32, args.tf32))
    else:
        if not args.profile.is_file():
            parser.error(f"--profile: {args.profile} is not a file")
        if args.out.exists():
            parser.error(f"--out: {args.out} exists; expected a new directory (nothing is overwritten)")
        for precision in PRECISIONS:
            project = _project(args.profile, precision, args.device, args.out / precision)
            subprocess.run(["dvc", "repro"], cwd=project, check=True)
        text = report(compare(args.out / "fp32" / "results", args.out / "tf32" / "results"))
        (args.out / "tf32_check.md").write_text(text)
    print(text, end="")
    raise SystemExit(0 if "passed" in text.splitlines()[0] else 1)


if __name__ == "__main__":
    main()
