"""The shared-computation measurement of a student (thesis 6.2): visited states are the student's own
rollouts, every task pair is compared, the per-state / average / CKA numbers are the ones the
definitions give, and a group's summary is the mean over its students."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mop_core.config import ConfigError, to_dict
from mop_core.distill.checkpoint import STUDENT_KIND, load_student
from mop_core.distill.config import DistillConfig
from mop_core.distill.student import Student, StudentConfig
from mop_core.representations.measures import hidden_activations, kendall_tau, kendall_tau_a, kendall_tau_b, linear_cka
from mop_core.shared_computation import (
    SharedComputationConfig,
    collect_visited,
    episode_seeds,
    measure_networks,
    measure_student,
    rollout_jobs,
    separate_hidden,
    student_hidden,
    summarise_students,
    untrained_like,
    visited_states,
)
from mop_core.storage.artifacts import save_checkpoint
from mop_core.walker.rollout import episode_returns


def _student(num_tasks: int, seed: int = 0, task_scale: float = 1.0) -> Student:
    torch.manual_seed(seed)
    student = Student(StudentConfig(hidden_sizes=(12, 8)), 24, 6, num_tasks)
    with torch.no_grad():
        student.actor.net[0].weight[:, 24:] *= task_scale  # the task-id inputs' weights
    return student.eval()


def _save(student: Student, path, tasks: list[str]):
    config = DistillConfig(student=student.config)
    save_checkpoint(path, {"kind": STUDENT_KIND, "tasks": tasks, "distill_config": to_dict(config), "obs_dim": 24,
                           "act_dim": 6, "student": student.state_dict()})
    return path


def test_a_student_that_ignores_its_task_id_shares_everything():
    student = _student(2, task_scale=0.0)
    states = [torch.randn(30, 24), torch.randn(20, 24)]
    record = measure_student(student, ["stand", "walk"], states)
    for layer in ("layer1", "layer2"):
        row = record["pairs"]["stand-walk"][layer]
        for variant in ("a", "b"):
            stats = row[f"per_state_tau_{variant}"]
            assert stats["states"] == 50  # s ~ D_stand u D_walk
        assert row["per_state_tau_b"]["mean"] == pytest.approx(1.0) and row["per_state_tau_b"]["sd"] == pytest.approx(0)
        assert 0 < row["per_state_tau_a"]["mean"] <= 1.0  # tied zeros lower tau-a only
        assert row["linear_cka"] == pytest.approx(1.0)
    same = measure_student(student, ["stand", "walk"], [states[0], states[0]])
    assert same["pairs"]["stand-walk"]["layer2"]["average_tau_b"] == pytest.approx(1.0)


class _OneId(torch.nn.Module):
    """A two-task student seen as a one-task network: its forward ignores the id it is given and uses
    ``task`` (the way a single-task student's only id, 0, selects its one task)."""

    def __init__(self, student: Student, task: int):
        super().__init__()
        self.student, self.task = student, task

    def hidden_layers(self):
        return self.student.hidden_layers()

    def forward(self, obs, task):
        assert task == 0  # separate_hidden calls each network under its only id
        return self.student(obs, self.task)


def test_no_sharing_reference_maps_network_i_to_task_id_i():
    """separate_hidden of a student's two ids as two networks measures exactly what the student does,
    so network i stands for id i in every measure (a swap or a reused network would differ)."""
    student = _student(2, seed=3, task_scale=4.0)
    states = [torch.randn(25, 24), torch.randn(15, 24)]
    joint = measure_student(student, ["stand", "walk"], states)
    split = measure_networks(separate_hidden([_OneId(student, 0), _OneId(student, 1)]), ["stand", "walk"], states)
    swapped = measure_networks(separate_hidden([_OneId(student, 1), _OneId(student, 0)]), ["stand", "walk"], states)
    assert split["pairs"] == joint["pairs"] and split["dormant"] == joint["dormant"]
    assert swapped["mean_activations"] != joint["mean_activations"]
    assert measure_networks(student_hidden(student), ["stand", "walk"], states)["pairs"] == joint["pairs"]


def test_two_separately_initialised_networks_agree_by_chance_only():
    """The no-sharing null: neurons of separate networks correspond by index only, so their per-state
    tau is near chance while the same network twice agrees perfectly."""
    states = [torch.randn(200, 24), torch.randn(200, 24)]
    a, b = _student(1, seed=0), _student(1, seed=1)
    null = measure_networks(separate_hidden([a, b]), ["stand", "walk"], states)["pairs"]["stand-walk"]
    same = measure_networks(separate_hidden([a, a]), ["stand", "walk"], states)["pairs"]["stand-walk"]
    for layer in ("layer1", "layer2"):
        assert same[layer]["per_state_tau_b"]["mean"] == pytest.approx(1.0)
        assert same[layer]["linear_cka"] == pytest.approx(1.0)
        assert abs(null[layer]["per_state_tau_b"]["mean"]) < 0.5
        assert null[layer]["linear_cka"] < 0.99


def test_every_pair_of_three_tasks_follows_the_definitions():
    student = _student(3, task_scale=20.0)  # a strong task id: activations differ across ids
    tasks = ["stand", "walk", "run"]
    states = [torch.randn(15, 24), torch.randn(10, 24), torch.randn(12, 24)]
    record = measure_student(student, tasks, states)
    assert set(record["pairs"]) == {"stand-walk", "stand-run", "walk-run"}
    i, j = 0, 2  # stand-run, layer 2, from the definitions directly
    pooled = torch.cat([states[i], states[j]])
    under_i, under_j = hidden_activations(student, pooled, i)[1], hidden_activations(student, pooled, j)[1]
    taus = kendall_tau(under_i, under_j)
    row = record["pairs"]["stand-run"]["layer2"]
    for variant in ("a", "b"):
        stats = row[f"per_state_tau_{variant}"]
        assert stats["mean"] == pytest.approx(float(taus[variant].nanmean()))
        assert stats["undefined"] == int(taus[variant].isnan().sum())
    assert row["linear_cka"] == pytest.approx(linear_cka(under_i, under_j))
    mean_i = hidden_activations(student, states[i], i)[1].mean(0)
    mean_j = hidden_activations(student, states[j], j)[1].mean(0)
    assert row["average_tau_b"] == pytest.approx(float(kendall_tau_b(mean_i, mean_j)))
    assert row["average_tau_a"] == pytest.approx(float(kendall_tau_a(mean_i, mean_j)))
    assert row["per_state_tau_b"]["mean"] < 0.99  # the task id changes the ranking
    zero = record["zero_fraction"]["walk"]["layer1"]
    assert zero == pytest.approx(float((hidden_activations(student, states[1], 1)[0] == 0).double().mean()))


def test_group_summary_is_the_mean_and_sd_over_students():
    states = [torch.randn(10, 24), torch.randn(10, 24)]
    records = [measure_student(_student(2, seed, 5.0), ["stand", "walk"], states) for seed in (0, 1)]
    summary = summarise_students(records)
    assert summary["students"] == 2
    row = summary["pairs"]["stand-walk"]["layer1"]
    for key in ("average_tau_a", "average_tau_b", "linear_cka"):
        values = [r["pairs"]["stand-walk"]["layer1"][key] for r in records]
        assert row[key] == pytest.approx(np.mean(values))
        assert row[f"{key}_seed_sd"] == pytest.approx(np.std(values, ddof=1))  # the sample sd, as everywhere
    values = [r["pairs"]["stand-walk"]["layer1"]["per_state_tau_a"]["mean"] for r in records]
    assert row["per_state_tau_a_mean"] == pytest.approx(np.mean(values))


def test_untrained_copy_has_the_same_shape_fresh_weights_and_leaves_the_student_alone():
    student = _student(2, seed=3, task_scale=5.0)
    before = {k: v.clone() for k, v in student.state_dict().items()}
    fresh = untrained_like(student, seed=7)
    again = untrained_like(student, seed=7)
    assert all(torch.equal(before[k], v) for k, v in student.state_dict().items())
    assert {k: v.shape for k, v in fresh.state_dict().items()} == {k: v.shape for k, v in before.items()}
    assert not torch.equal(fresh.state_dict()["actor.net.0.weight"], before["actor.net.0.weight"])
    assert all(torch.equal(v, again.state_dict()[k]) for k, v in fresh.state_dict().items())


def test_visited_states_are_the_students_own_rollouts_in_any_number_of_processes(tmp_path):
    student = _student(2, task_scale=3.0)
    path = _save(student, tmp_path / "student.pt", ["stand", "walk"])
    seeds = episode_seeds(0, "walk", 3)
    assert seeds == episode_seeds(0, "walk", 3) and seeds != episode_seeds(0, "stand", 3)
    obs, returns = visited_states(path, "walk", seeds, 20, 2)
    assert obs.shape == (60, 24) and obs.dtype == np.float32
    expected = episode_returns(load_student(path).policy("walk"), "walk", seeds, 20, 3)
    np.testing.assert_allclose(returns, expected, rtol=1e-5)  # batch size changes float rounding only
    jobs = [(path, "stand"), (path, "walk")]
    config = SharedComputationConfig(episodes=3, rollout_envs=2, workers=1)
    one = collect_visited(jobs, 0, 20, config)
    two = collect_visited(jobs, 0, 20, SharedComputationConfig(episodes=3, rollout_envs=2, workers=2))
    for (obs_a, ret_a), (obs_b, ret_b) in zip(one, two):
        np.testing.assert_array_equal(obs_a, obs_b)
        np.testing.assert_array_equal(ret_a, ret_b)
    np.testing.assert_array_equal(one[1][0], obs)


def test_rollouts_follow_the_checkpoints_task_order_not_the_studys(tmp_path):
    """measure_student pairs states[i] with task id i, so a study whose ``study.tasks`` lists
    the tasks in another order than the student was trained with must still roll out, per student,
    in the checkpoint's order (it swapped the tasks' activations before); another set is refused."""
    first = tmp_path / "first.pt"
    second = tmp_path / "second.pt"
    students = {"mse-medium-0": (first, ["stand", "walk"]), "mse-medium-1": (second, ["walk", "stand"])}
    expected = [(first, "stand"), (first, "walk"), (second, "walk"), (second, "stand")]
    assert rollout_jobs(students, ["stand", "walk"]) == expected
    assert rollout_jobs(students, ["walk", "stand"]) == expected
    with pytest.raises(ConfigError, match=r"study.tasks: expected the tasks student mse-medium-0 .*first.pt"):
        rollout_jobs(students, ["stand", "run"])
    with pytest.raises(ConfigError, match="rerun distill"):
        rollout_jobs(students, ["stand", "walk", "run"])


def test_config_errors_name_the_parameter():
    with pytest.raises(ValueError, match="episodes"):
        SharedComputationConfig(episodes=0)
    with pytest.raises(ValueError, match="expected one state batch per task"):
        measure_student(_student(2), ["stand", "walk"], [torch.randn(3, 24)])
