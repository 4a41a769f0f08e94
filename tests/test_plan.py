"""mop_core.plan: a profile's cost from measured rates (the catalogue's runs), and shortened profiles
that still
run."""

from __future__ import annotations

import pytest
import yaml
from conftest import ROOT

from mop_core.experiment.catalogue import build_catalogue
from mop_core.experiment.study import shift_grid, study_config
from mop_core.plan import STUDENT_STAGES, Rates, one_level_grid, plan_table, scaled_profile, stage_hours
from mop_core.shift.compose import compose_config
from mop_core.study_params import check_params

THESIS = yaml.safe_load((ROOT / "profiles" / "thesis.yaml").read_text())
RATES = Rates(device="test", td3=100.0, pbrl={"deterministic": 50.0, "gaussian": 40.0},
              student={"mse": {1: 200.0, 8: 100.0}, "q": {1: 100.0, 8: 40.0}}, rollout=5000.0, single_env=2000.0)


def test_student_group_cost_is_interpolated_between_the_measured_sizes():
    assert RATES.student_seconds_per_update("mse", 1) == pytest.approx(1 / 200)
    assert RATES.student_seconds_per_update("mse", 8) == pytest.approx(1 / 100)
    four = RATES.student_seconds_per_update("mse", 4)
    assert 1 / 200 < four < 1 / 100 and four == pytest.approx(1 / 200 + (1 / 100 - 1 / 200) * 3 / 7)
    assert RATES.student_seconds_per_update("kl", 8) == RATES.student_seconds_per_update("mse", 8)
    assert RATES.student_seconds_per_update("q", 16) == pytest.approx(16 / 8 / 40)  # linear beyond


def test_teacher_hours_are_runs_times_updates_over_the_rate_plus_their_rollouts():
    hours = stage_hours(THESIS, RATES)
    teachers = THESIS["train_teachers"]
    runs = len(THESIS["study"]["tasks"]) * len(THESIS["study"]["levels"]) * len(teachers["seeds"])
    steps, sched = teachers["schedule"]["steps"], teachers["schedule"]
    rollout = 1000 * (steps // sched["eval_every"] * sched["eval_episodes"] + sched["final_eval_episodes"]) / 5000.0
    expected = runs * (steps / 50.0 + rollout + steps / 40.0 + rollout) / 3600
    assert hours["train_teachers"] == (2 * runs, pytest.approx(expected))
    doubled = stage_hours(THESIS, Rates(**{**RATES.__dict__, "pbrl": {"deterministic": 100.0, "gaussian": 80.0},
                                         "rollout": 1e12}))
    assert doubled["train_teachers"][1] < hours["train_teachers"][1] / 2  # faster updates, free rollouts


def test_teacher_steps_per_level_cost_each_level_its_own_steps():
    steps = THESIS["train_teachers"]["schedule"]["steps"]
    per_level = {level: steps for level in THESIS["study"]["levels"]} | {"expert": 2 * steps}
    params = {**THESIS, "train_teachers": {**THESIS["train_teachers"],
                                           "schedule": {**THESIS["train_teachers"]["schedule"], "steps": per_level}}}
    levels = len(THESIS["study"]["levels"])
    one, two = stage_hours(THESIS, RATES)["train_teachers"][1], stage_hours(params, RATES)["train_teachers"][1]
    assert two > one and two < one * (levels + 1) / levels + 1e-9  # the expert third costs up to twice
    short = scaled_profile(params, 0.001)
    assert short["train_teachers"]["schedule"]["steps"]["expert"] == 2 * short["train_teachers"]["schedule"]["steps"][
        "medium"]
    check_params(short)


@pytest.mark.parametrize("fraction", [0.001, 0.0001])
def test_a_shortened_thesis_profile_passes_the_params_check_and_keeps_the_grid(fraction):
    short = scaled_profile(THESIS, fraction)
    check_params(short)  # every cross-check (batch sizes vs data, medium before expert) holds
    assert short["train_teachers"]["schedule"]["steps"] == max(10, round(1_000_000 * fraction))
    assert short["train_teachers"]["pbrl"]["hidden_sizes"] == THESIS["train_teachers"]["pbrl"]["hidden_sizes"]
    assert short["distill"]["seeds"] == THESIS["distill"]["seeds"]
    one = one_level_grid(scaled_profile(THESIS, fraction, max_evaluations=2))
    check_params(one)
    for schedule in (one["train_teachers"]["schedule"], one["distill"]["schedule"]):
        assert schedule["steps"] // schedule["eval_every"] <= 2
    assert one["study"]["levels"] == [THESIS["study"]["levels"][0]] and one["train_teachers"]["seeds"] == [0]
    assert one["distill"]["pairings"] == [THESIS["study"]["levels"][0]]
    assert stage_hours(one, RATES)["distill"][0] == 3 * len(THESIS["distill"]["seeds"])


def test_the_runs_counted_are_the_catalogues_and_the_stages():
    hours, catalogue = stage_hours(THESIS, RATES), build_catalogue(THESIS)
    assert hours["train_relabelled_teachers"][0] == len(catalogue.relabelled_teachers) == 14
    assert hours["distill"][0] == len(catalogue.mop_students())
    assert sum(hours[stage][0] for stage in STUDENT_STAGES) == len(catalogue.students + catalogue.shift_students)
    assert hours["distill_substitute"][0] == len(catalogue.substitute_students())
    assert hours["shared_computation"][0] == len(catalogue.students)
    # every eval job, the deterministic teachers on the transfer tasks included (3 levels x 2 tasks x stand_still)
    assert hours["eval"][0] == len(catalogue.eval_jobs(transfer_tasks=("stand_still",))) == 878 + 6


def test_compose_costs_the_pools_compose_rolls_out():
    config = compose_config(shift_grid(THESIS, study_config(THESIS)))
    # per task: the largest pools its datasets need, and their held-out sets' (1000 + 900 + 990, 100 + 90 + 99)
    episodes = 2890 + 289 + config.reference_episodes
    assert sum(config.pool_sizes().values()) + sum(config.pool_sizes(heldout=True).values()) == 2890 + 289
    assert THESIS["state_shift"]["workers"] == "auto"  # the measured machine's cores
    waves = -(-len(THESIS["study"]["tasks"]) // RATES.cores)
    assert stage_hours(THESIS, RATES)["compose"] == (
        8, pytest.approx(waves * episodes * THESIS["study"]["episode_length"] / 5000.0 / 3600))


def test_rollouts_over_every_core_cost_eval_and_shared_computation_their_all_core_rate():
    one = stage_hours(THESIS, RATES)  # a rates file without the all-cores rate: one process's
    spread = Rates(**{**RATES.__dict__, "parallel_rollout": 4 * RATES.rollout, "cores": 16})
    hours = stage_hours(THESIS, spread)
    assert THESIS["eval"]["workers"] == THESIS["shared_computation"]["workers"] == "auto"
    for stage in ("eval", "shared_computation"):
        assert hours[stage][1] == pytest.approx(one[stage][1] / 4)
    assert hours["train_teachers"] == one["train_teachers"]  # a teacher's evaluations: one process
    fixed = {**THESIS, "eval": {**THESIS["eval"], "workers": 2}}
    assert stage_hours(fixed, spread)["eval"][1] == pytest.approx(one["eval"][1])  # 2 of 16 cores: not spread
    record = {"machine": {}, "device": "cpu", "td3_updates_per_second": 1, "pbrl_updates_per_second": {},
              "student_group_updates_per_second": {}, "rollout_control_steps_per_second": 10,
              "single_env_control_steps_per_second": 5}
    assert Rates.from_json(record).parallel_rollout is None  # an older rates file
    assert Rates.from_json(record | {"parallel_rollout_control_steps_per_second": 80,
                                     "parallel_rollout_workers": 16}).rollout_over("auto") == 80


def test_a_plan_from_tf32_rates_says_so_in_its_heading():
    """bench_rates.py --tf32 measures what TF32 buys: a plan whose rates ran in another precision than the
    profile's study.cuda_matmul must not read as the profile's cost."""
    record = {"machine": {"gpu": "H200"}, "device": "cuda", "td3_updates_per_second": 100,
              "pbrl_updates_per_second": {"deterministic": 50.0, "gaussian": 40.0},
              "student_group_updates_per_second": {"mse": {"1": 200.0, "8": 100.0}, "q": {"1": 100.0, "8": 40.0}},
              "rollout_control_steps_per_second": 1000, "single_env_control_steps_per_second": 100}
    fp32, tf32 = Rates.from_json(record | {"tf32": False}), Rates.from_json(record | {"tf32": True})
    assert not Rates.from_json(record).tf32  # rates files before the flag: fp32
    assert THESIS["study"]["cuda_matmul"] == "fp32"
    heading = plan_table(THESIS, tf32).splitlines()[0]
    assert "TF32, not the FP32 this profile runs (study.cuda_matmul)" in heading
    assert "TF32" not in plan_table(THESIS, fp32).splitlines()[0]
    assert plan_table(THESIS, tf32).splitlines()[1:] == plan_table(THESIS, fp32).splitlines()[1:]
    in_tf32 = {**THESIS, "study": {**THESIS["study"], "cuda_matmul": "tf32"}}  # a profile that asks for TF32
    assert plan_table(in_tf32, tf32).splitlines()[0].endswith("; CUDA matmuls in TF32 (study.cuda_matmul), as "
                                                              "the rates ran):")
    assert "FP32, not the TF32 this profile runs" in plan_table(in_tf32, fp32).splitlines()[0]
    on_cpu = Rates.from_json(record | {"device": "cpu", "machine": {}})  # TF32 does nothing on a CPU
    assert on_cpu.device == "cpu" and "TF32" not in plan_table(in_tf32, on_cpu).splitlines()[0]


def test_a_teacher_entry_costs_its_vectorised_group_and_the_baseline_its_own_rate():
    grouped = Rates(**{**RATES.__dict__, "pbrl_group": {"deterministic": {1: 60.0, 8: 30.0},
                                                       "gaussian": {1: 50.0, 8: 20.0}}, "multitask": 75.0})
    assert grouped.teacher_seconds_per_update("deterministic", 8) == pytest.approx(1 / 30)
    assert grouped.teacher_seconds_per_update("gaussian", 4) == pytest.approx(1 / 50 + (1 / 20 - 1 / 50) * 3 / 7)
    assert RATES.teacher_seconds_per_update("gaussian", 6) == pytest.approx(6 / 40)  # no group rates: R singles
    teachers = THESIS["train_teachers"]
    runs = len(THESIS["study"]["tasks"]) * len(teachers["seeds"])  # one entry per (level, actor)
    steps, sched = teachers["schedule"]["steps"], teachers["schedule"]
    rollout = 1000 * (steps // sched["eval_every"] * sched["eval_episodes"] + sched["final_eval_episodes"]) / 5000.0
    per_level = (steps * grouped.teacher_seconds_per_update("deterministic", runs) + runs * rollout
                 + steps * grouped.teacher_seconds_per_update("gaussian", runs) + runs * rollout)
    hours, plain = stage_hours(THESIS, grouped), stage_hours(THESIS, RATES)
    assert hours["train_teachers"] == (2 * runs * len(THESIS["study"]["levels"]),
                                       pytest.approx(len(THESIS["study"]["levels"]) * per_level / 3600))
    # the multi-task baseline at its own rate (75/s against a single teacher's 50/s): its updates cost 2/3
    updates = plain["train_multitask"][1] - stage_hours(THESIS, Rates(**{**RATES.__dict__, "pbrl": {
        "deterministic": 1e12, "gaussian": 1e12}}))["train_multitask"][1]
    assert hours["train_multitask"][1] == pytest.approx(plain["train_multitask"][1] - updates / 3)
    # a level's seeds as one group: 3 baselines at 45 group updates/s against one at 75/s cost 5/9 of singles
    seeds = len(THESIS["train_multitask"]["seeds"])
    assert seeds == 3
    group = Rates(**{**grouped.__dict__, "multitask_group": {1: 75.0, 3: 45.0}})
    assert group.multitask_seconds_per_update(3) == pytest.approx(1 / 45)
    assert group.multitask_seconds_per_update(2) == pytest.approx((1 / 75 + 1 / 45) / 2)  # between sizes
    assert grouped.multitask_seconds_per_update(3) == pytest.approx(3 / 75)  # no group rates: R singles
    assert stage_hours(THESIS, group)["train_multitask"][1] == pytest.approx(
        hours["train_multitask"][1] - updates * 2 / 3 * 4 / 9)
