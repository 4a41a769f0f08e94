"""distill stage: the students of one distill entry (every seed of a loss, variant and pairing), trained together.

    python stages/distill.py --entry mse-w16-medium [--seeds 0 2]   (a subset of distill.seeds)

The catalogue names the entries and what each student learns from (mop_core.experiment.variants: its change); the
inputs are checked against data/student_inputs/<entry>.json. Files per seed under <entry>/: mop_core.storage.layout.
"""

from __future__ import annotations

import argparse

from common import load_params, require_inputs, run_stage

from mop_core.config import keys_under, require
from mop_core.data import read_json
from mop_core.distill.config import distill_config
from mop_core.distill.run import StudentSources, distill_students, finish_students
from mop_core.experiment.catalogue import LOSS_ACTORS, build_catalogue
from mop_core.experiment.study import distill_grid, study_config, study_device
from mop_core.learning.runtime import configure_compute, progress_enabled
from mop_core.provenance import check_student_sources
from mop_core.storage.layout import student_inputs_file


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--entry", required=True, help="a distill entry of the catalogue, e.g. mse-w16-medium")
    parser.add_argument("--seeds", type=int, nargs="+", default=None, help="a subset of distill.seeds")
    args = parser.parse_args()
    params = load_params()
    study, catalogue = study_config(params), build_catalogue(params)
    grid, entries = distill_grid(params, study, LOSS_ACTORS), catalogue.student_entries()
    require(args.entry in entries, "--entry", f"a distill entry of this study, one of {sorted(entries)}", args.entry)
    runs, seeds = entries[args.entry], list(grid.seeds) if args.seeds is None else args.seeds
    require(len(set(seeds)) == len(seeds) and set(seeds) <= set(grid.seeds), "--seeds",
            f"distinct seeds of distill.seeds {list(grid.seeds)}", seeds)
    runs = [run for run in runs if run.seed in seeds]
    first = runs[0]
    config = first.configure(distill_config(params, first.loss))
    device = study_device(study)
    for stage, files in {**first.upstream_files(), "student_inputs": (student_inputs_file(args.entry),)}.items():
        require_inputs(files, stage)
    check_student_sources(params, catalogue, runs, student_inputs_file(args.entry))  # before any compute

    configure_compute(grid.threads)
    with keys_under("distill"):  # sizes checked against the states: distill.batch_size
        records = distill_students(StudentSources.of(first), config, grid.schedule, study.episode_length, seeds,
                                   study.seed, [run.paths for run in runs], first.paths.resume, first.paths.timing,
                                   device, progress_enabled(study.progress), args.entry)
    timing = read_json(first.paths.timing)
    finish_students(runs, records)
    print(f"{args.entry}: {len(runs)} students trained together in {timing['seconds']:.0f} s, "
          f"{timing['steps_per_second']:.0f} group steps/s")


if __name__ == "__main__":
    run_stage(main)
