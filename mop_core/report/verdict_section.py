"""The report's opening: this profile's scale beside the thesis's, and a verdict for every finding.

:func:`decide` measures every registered finding (mop_core.report.findings) on a run and applies the rule of
mop_core.report.verdicts; :func:`verdict_section` renders the two tables (the thesis's findings, then this
run's own) with the prose of what this run shows, and :func:`verdict_record` the same as a JSON record
(``results/verdicts.json``; its counts go into ``results/metrics.json``, so ``dvc metrics diff``
compares them across runs).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from mop_core.report.evidence import Evidence
from mop_core.report.findings import FINDINGS, Finding
from mop_core.report.format import fmt, table
from mop_core.report.verdicts import CONTRADICTED, INCONCLUSIVE, REPRODUCED, Effect, finding_verdict

MARKDOWN_LINK = re.compile(r"\[([^\]]*)\]\(#page-[^)]*\)")  # the thesis text's cross-reference links


def plain_quote(text: str) -> str:
    """The thesis's words as they read: cross-reference links to their text, tabs to spaces."""
    return MARKDOWN_LINK.sub(r"\1", text).replace("\\", "").replace("\t", " ").strip()


@dataclass(frozen=True)
class Decision:
    finding: Finding
    effects: tuple[Effect, ...]
    verdict: str
    reason: str


def decide(evidence: Evidence, findings: Sequence[Finding] | None = None) -> list[Decision]:
    out = []
    for finding in findings or list(FINDINGS.values()):
        effects = tuple(finding.measure(evidence))
        verdict, reason = finding_verdict(effects, finding.expects, finding.every_cell)
        out.append(Decision(finding, effects, verdict, reason))
    return out


def effect_text(effect: Effect, digits: int = 3) -> str:
    if effect.value is None:
        return f"{effect.label}: not run ({effect.why})"
    value = f"{effect.label}: {fmt(effect.value, digits)}"
    if effect.decided:
        return f"{value} [{fmt(effect.low, digits)}, {fmt(effect.high, digits)}] (n={effect.n} {effect.unit})"
    return f"{value} (n={effect.n} {effect.unit}; {effect.why})"


def detectable_text(effects: Sequence[Effect], digits: int = 3) -> str:
    sizes = [e.detectable for e in effects if e.detectable is not None]
    return f"+-{fmt(max(sizes), digits)}" if sizes else "-"


def digits_of(finding: Finding) -> int:
    return 3 if any(word in finding.statistic for word in ("tau", "rho", "nats", "share")) else 1


def rows(decisions: Sequence[Decision]) -> list[list[str]]:
    out = []
    for number, d in enumerate(decisions, 1):
        f, digits = d.finding, digits_of(d.finding)
        quote = f"\"{plain_quote(f.claim)}\"" + (f" (l. {f.line})" if f.line else "")
        out.append([str(number), f.section, quote, f"{f.statistic}; claim: {f.expects.text()}",
                    "<br>".join(effect_text(e, digits) for e in d.effects), detectable_text(d.effects, digits),
                    f"**{d.verdict}** ({d.reason})"])
    return out


HEADER = ["#", "section", "claim", "statistic (claim)", "effect [95% CI] (unit, n)", "smallest detectable",
          "verdict"]
RULE = ("Rule (mop_core/report/verdicts.py): reproduced when the 95% interval of the effect lies on the claimed side "
        "of 0 (or, for a claim of equality, inside the margin), contradicted when it lies wholly on the other side "
        "(outside the margin), inconclusive otherwise: the interval straddles the boundary, fewer than 3 runs give "
        "no interval over runs (a teacher trained once: its episodes say nothing about another seed), or the "
        "finding needs a level, width or regulariser this profile does not run. Effects on returns are in "
        "normalised points; 'matches' claims hold within {margin:g} points, tau equalities within {tau:g}. "
        "Smallest detectable: the interval's half-width, the smallest effect that could have moved it off 0 at "
        "this n and spread. A finding with several cells (tasks, layers) takes their verdict when they agree; "
        "otherwise it is inconclusive with each cell named, or contradicted where one cell contradicts a claim "
        "that must hold on each.")


def summary_prose(decisions: Sequence[Decision], whose: str) -> str:
    counts = {v: [d for d in decisions if d.verdict == v] for v in (REPRODUCED, CONTRADICTED, INCONCLUSIVE)}
    not_run = [d for d in counts[INCONCLUSIVE] if all(e.value is None for e in d.effects)]
    few = [d for d in counts[INCONCLUSIVE] if d not in not_run and all(not e.decided for e in d.effects)]

    def keys(ds: Sequence[Decision]) -> str:
        return ", ".join(d.finding.key for d in ds) or "none"
    return (f"**What this run shows.** Of the {len(decisions)} {whose}, it reproduces {len(counts[REPRODUCED])} "
            f"({keys(counts[REPRODUCED])}), contradicts {len(counts[CONTRADICTED])} "
            f"({keys(counts[CONTRADICTED])}) and cannot decide {len(counts[INCONCLUSIVE])}: "
            f"{len(not_run)} not run at this profile's levels or sizes ({keys(not_run)}), {len(few)} with fewer "
            f"than 3 runs ({keys(few)}), the rest with intervals that straddle the claim's boundary.")


def scale_row(params: Mapping[str, Any]) -> dict[str, str]:
    """A profile's scale: what the verdicts' n and power follow from."""
    collect, teachers, distill = params["collect"], params["train_teachers"], params["distill"]
    datasets, schedule = collect.get("datasets", {}), collect["schedule"]
    steps = (f"{schedule['total_steps']} / {schedule.get('medium_step')}" if not schedule.get("expert_return") else
             f"until the expert returns {schedule['expert_return']} over {schedule.get('expert_eval_episodes')} "
             f"episodes (at most {schedule['total_steps']}; each task's steps: section 1) / the snapshot nearest "
             "the published medium return")
    return {"behaviour TD3 gradient steps (expert / medium)": steps,
            "dataset episodes (expert / medium)":
            f"{datasets.get('expert_episodes', 'n/a')} / {datasets.get('medium_episodes', 'n/a')}",
            "teacher levels": ", ".join(params["study"]["levels"]),
            "PBRL teacher steps x seeds": f"{teachers['schedule']['steps']} x {len(teachers['seeds'])}",
            "student steps x seeds": f"{distill['schedule']['steps']} x {len(distill['seeds'])}",
            "eval episodes per policy and task": str(params["eval"]["episodes"]),
            "shared-computation episodes per task": str(params.get("shared_computation", {}).get("episodes", "n/a"))}


def scale_lines(params: Mapping[str, Any] | None, thesis: Mapping[str, Any] | None) -> list[str]:
    if not params:
        return []
    ours = scale_row(params)
    theirs = scale_row(thesis) if thesis else {}
    return ["**Scale.** This run's profile next to the thesis's (profiles/thesis.yaml, whose values cite the "
            "thesis):", "", table(["", "this run", "thesis"], [[k, v, theirs.get(k, "n/a")] for k, v in ours.items()]),
            ""]


def verdict_section(decisions: Sequence[Decision], params: Mapping[str, Any] | None = None,
                    thesis: Mapping[str, Any] | None = None) -> str:
    from mop_core.report.findings import RETURN_MARGIN, TAU_MARGIN

    thesis_rows = [d for d in decisions if not d.finding.own]
    own_rows = [d for d in decisions if d.finding.own]
    out = ["## Verdicts: what this run reproduces", ""] + scale_lines(params, thesis)
    out += ["Each row quotes a finding of the thesis (its words, its section and the line of "
            "shared/reference/mop-thesis.txt), the statistic of this run that tests it and the verdict.", "",
            table(HEADER, rows(thesis_rows)), "", summary_prose(thesis_rows, "findings of the thesis"), "",
            RULE.format(margin=RETURN_MARGIN, tau=TAU_MARGIN), ""]
    if own_rows:
        out += ["### This run's own findings", "",
                "Statements of this study, not of the thesis, tested by the same rule.", "",
                table(HEADER, rows(own_rows)), "", summary_prose(own_rows, "findings of its own"), ""]
    return "\n".join(out)


def verdict_record(decisions: Sequence[Decision]) -> dict:
    """Verdict counts and each finding's verdict and cells (numbers), for ``dvc metrics``."""
    counts = {v: sum(d.verdict == v for d in decisions if not d.finding.own)
              for v in (REPRODUCED, CONTRADICTED, INCONCLUSIVE)}
    findings = {d.finding.key: {"verdict": d.verdict, "reason": d.reason,
                                "cells": {e.label: {"value": e.value, "ci_low": e.low, "ci_high": e.high, "n": e.n,
                                                    "unit": e.unit} for e in d.effects}}
                for d in decisions}
    return {"thesis_findings": counts, "findings": findings}
