"""report stage: results/report.md and its figures, from the run's result files (mop_core/report/document.py).

    python stages/report.py      # or: dvc repro report

Reads only what the other stages wrote under results/ (metrics JSON, learning-curve TSVs, figures)
for the runs of the study's catalogue; a missing file means that part of the study was not run, and
its section says so. The report opens with this profile's scale beside the thesis's (profiles/thesis.yaml)
and the verdict of every finding (mop_core/report/findings.py). Writes results/report.md, results/report/*.png,
results/verdicts.json (every finding's verdict and effects) and results/metrics.json (the headline
numbers, mop_core/report/headline.py, and the verdict counts).
"""

from __future__ import annotations

from pathlib import Path

from common import load_params, run_stage

from mop_core.data import atomic_path, write_json
from mop_core.experiment.catalogue import build_catalogue
from mop_core.report.common_structure import structure_section
from mop_core.report.document import render_report
from mop_core.report.evidence import Evidence
from mop_core.report.headline import headline_metrics
from mop_core.report.load import load_results, read_optional
from mop_core.report.sharing import sharing_section
from mop_core.report.shift import shift_section
from mop_core.report.verdict_section import decide, verdict_record, verdict_section
from mop_core.storage.layout import COMPOSE_METRICS, HEADLINE_METRICS, RESULTS, SHIFT_METRICS, VERDICTS

REPORT = RESULTS / "report.md"
FIGURES = RESULTS / "report"
THESIS_PROFILE = Path("profiles/thesis.yaml")  # the thesis's scale, beside this run's in the report's header


def main() -> None:
    params = load_params()
    thesis = load_params(THESIS_PROFILE)
    results = load_results(build_catalogue(params), params)
    shift_metrics = read_optional(SHIFT_METRICS)
    decisions = decide(Evidence(results, shift_metrics))
    prefix = FIGURES.relative_to(RESULTS).as_posix() + "/"
    later = [structure_section(results, FIGURES, prefix), sharing_section(results, FIGURES, prefix)]
    shift = shift_section(shift_metrics, read_optional(COMPOSE_METRICS), results.tasks,
                          "state_shift/figures/")
    markdown = render_report(results, FIGURES, prefix, later, [shift], verdict_section(decisions, params, thesis))
    with atomic_path(REPORT) as tmp:
        tmp.write_text(markdown)
    record = verdict_record(decisions)
    write_json(VERDICTS, record)
    headline = headline_metrics(results.evaluation, results.shared, results.tasks)
    write_json(HEADLINE_METRICS, headline | {"verdicts": record["thesis_findings"]})  # counts: dvc metrics diff
    print(f"report: wrote {REPORT} ({len(markdown.splitlines())} lines) and {FIGURES}/")


if __name__ == "__main__":
    run_stage(main, __doc__)
