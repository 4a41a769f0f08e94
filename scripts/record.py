"""Copy a finished study's results into ``record/``: the git-tracked record of a run.

    python scripts/record.py             # after `dvc repro` of the quick profile (params.yaml)
    python scripts/record.py --dest record/evidence   # after `dvc repro` of profiles/evidence.yaml

Every stage output is DVC-cached (so that the run cache can share any stage: docs/design.md),
which keeps results/ out of git. The record is how a run's results reach a reader of the repository:
every output under results/ that dvc.lock lists, copied to record/results/ with the same relative
paths (the report's figure links keep working), and dvc.lock itself as record/dvc.lock; the day's speed
probe (benchmarks/speed_probe.py: measured now, or ``--probe`` a probe taken with the run) as
record/speed_probe.json; and README.md's per-stage time table is rewritten from the record's timing
files and probe. Each copied
file or directory has the md5 that dvc.lock recorded for it, so the record is what the pipeline
produced and nothing else; ``check_record`` (run by the tests on the committed record) says so.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import tempfile
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from speed_probe import probe, summary  # noqa: E402

from mop_cluster.worker import drop_lock_entries  # noqa: E402
from mop_core.float_path import differs  # noqa: E402
from mop_core.storage.timings import stage_time_table  # noqa: E402

PROBE = "speed_probe.json"


def recorded_outputs(lock: dict) -> dict[str, str]:
    """path -> md5 of every output under results/ in a parsed dvc.lock."""
    outputs = {}
    for stage in lock.get("stages", {}).values():
        for out in stage.get("outs", []):
            if out["path"].startswith("results/"):
                outputs[out["path"]] = out["md5"]
    return outputs


def output_md5(path: Path) -> str:
    """The md5 DVC gives a file or directory output (``<md5>.dir`` for a directory), by DVC's own code."""
    from dvc_data.hashfile.build import build
    from dvc_data.hashfile.db import HashFileDB
    from dvc_objects.fs.local import LocalFileSystem

    fs = LocalFileSystem()
    with tempfile.TemporaryDirectory() as odb_dir:
        _, _, obj = build(HashFileDB(fs, odb_dir), str(path), fs, "md5", ignore=None)
        return obj.hash_info.value


EMPTY_DIRECTORY = "d751713988987e9331980363e24189ce.dir"  # DVC's md5 of a directory with no file


def check_record(record: Path) -> list[str]:
    """Every problem with a record directory: an output dvc.lock lists that is missing or differs, or a
    file that no output accounts for. Empty: the record is exactly what the locked run produced."""
    lock = yaml.safe_load((record / "dvc.lock").read_text())
    outputs = recorded_outputs(lock)
    # git keeps no empty directory: an output that was one (one-task students log no per-state tau) is
    # absent from a checkout, which is what the lock describes
    outputs = {path: md5 for path, md5 in outputs.items() if md5 != EMPTY_DIRECTORY or (record / path).exists()}
    problems = [f"{path}: missing" for path in outputs if not (record / path).exists()]
    problems += [f"{path}: md5 {output_md5(record / path)} != dvc.lock's {md5}" for path, md5 in outputs.items()
                 if (record / path).exists() and output_md5(record / path) != md5]
    for file in (record / "results").rglob("*"):
        relative = file.relative_to(record).as_posix()
        if file.is_file() and not any(relative == p or relative.startswith(p + "/") for p in outputs):
            problems.append(f"{relative}: not an output in dvc.lock")
    return problems


README_BLOCK = re.compile(r"(<!-- timings:record -->\n).*?(<!-- /timings:record -->)", re.S)


def timing_table(record: Path) -> str:
    """The per-stage seconds of the recorded run (its ``results/timings``), as the README shows them,
    with the day's speed probe when the record has one."""
    table = stage_time_table(record / "results" / "timings")
    if (record / PROBE).is_file():
        result = json.loads((record / PROBE).read_text())
        table += f"\n\nSpeed probe on the record's day ({result['when']}): {summary(result)}."
    return table


def readme_with_timings(readme: str, record: Path) -> str:
    """``readme`` with its ``timings:record`` block replaced by :func:`timing_table` of ``record``."""
    if not README_BLOCK.search(readme):
        raise SystemExit("error: README.md: the <!-- timings:record --> ... <!-- /timings:record --> block is missing")
    return README_BLOCK.sub(lambda m: m.group(1) + timing_table(record) + "\n" + m.group(2), readme)


def pipeline_stages(root: Path) -> set[str]:
    """The names of every stage entry ``root``'s dvc.yaml defines now (matrix entries expanded)."""
    from dvc.repo import Repo

    with Repo(str(root)) as repo:
        return {stage.name for stage in repo.index.stages}


def prune_lock(root: Path) -> list[str]:
    """Remove from ``root``'s dvc.lock the entries of stages its dvc.yaml no longer defines (a family a
    profile dropped: DVC keeps them, treeverse/dvc#5293), so that the lock and the record describe this
    pipeline's run only. Returns the removed entries' names."""
    lock_path = root / "dvc.lock"
    if not (root / "dvc.yaml").is_file():  # no pipeline to compare with
        return []
    lock = yaml.safe_load(lock_path.read_text())
    stale = sorted(set(lock.get("stages", {})) - pipeline_stages(root))
    drop_lock_entries(lock_path, stale)
    return stale


def recorded_float_path(record: Path) -> dict | None:
    """The float path a record's behaviour data was trained on (collect's timing record), else its speed
    probe's (the machine that recorded it), else None (records from before mop_core/float_path.py)."""
    for path in (record / "results" / "timings" / "collect.json", record / PROBE):
        if path.is_file() and "float_path" in (content := json.loads(path.read_text())):
            return content["float_path"]
    return None


def float_path_change(new: Path, old: Path) -> str:
    """One line on whether the new record's machine rounds as the replaced record's did."""
    ours, theirs = recorded_float_path(new), recorded_float_path(old)
    if ours is None or theirs is None:
        return (f"float path: none in the {'new' if ours is None else 'replaced'} record "
                "(mop_core/float_path.py): cannot say whether the two machines round alike")
    parted = differs(ours, theirs)
    if not parted:
        return "float path: as the replaced record's"
    return (f"float path: {', '.join(parted)} rounded otherwise than on the replaced record's machine "
            "(mop_core/float_path.py): its numbers may differ from the replaced record's for that reason alone")


def write_record(root: Path, record: Path, readme: bool = True, speed: dict | None = None) -> int:
    """Copy ``root``'s recorded outputs and dvc.lock to ``record`` with the day's speed probe (``speed``;
    None: measure it now); with ``readme``, rewrite README.md's time table from it (the quick profile's
    record; another profile's record leaves README alone)."""
    lock_path = root / "dvc.lock"
    if not lock_path.is_file():
        raise SystemExit(f"error: {lock_path}: not found; run `dvc repro` first")
    stale = prune_lock(root)
    if stale:
        print(f"dvc.lock: removed {len(stale)} entries of stages dvc.yaml no longer defines: {', '.join(stale)}")
    lock = yaml.safe_load(lock_path.read_text())
    outputs = recorded_outputs(lock)
    changed = [p for p, md5 in outputs.items() if not (root / p).exists() or output_md5(root / p) != md5]
    if changed:
        raise SystemExit(f"error: results differ from dvc.lock (run `dvc repro`, or `dvc checkout`): "
                         f"{', '.join(changed[:5])}{' ...' if len(changed) > 5 else ''}")
    staging = Path(tempfile.mkdtemp(prefix=".record-", dir=root))
    for path in outputs:
        target = staging / path
        target.parent.mkdir(parents=True, exist_ok=True)
        if (root / path).is_dir():
            shutil.copytree(root / path, target, ignore=shutil.ignore_patterns(".gitignore"))
        else:
            shutil.copyfile(root / path, target)
    shutil.copyfile(lock_path, staging / "dvc.lock")
    speed = speed or probe()
    (staging / PROBE).write_text(json.dumps(speed, indent=1) + "\n")
    print(f"speed probe ({speed['when']}): {summary(speed)}")
    problems = check_record(staging)
    if problems:
        shutil.rmtree(staging)
        raise SystemExit("error: the copy does not match dvc.lock: " + "; ".join(problems))
    print(float_path_change(staging, record))
    if record.exists():  # replace the old record only once the new one is complete, keeping the records of
        for nested in record.iterdir():  # other profiles inside it (record/evidence/: a dvc.lock of its own)
            if nested.is_dir() and (nested / "dvc.lock").is_file():
                nested.rename(staging / nested.name)
        shutil.rmtree(record)
    staging.rename(record)
    readme_path = root / "README.md"
    if readme and readme_path.is_file():
        readme_path.write_text(readme_with_timings(readme_path.read_text(), record))
    print(f"recorded {len(outputs)} outputs of dvc.lock under {record}"
          + ("; README.md's time table rewritten" if readme and readme_path.is_file() else ""))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=ROOT, help="the project whose results to record")
    parser.add_argument("--dest", type=Path, default=None, help="the record directory (default: <root>/record); "
                        "another profile's, e.g. record/evidence, leaves README.md's time table alone")
    parser.add_argument("--probe", type=Path, default=None, help="a speed probe JSON taken with the run "
                        "(benchmarks/speed_probe.py --out); default: measure one now")
    args = parser.parse_args(argv)
    speed = json.loads(args.probe.read_text()) if args.probe else None
    return write_record(args.root, args.dest or args.root / "record", readme=args.dest is None, speed=speed)


if __name__ == "__main__":
    sys.exit(main())
