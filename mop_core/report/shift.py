"""The report's state-shift section (thesis 5.2; the compose and state_shift stages' results).

Every number is read from results/compose/metrics.json and results/state_shift/metrics.json (the
figures are the state_shift stage's); nothing here computes a result.
"""

from __future__ import annotations

from typing import Mapping, Sequence

from mop_core.experiment.study import OFFLINE_DATA
from mop_core.report.format import fmt, not_run, table
from mop_core.storage.layout import HELDOUT_SUFFIX


def _plain(info: Mapping) -> bool:
    return info.get("correction", "none") == "none"


def _interval(entry: Mapping | None, digits: int = 1) -> str:
    if not entry:
        return "-"
    if entry.get("ci_low") is None:
        return f"{fmt(entry['mean'], digits)} (n={entry['n']})"
    return f"{fmt(entry['mean'], digits)} [{fmt(entry['ci_low'], digits)}, {fmt(entry['ci_high'], digits)}]"


def _cell(row: Mapping, task: str) -> str:
    entry = row.get(task)
    if not entry:
        return "-"
    return f"{_interval(entry['return'])} ({fmt(entry['to_teacher']['mean'], 2)})"


def _data_label(data: str, levels: Mapping[str, str]) -> str:
    level = sorted(set(levels.values()))
    return f"{'+'.join(level)} dataset (behaviour policy)" if data == OFFLINE_DATA else data


def _rows_by(groups: Mapping[str, Mapping], predicate) -> list[str]:
    return [label for label, info in groups.items() if predicate(info)]


def composed_lines(compose: Mapping | None) -> list[str]:
    if not compose:
        return []
    rows = []
    for key, summary in compose.items():
        datasets = sorted(summary["datasets"].items(), key=lambda item: (item[0] == "reference",
                                                                          -item[1]["teacher_episodes"], item[0]))
        for name, d in datasets:
            if name == "reference" or name.endswith(HELDOUT_SUFFIX):
                continue
            rest = f"{d['rest_episodes']} {d['rest']}" if d.get("rest_episodes") else "-"
            rows.append([key, name, str(d["teacher_episodes"]), rest,
                         f"{fmt(d['return_mean'])} +- {fmt(d['return_std'])}"])
        ref = summary["datasets"].get("reference")
        if ref:
            rows.append([key, "reference (held out)", str(ref["teacher_episodes"]), "-",
                         f"{fmt(ref['return_mean'])} +- {fmt(ref['return_std'])}"])
    return [table(["teacher", "dataset", "teacher episodes", "other episodes", "episode return (mean +- sd)"], rows),
            "", "Composed datasets (thesis 5.2.4): whole episodes of the MOP teacher (its rollouts), of the teacher "
            "with N(0, sigma) action noise clipped to [-1, 1] (noise) or of uniformly random actions (random); a "
            "dataset's teacher episodes are the online dataset's first ones and random90's random episodes are "
            "random99's first (the pools are shared, so the datasets differ only by composition). The reference "
            "episodes, on other seeds, are the teacher's visited states every dataset is measured against.", ""]


def shift_lines(metrics: Mapping) -> list[str]:
    shift = metrics.get("shift") or {}
    if not shift:
        return []
    measure = metrics.get("measure", {})
    rows = []
    for task, by_data in shift.items():
        ref = by_data.get("reference", {})
        null = f"{fmt(ref.get('kl_null'), 2)} [{fmt(ref.get('kl_null_min'), 2)}, {fmt(ref.get('kl_null_max'), 2)}]"
        for name, m in by_data.items():
            if name == "reference":
                continue
            verdict = "within" if m.get("within_null") else "above"
            rows.append([task, name, f"{fmt(m['kl'], 2)} [{fmt(m['kl_min'], 2)}, {fmt(m['kl_max'], 2)}]", null,
                         f"{fmt(m.get('kl_excess'), 2)} ({fmt(m.get('above_null'), 1)} of halves above)", verdict,
                         fmt(m["auc"], 3), fmt(m["ess"], 3)])
    ref = next(iter(shift.values())).get("reference", {})
    return [table(["task", "dataset D", "KL(T \\|\\| D), nats: mean [range over halves]", "null: T vs T, mean [range]",
                   "KL - null, paired by half", "vs the null", "classifier AUC", "ESS share of p_T/p_D"], rows), "",
            f"The shift the thesis could not measure (5.2.2), between the teacher's visited states T (its "
            f"held-out reference episodes) and each dataset D, standardised per task, every split by whole "
            f"episodes (an episode's states are near-duplicates: halves that share episodes read 'no shift' "
            f"whatever D is). The k={measure.get('k')} nearest-neighbour estimate of KL(T || D) (Wang, Kulkarni "
            f"and Verdu 2009; what the teacher visits that the data lacks), over {ref.get('halves')} random "
            f"episode-halves of T: per half, {ref.get('kl_states')} states of half A against as many of half B "
            f"(the null: what no shift gives) and against as many of D drawn from as many whole episodes as B "
            f"has (the estimate, on the null's footing). Mean and range (min..max, not a confidence interval) "
            f"over the halves; 'KL - null' pairs each half's estimate with its own null (the same states of A) "
            f"and counts the halves in which D reads above it; D is 'above' its null when it does so in at least "
            f"90% of the halves (under no shift each half is a coin flip), else 'within'. The classifier's AUC "
            f"telling T from D (0.5: indistinguishable) is cross-fitted over two folds of whole episodes of each "
            f"set, on {measure.get('states')} states of each; the effective sample share (sum w)^2 / (n sum w^2) "
            "of the density ratio w = p_T / p_D it implies on D (1: D already looks like T; near 0: a few of D's "
            "states carry T, what reweighted distillation leans on), each state's ratio from the classifier that "
            "did not see its episode. The kNN estimator is biased low in 24 dimensions (tests/test_shift.py), and "
            "a teacher that holds a pose (stand) visits a near-degenerate set: read the values against the null, "
            "not as nats.", ""]


def online_lines(metrics: Mapping, tasks: Sequence[str]) -> list[str]:
    groups, students = metrics.get("groups", {}), metrics.get("students", {})
    width = metrics.get("student_width")
    offline = _rows_by(groups, lambda i: i["data"] == OFFLINE_DATA and i["width"] == width and i["percent"] == 100
                       and _plain(i))
    online = _rows_by(groups, lambda i: i["data"] == "online" and i["width"] == width and _plain(i))
    if not (offline and online):
        return []
    rows = [[_data_label(groups[label]["data"], metrics.get("pairing_levels", {}))]
            + [_cell(students[label], t) for t in tasks] for label in offline + online]
    return ["### Online vs offline states (thesis 5.2.3, Figure 5.7)", "",
            table(["states the student learns on"] + [f"{t}: return [95% CI] (student/teacher)" for t in tasks], rows),
            "", f"MSE students of width {width}, same teachers, steps, batch and seeds; only the states differ: the "
            "offline dataset, or the online dataset (the teacher's own rollouts, as many episodes). "
            + _seed_caption(students, offline + online), ""]


def _seed_caption(students: Mapping, labels: Sequence[str]) -> str:
    row = students[labels[0]]
    task = next(k for k in row if k != "seeds")
    return (f"Each cell: mean over the n={len(row['seeds'])} training seeds of each student's eval-stage return "
            f"({row[task]['episodes_per_seed']} episodes per seed and task), with a Student-t 95% interval over the "
            "seeds (none under 3; cut at 0 where it reaches below), and the mean ratio to the eval-stage return of "
            "the teacher run the students learned from.")


def capacity_lines(metrics: Mapping, tasks: Sequence[str], link_prefix: str) -> list[str]:
    groups, students = metrics.get("groups", {}), metrics.get("students", {})
    labels = _rows_by(groups, lambda i: i["percent"] == 100 and _plain(i))
    composed = [label for label in labels if groups[label]["data"] != OFFLINE_DATA]
    if not composed:
        return []
    order = list(dict.fromkeys(groups[label]["data"] for label in labels))
    labels.sort(key=lambda label: (order.index(groups[label]["data"]), groups[label]["width"]))
    rows = [[_data_label(groups[label]["data"], metrics.get("pairing_levels", {})), str(groups[label]["width"])]
            + [_cell(students[label], t) for t in tasks] for label in labels]
    out = ["### Capacity under a composed shift (thesis 5.2.4, Figure 5.8)", "",
           table(["dataset", "width"] + [f"{t}: return [95% CI] (student/teacher)" for t in tasks], rows), "",
           "MSE students with every hidden layer that wide, on each dataset. " + _seed_caption(students, labels)
           + " The offline rows at widths other than the distill student's are the common_structure width "
           "students (section 7a). Hypothesis 1 predicts the small students to lose most on the datasets with "
           "the largest shift. What the thesis claims of these rows (5.2.4) and this run's verdicts: the verdict "
           "table (random_least_robust_small, noise_most_robust_small, random90_near_teacher_512, hypothesis_1). "
           "DART (Laskey et al. 2017: noise injected into the supervisor's demonstrations covers the states a "
           "perturbed learner reaches) is one possible mechanism for noise data helping small students; this "
           "study does not test it.", "",
           f"![capacity]({link_prefix}capacity.png)", ""]
    corr = metrics.get("hypothesis") or {}
    if corr:
        parts = [f"width {w}: " + ", ".join(f"{task} rho = {fmt(c['spearman'], 2)} (p = {fmt(c['p_value'], 2)}, "
                                            f"{c['points']} datasets)" for task, c in by_task.items())
                 for w, by_task in corr.items()]
        out += ["Hypothesis 1 on the measured axis: per task and width, Spearman's rank correlation between "
                "KL(T || D) and the students' student/teacher return over the datasets at full size (negative: "
                "more shift, less return; per task, because the tasks' KL scales differ) - " + "; ".join(parts)
                + ".", "",
                f"![return against shift]({link_prefix}shift_returns.png)", ""]
    return out


def size_lines(metrics: Mapping, tasks: Sequence[str]) -> list[str]:
    groups, students = metrics.get("groups", {}), metrics.get("students", {})
    width = metrics.get("student_width")
    labels = _rows_by(groups, lambda i: i["data"] == OFFLINE_DATA and i["width"] == width and _plain(i))
    if len(labels) < 2:
        return []
    labels.sort(key=lambda label: groups[label]["percent"])
    rows = [[f"{groups[label]['percent']}%"] + [_cell(students[label], t) for t in tasks] for label in labels]
    return ["### Dataset size (thesis 7.3)", "",
            table(["share of each dataset's episodes"] + [f"{t}: return [95% CI] (student/teacher)" for t in tasks],
                  rows), "",
            "MSE students on a share of each task's offline dataset, whole episodes drawn per training seed "
            "(100%: plain MOP). " + _seed_caption(students, labels), ""]


def _label(info: Mapping, levels: Mapping[str, str]) -> str:
    what = _data_label(info["data"], levels)
    if info["percent"] != 100:
        what = f"{info['percent']}% of the {what}"
    correction = "" if _plain(info) else f", {info['correction']}"
    return f"{what}, width {info['width']}{correction}"


def error_lines(metrics: Mapping, tasks: Sequence[str]) -> list[str]:
    groups, students = metrics.get("groups", {}), metrics.get("students", {})
    labels = [label for label in groups if any(students[label][t].get("action_mse") for t in tasks)]
    if not labels:
        return []
    rows = []
    for label in labels:
        for task in tasks:
            errors = students[label][task].get("action_mse", {})
            rows.append([_label(groups[label], metrics.get("pairing_levels", {})), task]
                        + [_interval(errors.get(kind), 3) for kind in ("train", "heldout", "visited")])
    return ["### Where the students go wrong", "",
            table(["students", "task", "on training states", "on held-out episodes", "on states it visits"], rows),
            "", "Action error ||pi_T(s) - pi_S(s, i)||^2 (summed over the 6 action dimensions), mean over each "
            "student's states; mean over the training seeds with a Student-t 95% interval over them. Training "
            "states: the dataset it learned on (a DAgger student's before aggregation); held-out: episodes of the "
            "same data it never saw (a composed dataset's held-out episodes, a dataset share's other episodes; "
            "'-': none); visited: the states its own final-evaluation episodes visit, labelled by the teacher. "
            "Visited >> held-out is the state distribution shift at work: the student is accurate where its data "
            "is and wrong where it goes.", ""]


def correction_lines(metrics: Mapping, tasks: Sequence[str]) -> list[str]:
    corrections, groups, students = metrics.get("corrections") or {}, metrics.get("groups", {}), \
        metrics.get("students", {})
    if not corrections:
        return []
    levels = metrics.get("pairing_levels", {})
    rows = []
    for label, c in corrections.items():
        for row_label in (c["plain"], label):
            rows.append([_label(groups[row_label], levels)] + [_cell(students[row_label], t) for t in tasks]
                        + ([_interval(c[t]["gain"]) for t in tasks] if row_label == label else ["" for _ in tasks]))
    return ["### Correcting the shift: reweighting and DAgger (thesis 5.3)", "",
            table(["students"] + [f"{t}: return [95% CI] (student/teacher)" for t in tasks]
                  + [f"{t}: gain over plain [95% CI]" for t in tasks], rows), "",
            "Each correcting group under the plain students of the same data and width. reweight: states drawn "
            "in proportion to a clipped density ratio p_T/p_D from a classifier of the teacher's held-out visited "
            "states against the dataset's (the thesis's proposal, 5.3; mop_core/distill/corrections.py); dagger: "
            "the student-sampled reference (the students act online between phases of training, the teacher "
            "labels what they visit, the states join their data; same gradient steps, plus online episodes offline "
            "distillation does not have: a reference with online access, not an upper bound; a correction of the "
            "offline states can gain more, as the gains below show where it does). Gain: the return "
            "difference paired by training seed, mean and Student-t 95% interval over the seeds. "
            + _seed_caption(students, [label for label in corrections])] + _weights_caption(corrections, tasks) + [""]


def _weights_caption(corrections: Mapping, tasks: Sequence[str]) -> list[str]:
    parts = [f"{label} {task}: classifier AUC {fmt(w['reweight_auc'], 3)}, effective sample share "
             f"{fmt(w['reweight_ess_unclipped'], 3)} unclipped, {fmt(w['reweight_ess'], 3)} clipped "
             f"({fmt(100 * w['reweight_clipped_share'], 1)}% of states at the clip)"
             for label, c in corrections.items() for task in tasks if (w := c[task].get("reweight"))]
    return ["", "The weights: " + "; ".join(parts) + "."] if parts else []


def shift_section(metrics: Mapping | None, compose: Mapping | None, tasks: Sequence[str], link_prefix: str) -> str:
    """Section 5b: composed datasets, the measured shift, online vs offline, capacity and size."""
    out = ["## 5b. State distribution shift (thesis 5.2)", ""]
    if not metrics or not (metrics.get("shift") or metrics.get("students")):
        return "\n".join(out + [not_run("the state-shift study", "It needs the state_shift section's datasets or "
                                        "data_percents and `dvc repro state_shift`."), ""])
    out += composed_lines(compose) + shift_lines(metrics) + online_lines(metrics, tasks)
    out += capacity_lines(metrics, tasks, link_prefix) + size_lines(metrics, tasks)
    out += error_lines(metrics, tasks) + correction_lines(metrics, tasks)
    return "\n".join(out)
