"""The findings the report decides: every testable claim of the thesis (chapters 5.1, 5.2, 6.2, 6.3,
6.4 and Table 6.3) and this study's own, each a typed :class:`Finding` registered in one table.

A finding quotes its claim (the thesis's words, with the line of shared/reference/mop-thesis.txt it
stands on), says which statistic tests it, in which direction (:class:`mop_core.report.verdicts.Claim`), and
measures it on a run (:class:`mop_core.report.evidence.Evidence` -> :class:`mop_core.report.verdicts.Effect` cells);
mop_core.report.verdicts turns the cells into reproduced / contradicted / inconclusive. Returns are in
normalised points (100 = published expert, 0 = random); a "matches" claim holds within
:data:`RETURN_MARGIN` points, a tau equality within :data:`TAU_MARGIN`.

Adding a finding: write its measure (a function of Evidence returning Effects) and ``register`` it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from mop_core.report.evidence import Evidence
from mop_core.report.measures import (
    MOP,
    at_pairing,
    best_teacher,
    cross_task_walk_teacher,
    ds_teacher,
    gaussian_teacher,
    joined,
    labelled,
    mop_teacher,
    noise_vs_online_small,
    online_vs_offline,
    online_within_null,
    oqs_teacher,
    pairing_tau_vs_others,
    random90_at_512,
    random_vs_teacher_data,
    ranking_measure,
    sc_tau_vs,
    sc_tau_vs_thesis,
    shift_rank_correlation,
    student_vs_student,
    student_vs_teacher,
    substitute_sharing_tau,
    teacher_vs_teacher,
    teachers_late_gain,
    teachers_reach,
    untrained_minus,
    width_measure,
)
from mop_core.report.verdicts import (
    ABOVE,
    BELOW,
    Claim,
    Effect,
    equal_within,
    not_run,
    paired,
)

TEACHER_RATIO = 0.9  # a teacher holds its level: >= 0.9 of its dataset's mean return
PLATEAU_MARGIN = 0.1  # a teacher's curve has plateaued: its last quarter within 0.1 dataset returns of its third
RETURN_MARGIN = 10.0  # normalised points: "matches" = within 10% of the expert-random range
TAU_MARGIN = 0.1  # Kendall tau: "a level similar to", "0.067" = within 0.1


@dataclass(frozen=True)
class Finding:
    """One claim and how this study tests it."""

    key: str
    section: str  # thesis section / figure / table ("this run" for the study's own findings)
    claim: str  # quoted: the thesis's words, or this study's statement
    line: int | None  # the claim's line in shared/reference/mop-thesis.txt (None: the study's own)
    statistic: str  # what is measured, in words (the effect's sign convention)
    expects: Claim
    measure: Callable[[Evidence], list[Effect]]
    every_cell: bool = True  # the claim holds on every cell (task, layer): one contradicted cell contradicts it
    levels: tuple[str, ...] = ("medium",)  # the dataset levels it needs

    @property
    def own(self) -> bool:
        return self.line is None


FINDINGS: dict[str, Finding] = {}


def register(finding: Finding) -> Finding:
    if finding.key in FINDINGS:
        raise ValueError(f"finding {finding.key!r} is registered twice")
    FINDINGS[finding.key] = finding
    return finding


# ---- measures -----------------------------------------------------------------------------------


# ---- the thesis's findings, in its order ---------------------------------------------------------------
BEHAVIOUR = "behaviour_medium"
THESIS: list[Finding] = [
    Finding("teachers_match_behaviour", "5.1.1, Figure 5.1",
            "The resulting policies closely match or slightly exceed the performance of their corresponding "
            "behavior policies.", 365, "teacher - behaviour policy (medium)", equal_within(RETURN_MARGIN),
            teacher_vs_teacher(mop_teacher, lambda ev, t: BEHAVIOUR)),
    Finding("multitask_fails", "5.1.2, Figure 5.3",
            "We conclude that introducing a multi-task actor prevents the agent to effectively learn either task.",
            379, "naive multi-task PBRL - single-task teacher", BELOW,
            teacher_vs_teacher(lambda ev, t: f"multitask_{ev.level(t)}", mop_teacher)),
    Finding("stochastic_teachers_worse", "5.1.3, Figure 5.4",
            "The stochastic teachers perform worse than the deterministic ones.", 449,
            "Gaussian teacher - deterministic teacher", BELOW, teacher_vs_teacher(gaussian_teacher, mop_teacher)),
    Finding("mse_best_loss", "5.1.3, Figure 5.4",
            "Experiments in the Walker environment indicate that, somewhat surprisingly, the MSE loss performs best.",
            447, "MSE students - Q / KL students (mean over tasks, paired by seed)", ABOVE,
            joined(labelled("vs Q", student_vs_student(MOP, MOP, False, losses=("mse", "q"))),
                   labelled("vs KL", student_vs_student(MOP, MOP, False, losses=("mse", "kl"))))),
    Finding("mse_matches_teacher", "5.1.3, Figure 5.4",
            "MSE matches the teachers' performance, whereas the Q-value loss yields slightly lower values.", 451,
            "MSE students - their teacher run", equal_within(RETURN_MARGIN),
            student_vs_teacher(MOP, mop_teacher)),
    Finding("q_below_mse", "5.1.3, Figure 5.4",
            "MSE matches the teachers' performance, whereas the Q-value loss yields slightly lower values.", 451,
            "Q students - MSE students (paired by seed)", BELOW, student_vs_student(MOP, MOP, losses=("q", "mse"))),
    Finding("kl_fails_walk", "5.1.3, Figure 5.4",
            "It fails to match teacher performance, particularly in the walking task.", 453,
            "KL students - their Gaussian teacher run", BELOW, student_vs_teacher(MOP, gaussian_teacher, "kl"),
            every_cell=False),
    Finding("medium_replay_walk_short", "5.2, Figure 5.5",
            "However, the approach falls slightly short on the walking task with the medium-replay dataset", 459,
            "MSE students - teacher run on walk (medium_replay)", BELOW,
            at_pairing("medium_replay", student_vs_teacher(MOP, mop_teacher, tasks=("walk",))),
            levels=("medium_replay",)),
    Finding("online_not_better", "5.2.3, Figure 5.7",
            "Contrary to expectations, online PD does not outperform offline PD in this setting.", 499,
            "students on online states - on the offline dataset (distill width; thesis: medium-replay)",
            equal_within(RETURN_MARGIN), online_vs_offline),
    Finding("random_least_robust_small", "5.2.4, Figure 5.8",
            "The Random90 and Random99 datasets are the least robust to smaller network sizes, which aligns with "
            "our initial expectations.", 526,
            "smallest width: mean of random90/random99 students - mean of online/noise students", BELOW,
            random_vs_teacher_data),
    Finding("noise_most_robust_small", "5.2.4, Figure 5.8",
            "Remarkably, the Noise dataset appears to be the most robust to smaller networks.", 528,
            "smallest width: noise students - online students", ABOVE, noise_vs_online_small),
    Finding("random90_near_teacher_512", "5.2.4, Figure 5.8",
            "Random90 nearly matches teacher performance for the largest network, which has 512 neurons per hidden "
            "layer.", 530, "width 512 random90 students - their teacher run", equal_within(RETURN_MARGIN),
            random90_at_512),
    Finding("hypothesis_1", "5.2.4 (Hypothesis 1)",
            "The hypothesis holds in that student performance generally declines when the network size is small "
            "and the distribution shift is large.", 550,
            "Spearman rho(measured KL(teacher || data), student return) over the datasets, per seed", BELOW,
            shift_rank_correlation),
    Finding("per_state_above_average", "6.2.3, Table 6.1",
            "The similarity for per-state activations is significantly higher than for average activations.", 692,
            "MOP students: per-state tau-a - average tau-a (each student with itself)", ABOVE,
            lambda ev: [paired(f"layer {layer}", ev.sc_tau(ev.structure(), layer, "per_state_tau_a"),
                               ev.sc_tau(ev.structure(), layer, "average_tau_a"), "training seeds (paired)")
                        for layer in ev.layers()]),
    Finding("layer_order_reverses", "6.2.3, Table 6.1",
            "Furthermore, the per-state activations indicate more sharing in the first layer than in the second "
            "layer, whereas for the average activations, this is reversed.", 692,
            "MOP students: per-state tau layer 1 - layer 2; average tau layer 2 - layer 1", ABOVE,
            lambda ev: [paired("per-state L1 - L2", ev.sc_tau(ev.structure(), 1, "per_state_tau_a"),
                               ev.sc_tau(ev.structure(), 2, "per_state_tau_a"), "training seeds (paired)"),
                        paired("average L2 - L1", ev.sc_tau(ev.structure(), 2), ev.sc_tau(ev.structure(), 1),
                               "training seeds (paired)")]),
    Finding("expert_shares_most", "6.2.3, Table 6.1",
            "The results show that Expert X Expert shares the most.", 696,
            "expert students' average tau - each other single-level pairing's (paired by seed)", ABOVE,
            pairing_tau_vs_others("expert"), levels=("expert", "medium")),
    Finding("width_degrades_return", "6.3.1, Figure 6.4",
            "As the network size decreases, both performance and shared computation gradually degrade.", 740,
            "smallest-width students - plain students (normalised return, paired by seed)", BELOW,
            width_measure("return")),
    Finding("width_degrades_tau", "6.3.1, Figure 6.4",
            "As the network size decreases, both performance and shared computation gradually degrade.", 740,
            "smallest-width students - plain students (per-state tau-a on probe states)", BELOW,
            width_measure("tau")),
    Finding("pairwise_highest_tau", "6.3.2, Figure 6.5",
            "The pairwise loss achieves the highest Kendall's τ , but this comes at a significant cost to "
            "performance.", 789, "pairwise-ranking students - plain students (per-state tau-a on probe states)",
            ABOVE, ranking_measure("pairwise", "tau")),
    Finding("pairwise_costs_return", "6.3.2, Figure 6.5",
            "The pairwise loss achieves the highest Kendall's τ , but this comes at a significant cost to "
            "performance.", 789, "pairwise-ranking students - plain students (return, mean over tasks)", BELOW,
            ranking_measure("pairwise", "return", per_task=False)),
    Finding("ndcg_no_effect", "6.3.2, Figure 6.5",
            "The NDCG loss shows results almost identical to those with no regularization in both episode reward "
            "and Kendall's τ .", 791, "approx-NDCG students - plain students (return, mean over tasks)",
            equal_within(RETURN_MARGIN), ranking_measure("approx_ndcg", "return", per_task=False)),
    Finding("listwise_raises_layer1_tau", "6.3.2, Figure 6.5",
            "Lastly, the listwise loss maintains the same performance while significantly improving Kendall's τ in "
            "the first layer.", 799, "listwise students - plain students (per-state tau-a, layer 1)", ABOVE,
            ranking_measure("listwise", "tau", (1,))),
    Finding("listwise_keeps_return", "6.3.2, Figure 6.5",
            "Lastly, the listwise loss maintains the same performance while significantly improving Kendall's τ in "
            "the first layer.", 799, "listwise students - plain students (return per task)",
            equal_within(RETURN_MARGIN), ranking_measure("listwise", "return")),
    Finding("listwise_layer2_at_baseline", "6.3.2, Figure 6.5",
            "However, in the second layer, the shared computation decreases, averaging out to a level similar to "
            "that with no regularization.", 799, "listwise students - plain students (per-state tau-a, layer 2)",
            equal_within(TAU_MARGIN), ranking_measure("listwise", "tau", (2,))),
    Finding("ds_teacher_better_on_stand", "6.4.4, Figure 6.9a",
            "The teacher improves upon MOP in the standing task and matches its performance in the walking task.",
            915, "DS teacher - MOP teacher on stand", ABOVE, teacher_vs_teacher(ds_teacher, mop_teacher, ("stand",))),
    Finding("ds_teacher_matches_on_walk", "6.4.4, Figure 6.9a",
            "The teacher improves upon MOP in the standing task and matches its performance in the walking task.",
            915, "DS teacher - MOP teacher on walk", equal_within(RETURN_MARGIN),
            teacher_vs_teacher(ds_teacher, mop_teacher, ("walk",))),
    Finding("ds_student_replicates_teacher", "6.4.4, Figure 6.9a",
            "The student successfully replicates this behavior, achieving the best performance compared to both "
            "MOP and OQS across both tasks.", 915, "DS students - their DS teacher run",
            equal_within(RETURN_MARGIN), lambda ev: student_vs_teacher(ev.sharing("ds"), ds_teacher)(ev)),
    Finding("ds_student_best", "6.4.4, Figure 6.9a",
            "The student successfully replicates this behavior, achieving the best performance compared to both "
            "MOP and OQS across both tasks.", 915, "DS students - MOP / OQS students (per task, paired by seed)",
            ABOVE, lambda ev: joined(labelled("vs MOP", student_vs_student(ev.sharing("ds"), MOP)),
                                     labelled("vs OQS", student_vs_student(ev.sharing("ds"),
                                                                           ev.sharing("oqs", "own"))))(ev)),
    Finding("ds_raises_tau", "6.4.4, Table 6.2",
            "Additionally, shared computation improves significantly compared to MOP", 915,
            "DS students - MOP students (average tau-a, Table 6.2's measure)", ABOVE,
            lambda ev: sc_tau_vs(ev.sharing("ds"), MOP)(ev)),
    Finding("oqs_highest_tau", "6.4.4, Table 6.2",
            "In terms of shared computation, as shown in Table [6.2,](#page-49-1) OQS performs the best.", 945,
            "OQS students - DS / MOP students (average tau-a)", ABOVE,
            lambda ev: joined(labelled("vs DS", sc_tau_vs(ev.sharing("oqs", "own"), ev.sharing("ds"))),
                              labelled("vs MOP", sc_tau_vs(ev.sharing("oqs", "own"), MOP)))(ev)),
    Finding("table_6_2_mop", "Table 6.2 (Medium X Medium, MOP)", "Medium X Medium	MOP	0.067	0.15", 930,
            "MOP students' average tau-a - the thesis's value", equal_within(TAU_MARGIN),
            sc_tau_vs_thesis(MOP, (0.067, 0.15))),
    Finding("table_6_2_ds", "Table 6.2 (Medium X Medium, DS)", "	DS	0.52	0.67", 931,
            "DS students' average tau-a - the thesis's value", equal_within(TAU_MARGIN),
            lambda ev: sc_tau_vs_thesis(ev.sharing("ds"), (0.52, 0.67))(ev)),
    Finding("table_6_2_oqs", "Table 6.2 (Medium X Medium, OQS)", "	OOS	0.68	0.76", 932,
            "OQS students' average tau-a - the thesis's value", equal_within(TAU_MARGIN),
            lambda ev: sc_tau_vs_thesis(ev.sharing("oqs", "own"), (0.68, 0.76))(ev)),
    Finding("oqs_data_teacher_stands", "6.4.4, Figure 6.9a",
            "In the standing task, the cross-task teachers outperform or match the original teachers", 941,
            "stand's teacher on walk's data - stand's MOP teacher", ABOVE,
            teacher_vs_teacher(oqs_teacher, mop_teacher, ("stand",))),
    Finding("oqs_data_teacher_walks_poorly", "6.4.4, Figure 6.9a",
            "However, in the walking task, the cross-task teachers perform poorly (the right bar is lower than the "
            "left bar).", 941, "walk's teacher on stand's data - walk's MOP teacher", BELOW,
            teacher_vs_teacher(oqs_teacher, mop_teacher, ("walk",))),
    Finding("oqs_student_below_best_teacher", "6.4.4, Figure 6.9a",
            "Contrary to these expectations, the OQS student always performs worse than its best teacher.", 943,
            "OQS students - the better of the task's MOP and OQS teacher runs", BELOW,
            lambda ev: student_vs_teacher(ev.sharing("oqs", "own"), best_teacher)(ev)),
    Finding("oqs_student_worse", "6.5",
            "While it showed improved shared computation, the overall student performance decreased.", 973,
            "OQS students - MOP students (mean over tasks, paired by seed)", BELOW,
            lambda ev: student_vs_student(ev.sharing("oqs", "own"), MOP, per_task=False)(ev)),
    Finding("ds_degrades_expert", "6.4.4, Figure 6.9b",
            "However, in the Expert X Expert setting (Figure [6.9b\\)](#page-49-0), DS significantly degrades "
            "teacher performance compared to MOP in both tasks.", 917, "DS teacher - MOP teacher (expert)", BELOW,
            at_pairing("expert", teacher_vs_teacher(ds_teacher, mop_teacher)), levels=("expert",)),
    Finding("walk_teacher_best_on_both", "6.4.5, Table 6.3",
            "indicate that the walk teacher performs better in both tasks for all offline datasets.", 951,
            "walk's teacher on each task's reward - that task's own teacher", ABOVE, cross_task_walk_teacher),
]

# ---- this run's own findings --------------------------------------------------------------------------
OWN: list[Finding] = [
    Finding("teachers_hold_level", "this run",
            f"Every deterministic PBRL teacher reaches at least {TEACHER_RATIO} of its dataset's mean return, on "
            "every task and level.", None,
            f"teacher return / dataset return - {TEACHER_RATIO} (the teacher's final evaluation)", ABOVE,
            teachers_reach(TEACHER_RATIO)),
    Finding("teachers_plateau", "this run",
            "The teachers' step budget reaches a plateau: no deterministic teacher's learning curve still rises "
            "or falls over its last quarter of gradient steps.", None,
            "mean curve return over the last quarter of steps - over the third quarter, in dataset returns",
            equal_within(PLATEAU_MARGIN), teachers_late_gain),
    Finding("training_lowers_tau", "this run",
            "Distillation lowers per-state tau: every plain MOP student ends below its own value at initialisation.",
            None, "plain students: final - initial per-state tau-a on the probe states", BELOW, untrained_minus),
    Finding("substitute_sharing_lowers_tau", "this run",
            "On {stand_still, walk}, DS and OQS students share less than MOP's, not more.", None,
            "DS / OQS students - MOP students on the substitute set (per-state tau-a)", BELOW,
            substitute_sharing_tau),
    Finding("single_task_beats_mop_on_stand", "this run",
            "On stand, students distilled on stand alone beat the multi-task MOP students.", None,
            "single-task students - MOP students on stand (paired by seed)", ABOVE,
            lambda ev: student_vs_student(ev.single("stand"), MOP, tasks=("stand",))(ev)
            if "stand" in ev.settings.get("single_task", []) else [not_run("stand", "no single-task students")]),
    Finding("online_within_null", "this run",
            "The online dataset (the teacher's own rollouts) shows no shift: its KL reads above the episode-split "
            "null no more often than a coin flip.", None,
            "share of episode-halves with KL(teacher || online) above the paired null, minus 1/2",
            equal_within(0.4), online_within_null),
]

for _finding in THESIS + OWN:
    register(_finding)
