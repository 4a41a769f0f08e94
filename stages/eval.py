"""eval stage: every policy of the study rolled out online, with 95% confidence intervals.

    python stages/eval.py

Evaluates, each on ``eval.episodes`` episodes per task (the same episode seeds for every policy),
every policy of the study's catalogue (mop_core/experiment/catalogue.py) on the tasks it was trained for: the
behaviour snapshots, the teachers, the naive multi-task baseline and every student; and each task's
deterministic teacher on every other task's reward (thesis 6.4.5). Returns also as normalised scores;
IQM and probabilities of improvement on them (mop_core/eval_study.py). A data_sharing substitute task
(stand_still) has no collect run: its R_random is measured here, with as many random episodes.

Writes results/eval/metrics.json (readable with `dvc metrics show <path>`), results/eval/returns.tsv (one row
per policy group and task, for `dvc plots`), results/eval/returns.json (every episode's return),
the bar chart results/eval/returns.png and the students' learning curves
results/eval/student_curves.png.
"""

from __future__ import annotations

from common import load_params, require_inputs, run_stage

from mop_core.eval_study import (
    eval_metrics,
    evaluate_study,
    normalisers,
    print_summary,
    substitute_normalisers,
    write_eval_outputs,
    write_eval_timing,
)
from mop_core.experiment.catalogue import build_catalogue
from mop_core.experiment.study import EvalConfig, study_config, typed_section
from mop_core.learning.runtime import progress_enabled
from mop_core.provenance import check_policies
from mop_core.storage.layout import COLLECT_METRICS, EVAL_METRICS, timing_file
from mop_core.walker.tasks import substitute_base


def main() -> None:
    params = load_params()
    study, config = study_config(params), typed_section(params, "eval", EvalConfig)
    catalogue = build_catalogue(params)
    jobs = catalogue.eval_jobs()
    require_inputs(sorted({job.checkpoint for job in jobs}), "distill")
    require_inputs([COLLECT_METRICS], "collect")
    check_policies(params, catalogue)  # every checkpoint is the run the catalogue names (widths, seeds, settings)
    norms = normalisers(study.tasks, COLLECT_METRICS)
    substitutes = {task: substitute_base(task) for task in catalogue.eval_tasks if task not in study.tasks}
    norms |= substitute_normalisers(substitutes, norms, study.seed, study.episode_length, config.rollout_envs)
    evaluation = evaluate_study(catalogue, config, study.episode_length, norms, progress_enabled(study.progress))
    metrics = eval_metrics(evaluation, catalogue, config, norms)
    plotted = write_eval_outputs(EVAL_METRICS.parent, evaluation, metrics, catalogue, config)
    print_summary(plotted, metrics, write_eval_timing(timing_file("eval"), evaluation))


if __name__ == "__main__":
    run_stage(main, __doc__)
