"""The verdict rule (mop_core.report.verdicts), the findings registry (mop_core.report.findings) and the report's
verdict table (mop_core.report.verdict_section) on synthetic results whose answer is known."""

from __future__ import annotations

from pathlib import Path

import pytest

from mop_core.report.evidence import Evidence
from mop_core.report.findings import FINDINGS, OWN, THESIS, Finding
from mop_core.report.results import StudyResults
from mop_core.report.verdict_section import decide, plain_quote, verdict_record, verdict_section
from mop_core.report.verdicts import (
    ABOVE,
    BELOW,
    CONTRADICTED,
    INCONCLUSIVE,
    REPRODUCED,
    Effect,
    cell_verdict,
    equal_within,
    finding_verdict,
    paired,
    unpaired,
    versus_run,
)
from mop_core.statistics import confidence_interval

THESIS_TEXT = Path(__file__).resolve().parents[2] / "shared" / "reference" / "mop-thesis.txt"
TASKS = ["stand", "walk"]


def _effect(low: float, high: float, n: int = 3) -> Effect:
    return Effect("cell", (low + high) / 2, low, high, n, "training seeds")


@pytest.mark.parametrize("claim", [ABOVE, BELOW])
def test_separated_in_the_claims_direction_reproduces_and_the_opposite_contradicts(claim):
    positive, negative, straddling = _effect(1.0, 3.0), _effect(-3.0, -1.0), _effect(-1.0, 2.0)
    agree, disagree = (positive, negative) if claim is ABOVE else (negative, positive)
    assert cell_verdict(agree, claim)[0] == REPRODUCED
    assert cell_verdict(disagree, claim)[0] == CONTRADICTED
    assert cell_verdict(straddling, claim) == (INCONCLUSIVE, "interval contains 0")


def test_equality_claims_need_the_interval_inside_the_margin():
    claim = equal_within(10.0)
    assert cell_verdict(_effect(-4.0, 6.0), claim)[0] == REPRODUCED
    assert cell_verdict(_effect(12.0, 30.0), claim)[0] == CONTRADICTED
    assert cell_verdict(_effect(-25.0, -11.0), claim)[0] == CONTRADICTED
    assert cell_verdict(_effect(-5.0, 15.0), claim)[0] == INCONCLUSIVE


def test_fewer_than_three_runs_or_a_missing_run_are_inconclusive_and_say_why():
    two = paired("stand", {0: 5.0, 1: 6.0}, {0: 1.0, 1: 2.0})
    assert two.value == pytest.approx(4.0) and not two.decided
    assert cell_verdict(two, ABOVE) == (INCONCLUSIVE, "2 seeds: fewer than 3")
    assert cell_verdict(Effect("expert", None, why="needs expert teachers"), ABOVE) == \
        (INCONCLUSIVE, "needs expert teachers")


def test_a_finding_with_mixed_cells_names_them_and_one_contradicted_cell_contradicts_an_every_cell_claim():
    cells = [Effect("stand", 2.0, 1.0, 3.0, 3, "s"), Effect("walk", 0.5, -1.0, 2.0, 3, "s")]
    assert finding_verdict(cells, ABOVE) == (INCONCLUSIVE, "stand: reproduced; walk: inconclusive")
    cells.append(Effect("run", -2.0, -3.0, -1.0, 3, "s"))
    assert finding_verdict(cells, ABOVE)[0] == CONTRADICTED
    assert finding_verdict(cells, ABOVE, every_cell=False)[0] == INCONCLUSIVE


def test_paired_effects_are_t_intervals_over_the_seeds_differences():
    effect = paired("stand", {0: 10.0, 1: 14.0, 2: 11.0, 3: 99.0}, {0: 8.0, 1: 9.0, 2: 10.0})
    expected = confidence_interval([2.0, 5.0, 1.0])
    assert effect.n == 3 and (effect.value, effect.low, effect.high) == pytest.approx(
        (expected["mean"], expected["ci_low"], expected["ci_high"]))
    assert effect.detectable == pytest.approx((expected["ci_high"] - expected["ci_low"]) / 2)


def test_a_group_against_one_fixed_run_adds_the_runs_episode_noise():
    seeds = {0: 50.0, 1: 52.0, 2: 54.0}
    tight = versus_run("stand", seeds, 40.0, 0.0, 15)
    noisy = versus_run("stand", seeds, 40.0, 30.0, 15)
    assert tight.value == noisy.value == pytest.approx(12.0)
    assert tight.low > 0 and noisy.high - noisy.low > tight.high - tight.low


@pytest.mark.skipif(not THESIS_TEXT.is_file(), reason="shared/reference/mop-thesis.txt is beside the clone in CI")
def test_every_thesis_claim_is_quoted_verbatim_from_its_line():
    lines = THESIS_TEXT.read_text().splitlines()
    for finding in THESIS:
        assert finding.claim in lines[finding.line - 1], finding.key
        assert plain_quote(finding.claim) and "](#page" not in plain_quote(finding.claim)


def test_the_registry_holds_every_finding_once():
    assert list(FINDINGS) == [f.key for f in THESIS + OWN]
    assert all(isinstance(f, Finding) for f in FINDINGS.values()) and all(f.own for f in OWN)
    assert not any(f.own for f in THESIS)


def _entry(seed_means: dict[int, float]) -> dict:
    mean = sum(seed_means.values()) / len(seed_means)
    return {"mean": mean, "seed_means": {str(s): v for s, v in seed_means.items()}, "n": len(seed_means),
            "std": 10.0}


def _results(mse: dict[int, float], q: dict[int, float]) -> StudyResults:
    evaluation = {task: {"student_mse_medium": _entry(mse), "student_q_medium": _entry(q),
                         "student_kl_medium": _entry(q)} for task in TASKS}
    evaluation["normalisation"] = {t: {"random_return": 0.0, "expert_return": 1000.0} for t in TASKS}
    return StudyResults(tasks=TASKS, levels=["medium"], settings={"structure_pairing": "medium", "teacher_seed": 0},
                        pairing_levels={"medium": ["medium", "medium"]}, evaluation=evaluation)


def test_a_finding_is_decided_from_the_runs_results():
    """'MSE performs best': MSE students clearly above Q/KL reproduce it, clearly below contradict it,
    and students within noise of each other leave it inconclusive."""
    finding = [FINDINGS["mse_best_loss"]]
    above = decide(Evidence(_results({0: 600, 1: 610, 2: 620}, {0: 300, 1: 320, 2: 310})), finding)[0]
    below = decide(Evidence(_results({0: 300, 1: 320, 2: 310}, {0: 600, 1: 610, 2: 620})), finding)[0]
    noise = decide(Evidence(_results({0: 300, 1: 600, 2: 450}, {0: 610, 1: 290, 2: 460})), finding)[0]
    assert (above.verdict, below.verdict, noise.verdict) == (REPRODUCED, CONTRADICTED, INCONCLUSIVE)
    assert above.effects[0].value == pytest.approx(30.0)  # normalised points: 100 * 300 / 1000
    assert above.effects[0].unit == "paired training seeds" and above.effects[0].n == 3


def test_two_groups_of_independent_runs_get_a_welch_interval_over_their_seeds():
    from scipy import stats

    x, y = {0: 50.0, 1: 54.0, 2: 52.0}, {0: 40.0, 1: 30.0, 2: 35.0, 3: 39.0}
    effect = unpaired("walk", x, y)
    welch = stats.ttest_ind(list(x.values()), list(y.values()), equal_var=False).confidence_interval()
    assert effect.value == pytest.approx(52.0 - 36.0) and (effect.low, effect.high) == pytest.approx(
        (welch.low, welch.high))
    assert effect.n == 3 and "unpaired" in effect.unit
    assert not unpaired("walk", x, {0: 1.0, 1: 2.0}).decided  # 2 runs on a side: no interval over runs


def test_teacher_findings_use_teacher_seeds_when_a_profile_trains_three():
    """'teachers match their behaviour policy' with 3 teacher seeds: the seeds against the one
    behaviour snapshot (an interval); with 1 seed, two single runs (no interval, inconclusive)."""
    def results(teacher: dict[int, float]) -> StudyResults:
        evaluation = {task: {"teacher_medium_deterministic": _entry(teacher),
                             "behaviour_medium": _entry({0: 600.0}) | {"n": 15}} for task in TASKS}
        evaluation["normalisation"] = {t: {"random_return": 0.0, "expert_return": 1000.0} for t in TASKS}
        return StudyResults(tasks=TASKS, levels=["medium"], settings={"teacher_seed": 0},
                            pairing_levels={"medium": ["medium", "medium"]}, evaluation=evaluation)

    finding = [FINDINGS["teachers_match_behaviour"]]
    three = decide(Evidence(results({0: 601.0, 1: 599.0, 2: 600.5})), finding)[0]
    one = decide(Evidence(results({0: 601.0})), finding)[0]
    assert three.verdict == REPRODUCED and three.effects[0].decided and three.effects[0].n == 3
    assert one.verdict == INCONCLUSIVE and not one.effects[0].decided


def test_one_multitask_run_against_three_teacher_seeds_is_the_teachers_interval_turned_around():
    evaluation = {task: {"teacher_medium_deterministic": _entry({0: 600.0, 1: 610.0, 2: 605.0}),
                         "multitask_medium": _entry({0: 200.0}) | {"n": 15}} for task in TASKS}
    evaluation["normalisation"] = {t: {"random_return": 0.0, "expert_return": 1000.0} for t in TASKS}
    results = StudyResults(tasks=TASKS, levels=["medium"], settings={"teacher_seed": 0},
                           pairing_levels={"medium": ["medium", "medium"]}, evaluation=evaluation)
    verdict = decide(Evidence(results), [FINDINGS["multitask_fails"]])[0]
    effect = verdict.effects[0]
    assert verdict.verdict == REPRODUCED and effect.value == pytest.approx(-40.5) and effect.high < 0


def test_every_finding_runs_on_an_empty_run_and_the_table_says_why_nothing_is_decided():
    decisions = decide(Evidence(StudyResults(tasks=TASKS, levels=["medium"], settings={})))
    assert len(decisions) == len(FINDINGS) and {d.verdict for d in decisions} == {INCONCLUSIVE}
    section = verdict_section(decisions)
    assert section.startswith("## Verdicts") and "it reproduces 0" in section
    record = verdict_record(decisions)
    assert record["thesis_findings"] == {REPRODUCED: 0, CONTRADICTED: 0, INCONCLUSIVE: len(THESIS)}


def _shared(taus: dict[str, list[float]]) -> dict:
    """shared_computation's record: per pairing, MSE students (one per seed) with an average tau-a."""
    groups, students = {}, {}
    for pairing, values in taus.items():
        members = [f"mse-{pairing}-{seed}" for seed in range(len(values))]
        groups[f"mse_{pairing}"] = {"members": members, "pairs": {"stand-walk": {"layer1": {}}}}
        students |= {m: {"pairs": {"stand-walk": {"layer1": {"average_tau_a": v}}}} for m, v in zip(members, values)}
    return {"groups": groups, "students": students}


def test_expert_shares_most_compares_the_expert_pairings_tau_with_every_other_single_level_pairing():
    pairings = {"expert": ["expert"] * 2, "medium": ["medium"] * 2, "medium_replay": ["medium_replay"] * 2,
                "expert+medium": ["expert", "medium"]}
    shared = _shared({"expert": [0.30, 0.32, 0.31], "medium": [0.10, 0.12, 0.11], "medium_replay": [0.2, 0.21, 0.22]})
    results = StudyResults(tasks=TASKS, levels=["expert", "medium", "medium_replay"],
                           settings={"structure_pairing": "medium"}, pairing_levels=pairings, shared=shared)
    verdict = decide(Evidence(results), [FINDINGS["expert_shares_most"]])[0]
    assert [e.label for e in verdict.effects] == ["expert - medium, layer 1", "expert - medium_replay, layer 1"]
    assert verdict.verdict == REPRODUCED and verdict.effects[0].value == pytest.approx(0.2)
    medium_only = StudyResults(tasks=TASKS, levels=["medium"], settings={}, pairing_levels={"medium": ["medium"] * 2})
    assert decide(Evidence(medium_only), [FINDINGS["expert_shares_most"]])[0].verdict == INCONCLUSIVE


def test_the_medium_replay_finding_reads_the_medium_replay_students_and_teacher_on_walk():
    evaluation = {task: {"student_mse_medium_replay": _entry({0: 500, 1: 510, 2: 505}),
                         "teacher_medium_replay_deterministic": _entry({0: 700}) | {"n": 15, "std": 5.0},
                         "student_mse_medium": _entry({0: 700, 1: 710, 2: 705}),
                         "teacher_medium_deterministic": _entry({0: 700}) | {"n": 15, "std": 5.0}} for task in TASKS}
    evaluation["normalisation"] = {t: {"random_return": 0.0, "expert_return": 1000.0} for t in TASKS}
    results = StudyResults(tasks=TASKS, levels=["medium", "medium_replay"], settings={"structure_pairing": "medium"},
                           pairing_levels={"medium": ["medium"] * 2, "medium_replay": ["medium_replay"] * 2},
                           evaluation=evaluation)
    verdict = decide(Evidence(results), [FINDINGS["medium_replay_walk_short"]])[0]
    assert verdict.verdict == REPRODUCED and [e.label for e in verdict.effects] == ["walk"]
    assert verdict.effects[0].value == pytest.approx(-19.5)  # (505 - 700) / 1000 * 100


def test_teachers_hold_their_level_is_decided_per_task_and_level_over_teacher_seeds():
    """The teacher bar (>= 0.9 of the dataset's return): 3 seeds well above it reproduce, one level
    below it contradicts the whole finding, one seed is no interval."""
    from mop_core.report.results import Run

    def results(ratios: dict[tuple[str, str], list[float]]) -> StudyResults:
        runs = [Run({"task": task, "level": level, "actor": "deterministic"}, seed, {"return_ratio": r}, [])
                for (task, level), values in ratios.items() for seed, r in enumerate(values)]
        runs.append(Run({"task": "stand", "level": "expert", "actor": "gaussian"}, 0, {"return_ratio": 0.1}, []))
        return StudyResults(tasks=TASKS, levels=["expert", "medium"], settings={}, teachers=runs)

    good = {(t, lv): [0.98, 1.01, 0.99] for t in TASKS for lv in ("expert", "medium")}
    finding = [FINDINGS["teachers_hold_level"]]
    held = decide(Evidence(results(good)), finding)[0]
    assert held.verdict == REPRODUCED and len(held.effects) == 4 and all(e.n == 3 for e in held.effects)
    assert held.effects[0].value == pytest.approx((0.98 + 1.01 + 0.99) / 3 - 0.9)  # the Gaussian teacher is not read
    failed = decide(Evidence(results(good | {("walk", "expert"): [0.55, 0.6, 0.5]})), finding)[0]
    assert failed.verdict == CONTRADICTED
    one_seed = decide(Evidence(results({(t, "medium"): [0.99] for t in TASKS})), finding)[0]
    assert one_seed.verdict == INCONCLUSIVE


def test_teachers_plateau_compares_the_last_quarter_of_each_curve_with_the_third():
    """A curve flat over its second half reproduces the plateau; one still rising by 0.3 dataset
    returns contradicts it (the fixed step budget stopped a climbing teacher)."""
    from mop_core.report.results import Run

    def run(seed: int, late: float) -> Run:
        curve = [{"step": str(s), "return_mean": str(r)} for s, r in
                 ((5000, 300.0), (10000, 500.0), (12500, 500.0), (15000, 500.0), (17500, 500.0 + late),
                                  (20000, 500.0 + late))]
        return Run({"task": "stand", "level": "medium", "actor": "deterministic"}, seed,
                   {"gradient_steps": 20000, "dataset_return_mean": 500.0}, curve)

    def verdict(lates: list[float]):
        results = StudyResults(tasks=["stand"], levels=["medium"], settings={},
                               teachers=[run(s, late) for s, late in enumerate(lates)])
        return decide(Evidence(results), [FINDINGS["teachers_plateau"]])[0]

    flat = verdict([2.0, -3.0, 1.0])
    assert flat.verdict == REPRODUCED and flat.effects[0].n == 3
    climbing = verdict([150.0, 160.0, 140.0])  # last quarter (15k, 20k]: +0.3 dataset returns over (10k, 15k]
    assert climbing.verdict == CONTRADICTED
    assert climbing.effects[0].value == pytest.approx((150 + 160 + 140) / 3 / 500.0)
