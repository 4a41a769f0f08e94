"""Does collect's behaviour data meet its criteria on every seed, and what does it cost?

    python scripts/behaviour_seeds.py --seeds 0 1 2 --set collect.td3.layer_norm=true \
        --set 'collect.schedule.expert_return={stand: 900, walk: 850}' --out behaviour_seeds.json

Runs collect's whole behaviour step (mop_core.collect.collect_task: TD3 until the expert criterion,
the medium snapshot nearest its target, both snapshots measured over ``snapshot_eval_episodes``
fresh episodes, expert > medium checked) for every study task and seed of a params file, with
``--set`` overrides, one process per run on one core each. Datasets are rolled out with one episode
each and R_random from one episode: the criteria do not depend on them, and the script measures the
policies, not the data. Prints one row per run (criterion met, steps, returns, seconds) and writes
them as JSON; a run that misses a criterion is a row with its error, not a crash.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mop_core.collect import CollectConfig, collect_configs, collect_task  # noqa: E402
from mop_core.experiment.study import study_config  # noqa: E402
from mop_core.learning.runtime import CriterionNotMetError, configure_compute  # noqa: E402
from mop_core.storage.layout import LEVELS, CollectPaths  # noqa: E402


def with_overrides(params: dict, overrides: list[str]) -> dict:
    """``params`` with each ``dotted.key=yaml_value`` set (the key must exist: a typo is refused)."""
    for item in overrides:
        key, _, value = item.partition("=")
        *path, last = key.split(".")
        section = params
        for name in path:
            section = section[name]
        if last not in section:
            raise SystemExit(f"error: --set {key}: no such parameter in the params file")
        section[last] = yaml.safe_load(value)
    return params


def run_one(task: str, seed: int, config: CollectConfig) -> dict:
    configure_compute(1)
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        paths = CollectPaths(checkpoints={lv: root / f"{lv}.pt" for lv in ("medium", "expert")},
                             datasets={lv: root / f"{lv}.hdf5" for lv in LEVELS},
                             dataset_metrics={lv: root / f"{lv}.json" for lv in LEVELS}, curve=root / "curve.tsv")
        try:
            summary = collect_task(task, config, seed, paths)
        except CriterionNotMetError as err:
            return {"task": task, "seed": seed, "met": False, "error": str(err).split(" Its learning curve:")[0],
                    "seconds": round(time.perf_counter() - started, 1), "curve": _curve(paths.curve)}
        curve = _curve(paths.curve)
    snaps = summary["snapshots"]
    return {"task": task, "seed": seed, "met": True, "expert_steps": snaps["expert"]["gradient_steps"],
            "expert_criterion_return": summary.get("criterion", {}).get("expert_criterion_return"),
            "expert_return": snaps["expert"]["return_mean"], "medium_steps": snaps["medium"]["gradient_steps"],
            "medium_return": snaps["medium"]["return_mean"], "seconds": round(time.perf_counter() - started, 1),
            "curve": curve}


def _curve(path: Path) -> list[list[float]]:
    """The run's learning curve (collect's curve.tsv) as [gradient steps, mean return] pairs."""
    if not path.exists():
        return []
    header, *rows = [line.split("\t") for line in path.read_text().splitlines()]
    step, value = header.index("step"), header.index("return_mean")
    return [[int(row[step]), round(float(row[value]), 1)] for row in rows]


def row_line(row: dict) -> str:
    """One run's outcome in words."""
    if not row["met"]:
        return f"{row['task']} seed {row['seed']}: FAILED after {row['seconds']:.0f} s: {row['error']}"
    check = row["expert_criterion_return"]
    return (f"{row['task']} seed {row['seed']}: expert at {row['expert_steps']} updates (criterion check "
            f"{'-' if check is None else f'{check:.1f}'}, snapshot {row['expert_return']:.1f}); medium at "
            f"{row['medium_steps']} ({row['medium_return']:.1f}); {row['seconds']:.0f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--tasks", nargs="+", help="a subset of the params' study tasks (default: all)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--workers", type=int, default=2, help="runs at a time (one core each)")
    parser.add_argument("--out", type=Path, default=Path("behaviour_seeds.json"))
    args = parser.parse_args()
    params = with_overrides(yaml.safe_load(args.params.read_text()), args.set)
    params["collect"]["datasets"] |= {"expert_episodes": 1, "medium_episodes": 1}
    params["collect"]["schedule"]["random_episodes"] = 1
    study = study_config(params)
    _, config = collect_configs(params, study)
    unknown = set(args.tasks or ()) - set(study.tasks)
    if unknown:
        raise SystemExit(f"error: --tasks {sorted(unknown)}: not among the params' study.tasks {list(study.tasks)}")
    runs = [(task, seed) for seed in args.seeds for task in (args.tasks or study.tasks)]
    rows = []
    with ProcessPoolExecutor(args.workers) as pool:  # each row printed and saved as its run ends
        futures = [pool.submit(run_one, task, seed, config) for task, seed in runs]
        for future in as_completed(futures):
            rows.append(future.result())
            print(row_line(rows[-1]), flush=True)
            record = {"params": str(args.params), "set": args.set, "runs": rows}
            args.out.write_text(json.dumps(record, indent=2) + "\n")
    met = sum(row["met"] for row in rows)
    print(f"{met} of {len(rows)} runs met every criterion; {sum(r['seconds'] for r in rows) / 60:.1f} core-minutes")


if __name__ == "__main__":
    main()
