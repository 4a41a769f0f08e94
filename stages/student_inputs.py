"""student_inputs stage: per distill entry, a record of the files its students will read, by content hash.

    python stages/student_inputs.py

Writes data/student_inputs/<loss>-<pairing>.json (mop_core.experiment.catalogue.student_inputs): the SHA-256 of
each teacher checkpoint the entry's students (every seed) learn from and the content hash of each
dataset their states come from. Each ``distill`` entry depends on its own record instead of on every
teacher, so a retrained teacher reruns only its students (this stage takes seconds; a record whose
files did not change is rewritten byte for byte, and DVC leaves its students alone).
"""

from __future__ import annotations

from common import load_params, require_inputs, run_stage

from mop_core.data import write_json
from mop_core.experiment.catalogue import build_catalogue, student_inputs
from mop_core.experiment.study import study_config
from mop_core.provenance import Provenance, check_teachers
from mop_core.storage.layout import student_inputs_file
from mop_core.teachers import teacher_config


def main() -> None:
    params = load_params()
    study, catalogue = study_config(params), build_catalogue(params)
    students = catalogue.students + catalogue.shift_students
    require_inputs(sorted({t.paths.checkpoint for run in students for t in run.teachers}), "train_teachers")
    files = {d for run in students for d in run.input_datasets}
    require_inputs(sorted(d for d in files if d.parent.name != "composed"), "collect")
    require_inputs(sorted(d for d in files if d.parent.name == "composed"), "compose")
    # record only files that are what the catalogue says (a swapped file is refused, not laundered)
    check_teachers([t for run in students for t in run.all_teachers], study.seed,
                   lambda actor, level: teacher_config(params, study, actor, level))
    Provenance.of_params(params, catalogue).check_datasets(sorted(files))
    entries = catalogue.student_entries()
    for entry, runs in entries.items():
        write_json(student_inputs_file(entry), student_inputs(runs))
    print(f"student_inputs: recorded the teachers and datasets of {len(catalogue.students)} students "
          f"and {len(catalogue.shift_students)} state-shift students in {len(entries)} distill entries")


if __name__ == "__main__":
    run_stage(main, __doc__)
