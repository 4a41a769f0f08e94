"""How a finding is measured on a run's evidence: effects over runs of student, teacher and tau comparisons
(paired by seed, against a teacher run, against the thesis's value), each a function of the evidence."""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Sequence

import numpy as np
from scipy.stats import beta, spearmanr

from mop_core.experiment.variants import Variant
from mop_core.report.evidence import Evidence
from mop_core.report.verdicts import (
    Effect,
    not_run,
    paired,
    single_runs,
    unpaired,
    versus_constant,
    versus_run,
)
from mop_core.statistics import MIN_SEEDS_FOR_SEED_CI, TAU_BOUNDS, seed_interval

MOP: Variant | None = None  # plain MOP's students: no variant


def student_vs_student(x: Variant | None, y: Variant | None, per_task: bool = True, tasks: Sequence[str] | None = None,
                       losses: tuple[str, str] = ("mse", "mse")) -> Callable[[Evidence], list[Effect]]:
    """Student variants x - y (normalised return; of ``losses``), paired by seed: per task, or the mean
    over tasks."""
    def measure(ev: Evidence) -> list[Effect]:
        gx, gy = ev.student(x, losses[0]), ev.student(y, losses[1])
        if not per_task:
            a, b = ev.task_mean(gx, tasks), ev.task_mean(gy, tasks)
            return [paired("mean over tasks", a, b)]
        out = []
        for task in tasks or ev.tasks:
            out.append(paired(task, ev.scores(gx, task), ev.scores(gy, task)))
        return out
    return measure


def student_vs_teacher(variant: Variant | None, teacher: Callable[[Evidence, str], str | None], loss: str = "mse",
                       tasks: Sequence[str] | None = None) -> Callable[[Evidence], list[Effect]]:
    """A student group against the one teacher run it is compared with (a fixed target), per task."""
    def measure(ev: Evidence) -> list[Effect]:
        out = []
        for task in tasks or ev.tasks:
            seeds, group = ev.scores(ev.student(variant, loss), task), teacher(ev, task)
            run = ev.run(group, task) if group else None
            out.append(versus_run(task, seeds, *run) if seeds and run else not_run(task, "not run at this profile"))
        return out
    return measure


def teacher_vs_teacher(a: Callable[[Evidence, str], str], b: Callable[[Evidence, str], str],
                       tasks: Sequence[str] | None = None) -> Callable[[Evidence], list[Effect]]:
    """Two policy groups per task (teachers, the multi-task baseline, a behaviour policy), normalised:
    with >= 3 training seeds on each side, a Welch interval over the seeds (:func:`unpaired`); with
    >= 3 on one side and one policy on the other (a behaviour snapshot, a multi-task baseline trained
    once), the seeds against that one fixed run (:func:`versus_run`); otherwise the difference of two
    single runs' means, no interval."""
    def measure(ev: Evidence) -> list[Effect]:
        out = []
        for task in tasks or ev.tasks:
            ga, gb = a(ev, task), b(ev, task)
            sa, sb = ev.scores(ga, task) or {}, ev.scores(gb, task) or {}
            if len(sa) >= MIN_SEEDS_FOR_SEED_CI and len(sb) >= MIN_SEEDS_FOR_SEED_CI:
                out.append(unpaired(task, sa, sb))
                continue
            if len(sa) >= MIN_SEEDS_FOR_SEED_CI and len(sb) <= 1 and ev.entry(gb, task) is not None:
                out.append(versus_run(task, sa, *ev.run(gb, task)))
                continue
            if len(sb) >= MIN_SEEDS_FOR_SEED_CI and len(sa) <= 1 and ev.entry(ga, task) is not None:
                flipped = versus_run(task, sb, *ev.run(ga, task))  # b - a: the one run a is the fixed side
                out.append(replace(flipped, value=-flipped.value, low=-flipped.high, high=-flipped.low))
                continue
            effect = single_runs(task, ev.entry(ga, task), ev.entry(gb, task))
            out.append(effect if effect.value is None else
                       Effect(task, effect.value * ev.scale(task), n=effect.n, unit=effect.unit, why=effect.why))
        return out
    return measure


def teachers_reach(ratio: float) -> Callable[[Evidence], list[Effect]]:
    """Per task and teacher level: deterministic teachers' return over their dataset's return, minus
    ``ratio``, over training seeds."""
    def measure(ev: Evidence) -> list[Effect]:
        return [versus_constant(f"{task} {level}", ev.teacher_ratios(task, level), ratio)
                for level in ev.results.levels for task in ev.tasks]
    return measure


def teachers_late_gain(ev: Evidence) -> list[Effect]:
    """Per task and teacher level: deterministic teachers' curve rise over the last quarter of their
    gradient steps (in dataset returns), over training seeds: ~0 when the fixed step budget reached a
    plateau."""
    return [versus_constant(f"{task} {level}", ev.teacher_late_gain(task, level), 0.0)
            for level in ev.results.levels for task in ev.tasks]


def probe_tau_vs(x: Variant | None, y: Variant | None = None, layers: Sequence[int] | None = None, at_y: str = "final"
                 ) -> Callable[[Evidence], list[Effect]]:
    """Per layer: per-state tau-a on the probe states of students x - students y, paired by seed."""
    def measure(ev: Evidence) -> list[Effect]:
        out = []
        for layer in layers or ev.layers() or (1, 2):
            out.append(paired(f"layer {layer}", ev.probe_tau(x, layer), ev.probe_tau(y, layer, at_y)))
        return out
    return measure


def sc_tau_vs(x: Variant | None, y: Variant | None, measure_key: str = "average_tau_a", scope: str | None = None
              ) -> Callable[[Evidence], list[Effect]]:
    """Per layer: shared_computation tau of student groups x - y (structure variants), paired by seed."""
    def measure(ev: Evidence) -> list[Effect]:
        out = []
        for layer in ev.layers():
            out.append(paired(f"layer {layer}", ev.sc_tau(ev.structure(x, scope=scope), layer, measure_key),
                              ev.sc_tau(ev.structure(y, scope=scope), layer, measure_key)))
        return out
    return measure


def sc_tau_vs_thesis(variant: Variant | None, thesis: tuple[float, float]) -> Callable[[Evidence], list[Effect]]:
    """Per layer: average tau-a of a group (Table 6.2's measure) minus the thesis's Table 6.2 value."""
    def measure(ev: Evidence) -> list[Effect]:
        out = []
        for layer, value in zip(ev.layers() or (1, 2), thesis):
            out.append(versus_constant(f"layer {layer}", ev.sc_tau(ev.structure(variant), layer), value))
        return out
    return measure


def at_pairing(pairing: str, measure: Callable[[Evidence], list[Effect]]) -> Callable[[Evidence], list[Effect]]:
    """``measure`` on the students and teachers of distill pairing ``pairing`` instead of the run's
    comparison pairing; one not-run cell where the run has no such pairing."""
    def wrapped(ev: Evidence) -> list[Effect]:
        if pairing not in ev.results.pairing_levels:
            return [not_run(pairing, f"no {pairing} pairing in this run (distill.pairings: "
                                     f"{list(ev.results.pairing_levels)})")]
        settings = {**ev.settings, "structure_pairing": pairing}
        return measure(replace(ev, results=replace(ev.results, settings=settings)))
    return wrapped


def pairing_tau_vs_others(pairing: str) -> Callable[[Evidence], list[Effect]]:
    """Per other single-level pairing of the run and layer: the average tau-a (Table 6.2's measure) of
    ``pairing``'s MSE students minus that pairing's, paired by seed (training seeds in distill.seeds order)."""
    def measure(ev: Evidence) -> list[Effect]:
        others = [p for p, levels in ev.results.pairing_levels.items() if p != pairing and len(set(levels)) == 1]
        if pairing not in ev.results.pairing_levels or not others:
            return [not_run(pairing, f"needs the {pairing} pairing and another single-level one (distill.pairings: "
                                     f"{list(ev.results.pairing_levels)})")]
        return [paired(f"{pairing} - {other}, layer {layer}", ev.sc_tau(ev.structure(scope=pairing), layer),
                       ev.sc_tau(ev.structure(scope=other), layer), "training seeds (paired)")
                for other in others for layer in ev.layers()]
    return measure


def mop_teacher(ev: Evidence, task: str) -> str:
    return ev.teacher(task)


def gaussian_teacher(ev: Evidence, task: str) -> str:
    return ev.teacher(task, "gaussian")


def ds_teacher(ev: Evidence, task: str) -> str:
    return f"teacher_ds_{ev.level(task)}_deterministic"


def other_task(ev: Evidence, task: str) -> str:
    return next(t for t in ev.tasks if t != task)


def oqs_teacher(ev: Evidence, task: str) -> str:
    """Task ``task``'s OQS candidate trained on the other task's data relabelled (D_{j->i}, j != i)."""
    return f"teacher_from_{other_task(ev, task)}_{ev.level(task)}_deterministic"


def best_teacher(ev: Evidence, task: str) -> str | None:
    """The better (by eval mean) of task's own MOP teacher and its OQS candidate on the other's data."""
    groups = [g for g in (mop_teacher(ev, task), oqs_teacher(ev, task)) if ev.entry(g, task)]
    return max(groups, key=lambda g: ev.entry(g, task)["mean"]) if groups else None


def cross_task_walk_teacher(ev: Evidence) -> list[Effect]:
    """Table 6.3: on each study task's reward, the walk teacher minus that task's own teacher (runs trained once)."""
    cross = (ev.results.evaluation or {}).get("cross_task", {}).get(ev.level(ev.tasks[0]), {})
    if "walk" not in cross:
        return [not_run("walk", "no walk teacher in this study")]
    out = []
    for task in ev.tasks:
        if task == "walk" or task not in cross:
            continue
        walk, own = cross["walk"].get(task), cross[task].get(task)
        out.append(Effect(f"on {task}'s reward", (walk["mean"] - own["mean"]) * ev.scale(task), n=1,
                          unit="run per side", why="1 run per side: no interval over runs"))
    return out


def composed_widths(ev: Evidence) -> list[int]:
    return sorted(ev.settings.get("shift_widths", []))


def width_composed_mean(ev: Evidence, datasets: Sequence[str], width: int) -> dict[int, float] | None:
    """Per seed: the mean over tasks and ``datasets`` of the width-``width`` students' normalised returns."""
    means = [ev.task_mean(ev.student(ev.composed(d, width))) for d in datasets]
    if any(m is None for m in means):
        return None
    seeds = sorted(set.intersection(*(set(m) for m in means)))
    return {s: float(np.mean([m[s] for m in means])) for s in seeds}


def random_vs_teacher_data(ev: Evidence) -> list[Effect]:
    widths = composed_widths(ev)
    if not widths:
        return [not_run("smallest width", "no composed-data students (state_shift.widths)")]
    w = widths[0]
    a = width_composed_mean(ev, ("random90", "random99"), w)
    b = width_composed_mean(ev, ("online", "noise"), w)
    return [paired(f"width {w}", a, b)]


def noise_vs_online_small(ev: Evidence) -> list[Effect]:
    widths = composed_widths(ev)
    if not widths:
        return [not_run("smallest width", "no composed-data students (state_shift.widths)")]
    w = widths[0]
    return student_vs_student(ev.composed("noise", w), ev.composed("online", w))(ev)


def random90_at_512(ev: Evidence) -> list[Effect]:
    if 512 not in composed_widths(ev):
        return [not_run("width 512", f"needs width 512 (state_shift.widths: {composed_widths(ev)})")]
    return student_vs_teacher(ev.composed("random90", 512), mop_teacher)(ev)


def online_vs_offline(ev: Evidence) -> list[Effect]:
    width = ev.settings.get("student_width")
    if width not in composed_widths(ev):
        return [not_run("online", "no online students at the distill width")]
    return student_vs_student(ev.composed("online", width), MOP)(ev)


def shift_rank_correlation(ev: Evidence) -> list[Effect]:
    """Hypothesis 1 at the smallest composed width: per training seed and task, Spearman's rho between
    the measured KL(teacher || dataset) and the student's normalised return over the datasets (the
    offline one and each composed one); t-interval over seeds."""
    widths, shift = composed_widths(ev), (ev.shift or {}).get("shift", {})
    if not widths or not shift:
        return [not_run("smallest width", "no composed-data students or no shift measure")]
    w, out = widths[0], []
    for task in ev.tasks:
        kl = {name: m["kl"] for name, m in shift.get(task, {}).items() if "kl" in m}
        groups = {d: ev.student(ev.composed(d, w)) for d in ev.settings.get("shift_datasets", []) if d in kl}
        per_seed = {d: ev.scores(g, task) for d, g in groups.items()}
        per_seed = {d: s for d, s in per_seed.items() if s}
        if len(per_seed) < 3:
            out.append(not_run(task, "fewer than 3 composed datasets with students"))
            continue
        seeds = sorted(set.intersection(*(set(s) for s in per_seed.values())))
        rhos = {s: float(spearmanr([kl[d] for d in per_seed], [per_seed[d][s] for d in per_seed])[0]) for s in seeds}
        ci = seed_interval(list(rhos.values()), TAU_BOUNDS)
        out.append(Effect(f"{task}, width {w}", ci["mean"], ci["ci_low"], ci["ci_high"], len(seeds),
                          f"training seeds (rho over {len(per_seed)} datasets each)",
                          "" if ci["ci_low"] is not None else "fewer than 3 seeds"))
    return out


def online_within_null(ev: Evidence) -> list[Effect]:
    """The online dataset (the teacher's own rollouts: no shift by construction) against the paired
    episode-split null: the share of episode-halves in which its KL reads above the same half's null,
    minus the coin flip 1/2 that no shift gives, with a Clopper-Pearson 95% interval over the halves
    (re-deals of the same reference episodes, so the interval is optimistic)."""
    shift = (ev.shift or {}).get("shift", {})
    out = []
    for task in ev.tasks:
        online, reference = shift.get(task, {}).get("online"), shift.get(task, {}).get("reference", {})
        if not online or "above_null" not in online:
            out.append(not_run(task, "no online dataset measured against an episode-split null"))
            continue
        n = int(reference["halves"])
        above = round(online["above_null"] * n)
        low = beta.ppf(0.025, above, n - above + 1) if above > 0 else 0.0
        high = beta.ppf(0.975, above + 1, n - above) if above < n else 1.0
        out.append(Effect(task, online["above_null"] - 0.5, float(low) - 0.5, float(high) - 0.5, n,
                          "episode-halves (share above the paired null - 1/2)"))
    return out


def untrained_minus(ev: Evidence) -> list[Effect]:
    """Plain MOP students: final per-state tau-a on the probe states minus the same student's at
    initialisation, paired (each student with itself)."""
    out = []
    for layer in ev.layers() or (1, 2):
        out.append(paired(f"layer {layer}", ev.probe_tau(MOP, layer), ev.probe_tau(MOP, layer, "at_init"),
                          "training seeds (each student with itself)"))
    return out


def substitute_sharing_tau(ev: Evidence) -> list[Effect]:
    """On each substitute's task set: per-state tau-a of DS and OQS students minus MOP's, per layer."""
    substitutes = list(dict.fromkeys(r.key["substitute"] for r in ev.results.substitutes))
    if not substitutes:
        return [not_run("substitute set", "no data_sharing.substitutes")]
    out = []
    for sub in substitutes:
        scope = f"{sub}-{ev.pairing}"
        for variant, name in ((ev.sharing("ds"), "DS"), (ev.sharing("oqs", "own"), "OQS")):
            for cell in sc_tau_vs(variant, ev.sharing("mop"), "per_state_tau_a", scope)(ev):
                out.append(Effect(f"{name} {cell.label}", cell.value, cell.low, cell.high, cell.n, cell.unit, cell.why))
    return out



def labelled(label: str, measure: Callable[[Evidence], list[Effect]]) -> Callable[[Evidence], list[Effect]]:
    """``measure``'s cells with ``label`` before their own (to join several measures in one finding)."""
    def wrapped(ev: Evidence) -> list[Effect]:
        return [Effect(f"{label}, {e.label}", e.value, e.low, e.high, e.n, e.unit, e.why) for e in measure(ev)]
    return wrapped


def joined(*measures: Callable[[Evidence], list[Effect]]) -> Callable[[Evidence], list[Effect]]:
    return lambda ev: [effect for measure in measures for effect in measure(ev)]


def smallest_width(ev: Evidence) -> int | None:
    widths = ev.settings.get("widths") or []
    return min(widths) if widths else None


def width_measure(kind: str) -> Callable[[Evidence], list[Effect]]:
    """The smallest common_structure width against the plain students: return per task, or probe tau."""
    def measure(ev: Evidence) -> list[Effect]:
        w = smallest_width(ev)
        if w is None:
            return [not_run("smallest width", "no width students (common_structure.widths)")]
        inner = student_vs_student(ev.width(w), MOP) if kind == "return" else probe_tau_vs(ev.width(w))
        return labelled(f"width {w}", inner)(ev)
    return measure


def ranking_measure(loss: str, kind: str, layers: Sequence[int] | None = None,
                    per_task: bool = True) -> Callable[[Evidence], list[Effect]]:
    def measure(ev: Evidence) -> list[Effect]:
        if loss not in ev.settings.get("ranking_losses", []):
            return [not_run(loss, f"needs {loss} students (common_structure.ranking_losses)")]
        if kind == "return":
            return student_vs_student(ev.ranking(loss), MOP, per_task=per_task)(ev)
        return probe_tau_vs(ev.ranking(loss), MOP, layers)(ev)
    return measure
