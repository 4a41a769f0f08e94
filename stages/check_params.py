"""params stage: check the whole params file before any other stage runs (mop_core/study_params.py).

    python stages/check_params.py

dvc.yaml has this stage depend on the whole params file (``params.yaml:`` with no keys), so any
edit reruns it, a new or misspelt section (``distil:`` beside ``distill:``) included, which
mop_core.study_params refuses with the unknown keys and the settings that would have no effect.
Every stage of dvc.yaml depends on this stage's output, whose content never changes while the
params are valid: a valid edit reruns only the stages whose own params changed, and an invalid one
stops ``dvc repro`` here, with one line naming the key, before DVC deletes any other stage's
outputs.
"""

from __future__ import annotations

from common import PARAMS, PARAMS_CHECKED, load_params, run_stage

from mop_core.data import atomic_path
from mop_core.study_params import check_params


def main() -> None:
    check_params(load_params(), str(PARAMS))
    with atomic_path(PARAMS_CHECKED) as tmp:
        tmp.write_text("params.yaml passed mop_core/study_params.py's checks\n")
    print(f"params: every section checked; wrote {PARAMS_CHECKED}")


if __name__ == "__main__":
    run_stage(main, __doc__)
