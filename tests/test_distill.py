"""Distillation: each loss against its equation, cached teacher targets, state sources, the
student's task ids, and a full run (files, resume, determinism) on tiny teachers."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from mop_core.agents.pbrl import PBRLConfig
from mop_core.config import ConfigError
from mop_core.data import read_dataset
from mop_core.distill.checkpoint import load_student, student_policy
from mop_core.distill.config import DistillConfig
from mop_core.distill.distiller import Distiller
from mop_core.distill.losses import gaussian_kl_per_state, mse_per_state, q_per_state, reduce_ensemble
from mop_core.distill.run import StudentSources, distill_student, distill_students, union_states
from mop_core.distill.states import TaskStates, offline_states, online_states, q_switch_states, task_states
from mop_core.distill.student import Student, StudentConfig, StudentGroup
from mop_core.learning.nn import DeterministicActor, EnsembleCritic, GaussianActor
from mop_core.learning.schedule import TrainSchedule
from mop_core.learning.training import RunPaths
from mop_core.teacher_policies import Teacher, load_teacher
from mop_core.walker.envs import WalkerEnv

TINY = StudentConfig(hidden_sizes=(16, 16))


def _targets(num_tasks: int, gaussian: bool, n: int = 64, seed: int = 0) -> list[TaskStates]:
    gen = torch.Generator().manual_seed(seed)
    out = []
    for i in range(num_tasks):
        actor = (GaussianActor if gaussian else DeterministicActor)(24, 6, (8,))
        out.append(task_states(f"task{i}", torch.randn(n, 24, generator=gen).numpy(), actor, {"source": "test"}))
    return out


# ---- losses ------------------------------------------------------------------------------------------------
def test_mse_is_zero_at_the_teacher_and_its_gradient_moves_the_student_towards_it():
    teacher = torch.rand(32, 6) * 2 - 1
    assert torch.equal(mse_per_state(teacher.clone(), teacher), torch.zeros(32))
    student = torch.zeros(32, 6, requires_grad=True)
    mse_per_state(student, teacher).mean().backward()
    torch.testing.assert_close(student.grad, -2 * teacher / 32)  # d/da ||t - a||^2 = -2 (t - a)
    assert (mse_per_state(student.detach() - 0.1 * student.grad, teacher) < mse_per_state(student.detach(),
                                                                                          teacher)).all()


def test_kl_is_zero_for_equal_gaussians_positive_otherwise_and_matches_monte_carlo():
    gen = torch.Generator().manual_seed(0)
    mu_s, mu_t = torch.randn(4, 6, generator=gen), torch.randn(4, 6, generator=gen)
    std_s, std_t = torch.rand(4, 6, generator=gen) + 0.3, torch.rand(4, 6, generator=gen) + 0.3
    assert torch.allclose(gaussian_kl_per_state(mu_t, std_t, mu_t, std_t), torch.zeros(4), atol=1e-6)
    kl = gaussian_kl_per_state(mu_s, std_s, mu_t, std_t)
    assert (kl > 0).all()
    # Monte Carlo: E_{x ~ N_s}[log N_s(x) - log N_t(x)]
    dist_s = torch.distributions.Normal(mu_s.double(), std_s.double())
    dist_t = torch.distributions.Normal(mu_t.double(), std_t.double())
    x = dist_s.sample((200_000,))
    mc = (dist_s.log_prob(x) - dist_t.log_prob(x)).sum(-1).mean(0)
    torch.testing.assert_close(kl.double(), mc, rtol=0.02, atol=0.02)
    torch.testing.assert_close(kl.double(), torch.distributions.kl_divergence(dist_s, dist_t).sum(-1))


def test_kl_gradient_moves_the_student_mean_towards_the_teacher():
    mu_t, std_t = torch.full((1, 6), 0.5), torch.full((1, 6), 0.2)
    mu_s = torch.zeros(1, 6, requires_grad=True)
    gaussian_kl_per_state(mu_s, std_t, mu_t, std_t).sum().backward()
    assert (mu_s.grad < 0).all()  # descending the gradient raises mu_s towards 0.5


def test_q_loss_is_minus_the_reduced_ensemble_and_its_gradient_raises_q():
    torch.manual_seed(0)
    critic = EnsembleCritic(24, 6, (16,), 3).requires_grad_(False)
    obs = torch.randn(8, 24)
    action = torch.zeros(8, 6, requires_grad=True)
    q = critic(obs, action)
    torch.testing.assert_close(q_per_state(q, "min"), -q.min(0).values)
    torch.testing.assert_close(q_per_state(q, "mean"), -q.mean(0))
    with pytest.raises(ValueError, match="reduction"):
        reduce_ensemble(q, "max")
    q_per_state(q, "min").sum().backward()
    stepped = (action - 1e-3 * action.grad).detach()
    assert (critic(obs, stepped).min(0).values > q.min(0).values).all()


# ---- student and states ------------------------------------------------------------------------------------
def test_student_reads_a_one_hot_task_id_for_three_tasks():
    student = Student(TINY, 24, 6, num_tasks=3)
    assert student.actor.net[0].in_features == 27
    obs = torch.randn(5, 24).repeat(3, 1)
    ids = torch.arange(3).repeat_interleave(5)
    out = student(obs, ids)
    for i in range(3):
        torch.testing.assert_close(out[5 * i:5 * (i + 1)], student(obs[:5], i))
    assert not torch.allclose(out[:5], out[5:10]) and not torch.allclose(out[5:10], out[10:])
    assert len(student.hidden_layers()) == 2


def test_cached_teacher_targets_equal_the_teacher_outputs():
    actor = GaussianActor(24, 6, (8,))
    states = torch.randn(100, 24)
    cached = task_states("stand", states.numpy(), actor, {})
    mu, std = actor.distribution(states)
    torch.testing.assert_close(cached.teacher_actions, mu.detach())
    torch.testing.assert_close(cached.teacher_std, std.detach())
    assert task_states("stand", states.numpy(), DeterministicActor(24, 6, (8,)), {}).teacher_std is None


def test_offline_states_subsample_without_replacement(tiny_teachers):
    _, datasets = tiny_teachers
    from mop_core.data import read_dataset

    all_obs = read_dataset(datasets["stand"]).arrays["observations"]
    sub = offline_states(datasets["stand"], 30, np.random.default_rng(0))
    assert sub.shape == (30, 24) and len(np.unique(sub, axis=0)) == 30
    assert all((all_obs == row).all(1).any() for row in sub)
    assert len(offline_states(datasets["stand"], 0, np.random.default_rng(0))) == len(all_obs)


def test_online_states_are_exactly_the_states_the_teacher_visits(tiny_teachers):
    checkpoints, _ = tiny_teachers
    teacher = load_teacher(checkpoints[("walk", "deterministic")])
    def row_by_row(obs):  # the same float arithmetic as the single-env replay below
        return np.stack([teacher.act(o[None])[0] for o in obs])

    states = online_states(row_by_row, "walk", 70, 50, seeds=[11, 12], num_envs=2)
    assert states.shape == (70, 24)
    visited = []
    for seed in (11, 12):  # replay the teacher one env at a time
        env = WalkerEnv("walk", seed, 50)
        obs = env.reset()
        for _ in range(50):
            visited.append(obs)
            obs = env.step(teacher.act(obs[None])[0]).observation
    np.testing.assert_allclose(states, np.asarray(visited[:70], dtype=np.float32), atol=1e-6)


# ---- the learner -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("loss", ["mse", "q", "kl"])
def test_every_loss_trains_every_student_parameter_and_leaves_teachers_frozen(loss):
    targets = _targets(2, gaussian=loss == "kl")
    critics = [EnsembleCritic(24, 6, (8,), 3) for _ in targets] if loss == "q" else None
    before = [c.state_dict() for c in critics] if critics else []
    before = [{k: v.clone() for k, v in s.items()} for s in before]
    distiller = Distiller(DistillConfig(loss=loss, student=TINY, batch_size=8), [targets], 24, 6, seeds=[0],
                          critics=critics)
    loss_value, metrics = distiller.loss([[distiller._rows(0, t, 8) for t in range(2)]])
    loss_value.backward()
    metrics = {key: float(value) for key, value in metrics.items()}
    for name, p in distiller.group.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name
    assert set(metrics) >= {"loss@0", "loss_task0@0", "loss_task1@0", "action_mse_task0@0"}
    assert metrics["loss@0"] == pytest.approx((metrics["loss_task0@0"] + metrics["loss_task1@0"]) / 2, rel=1e-5)
    for _ in range(3):
        distiller.update()
    for critic, state in zip(critics or [], before):
        for k, v in critic.state_dict().items():
            assert torch.equal(v, state[k])


def test_mse_distillation_fits_the_teachers_and_is_repeatable():
    targets = _targets(2, gaussian=False, n=256)
    config = DistillConfig(loss="mse", student=StudentConfig(hidden_sizes=(64, 64)), learning_rate=3e-3,
                           batch_size=64)
    a = Distiller(config, [targets], 24, 6, seeds=[3])
    first = a.update()["loss@0"]
    for _ in range(300):
        last = a.update()["loss@0"]
    assert last < 0.2 * first
    b = Distiller(config, [targets], 24, 6, seeds=[3])
    for _ in range(301):
        b.update()
    for x, y in zip(a.group.parameters(), b.group.parameters()):
        assert torch.equal(x, y)


@pytest.mark.parametrize("loss", ["mse", "q", "kl"])
def test_step_per_task_takes_one_adam_step_per_task_on_that_tasks_rows_only(loss):
    """The reference code's schedule: each update takes m optimiser steps, each on one task's batch."""
    targets = _targets(2, gaussian=loss == "kl")
    critics = [EnsembleCritic(24, 6, (8,), 3) for _ in targets] if loss == "q" else None
    config = DistillConfig(loss=loss, student=TINY, batch_size=8, step_per_task=True)
    distiller = Distiller(config, [targets], 24, 6, seeds=[0], critics=critics)
    metrics = distiller.update()
    steps = {int(state["step"]) for state in distiller.optimizer.state.values()}
    assert steps == {2} and distiller.updates == 1  # 2 tasks: 2 Adam steps in one update
    assert metrics["loss@0"] == pytest.approx((metrics["loss_task0@0"] + metrics["loss_task1@0"]) / 2)
    # the update is exactly a step on task 0's rows alone, then one on task 1's: replay it by hand
    replay = Distiller(DistillConfig(loss=loss, student=TINY, batch_size=8), [targets], 24, 6, [0], critics)
    for group in replay.optimizer.param_groups:
        group["lr"] = config.learning_rate
    for task in (0, 1):
        loss_value, _ = replay.loss([[replay._rows(0, task, 8)]], [task])
        replay._step(loss_value)
    for x, y in zip(replay.group.parameters(), distiller.group.parameters()):
        assert torch.equal(x, y)
    one_step = Distiller(DistillConfig(loss=loss, student=TINY, batch_size=8), [targets], 24, 6, [0], critics)
    one_step.update()
    assert {int(state["step"]) for state in one_step.optimizer.state.values()} == {1}


# ---- groups: R students as one vectorised model ------------------------------------------------------------
@pytest.mark.parametrize("gaussian", [False, True])
@pytest.mark.parametrize("member_loop", [False, True])
def test_a_student_group_computes_what_each_of_its_students_computes(gaussian, member_loop, monkeypatch):
    """Run r of a group, on its own inputs, gives run r's Student's outputs and gradients, whichever
    path (one bmm per layer, or member by member with the hand-written backward) computes it."""
    import mop_core.distill.student as student_module

    monkeypatch.setattr(student_module, "member_loop_pays", lambda *args: member_loop)
    students = []
    for seed in (0, 1, 2):
        torch.manual_seed(seed)
        students.append(Student(TINY, 24, 6, 3, gaussian=gaussian))
    group = StudentGroup(students)
    obs = torch.randn(3, 10, 24)
    task = torch.arange(3).repeat_interleave(4)[:10]
    out = group.distribution(obs, task) if gaussian else (group(obs, task),)
    sum(o.pow(2).sum() for o in out).backward()
    for r, student in enumerate(students):
        alone = student.distribution(obs[r], task) if gaussian else (student(obs[r], task),)
        for x, y in zip(out, alone):
            torch.testing.assert_close(x[r], y)
        sum(o.pow(2).sum() for o in alone).backward()
        plain = [m for m in student.actor.net if isinstance(m, torch.nn.Linear)]
        for layer, lin in zip(group.net[0::2], plain):
            torch.testing.assert_close(layer.weight.grad[r], lin.weight.grad.t())
            torch.testing.assert_close(layer.bias.grad[r, 0], lin.bias.grad)
        member = group.member(r)
        for x, y in zip(member.state_dict().values(), student.state_dict().values()):
            assert torch.equal(x, y)


def _on(target: TaskStates, device: torch.device) -> TaskStates:
    std = None if target.teacher_std is None else target.teacher_std.to(device)
    return TaskStates(target.task, target.states.to(device), target.teacher_actions.to(device), std, target.source)


@pytest.mark.parametrize("loss,step_per_task", [("mse", False), ("q", False), ("kl", False), ("mse", True)])
def test_a_group_of_runs_equals_the_runs_trained_alone(loss, step_per_task, device):
    """The issue's test: R runs trained as one model end where each run trained alone ends (own seed,
    own states, own sampling stream), to float rounding."""
    config = DistillConfig(loss=loss, student=TINY, batch_size=8, learning_rate=3e-3, lr_schedule="cosine",
                           step_per_task=step_per_task)
    targets = [[_on(t, device) for t in _targets(2, gaussian=loss == "kl", seed=run)] for run in range(3)]
    torch.manual_seed(9)
    critics = [EnsembleCritic(24, 6, (8,), 3) for _ in range(2)] if loss == "q" else None
    seeds = [4, 7, 11]
    group = Distiller(config, targets, 24, 6, seeds=seeds, critics=critics, device=device, total_steps=30)
    alone = [Distiller(config, [t], 24, 6, seeds=[seed], critics=critics, device=device, total_steps=30)
             for t, seed in zip(targets, seeds)]
    for _ in range(30):
        metrics = group.update()
        single = [run.update() for run in alone]
    for r, run in enumerate(alone):
        for x, y in zip(group.student(r).state_dict().values(), run.student(0).state_dict().values()):
            torch.testing.assert_close(x, y, rtol=1e-4, atol=1e-5)
        assert float(metrics[f"loss@{r}"]) == pytest.approx(float(single[r]["loss@0"]), rel=1e-4, abs=1e-6)


def test_gradient_cosines_equal_each_runs_own_per_task_gradients_and_leave_training_unchanged():
    """PCGrad's conflict measure: per run, the cosine of the two tasks' loss gradients over every
    student weight, as a lone student computes it; measuring draws from its own generator."""
    config = DistillConfig(loss="mse", student=TINY, batch_size=8, learning_rate=3e-3)
    targets = [_targets(2, gaussian=False, seed=run) for run in range(2)]
    group = Distiller(config, targets, 24, 6, seeds=[4, 7], total_steps=10)
    twin = Distiller(config, targets, 24, 6, seeds=[4, 7], total_steps=10)
    for _ in range(5):
        group.update(), twin.update()
    cosines = group.gradient_cosines(torch.Generator().manual_seed(3))
    draws = torch.Generator().manual_seed(3)  # the same draws, in the same order (task 0 then 1, runs in order)
    rows = [[torch.randint(64, (8,), generator=draws) for _ in range(2)] for _ in range(2)]
    for r in range(2):
        student = group.student(r)
        grads = []
        for t in range(2):
            obs = targets[r][t].states[rows[t][r]]
            student.zero_grad()
            mse_per_state(student(obs, t), targets[r][t].teacher_actions[rows[t][r]]).mean().backward()
            grads.append(torch.cat([p.grad.flatten() for p in student.parameters()]))
        expected = float(torch.nn.functional.cosine_similarity(grads[0], grads[1], dim=0))
        assert cosines[r]["grad_cosine_task0-task1"] == pytest.approx(expected, abs=1e-5)
        assert cosines[r]["grad_cosine"] == cosines[r]["grad_cosine_task0-task1"]
    group.update(), twin.update()
    for x, y in zip(group.group.state_dict().values(), twin.group.state_dict().values()):
        assert torch.equal(x, y)


def test_opposite_teachers_on_the_same_states_give_conflicting_gradients():
    """Two tasks whose teachers act oppositely on the same states: their gradients point apart (cosine
    < 0); two tasks with the same teacher: they agree (cosine > 0)."""
    config = DistillConfig(loss="mse", student=TINY, batch_size=32)
    base = _targets(1, gaussian=False)[0]
    states = base.states
    same = TaskStates("b", states, base.teacher_actions, None, base.source)
    opposite = TaskStates("b", states, -base.teacher_actions, None, base.source)
    for other, sign in ((opposite, -1), (same, 1)):
        distiller = Distiller(config, [[base, other]], 24, 6, seeds=[0])
        cosine = distiller.gradient_cosines(torch.Generator().manual_seed(0))[0]["grad_cosine"]
        assert sign * cosine > 0.3


def test_distill_students_as_a_group_writes_each_runs_files_like_separate_runs(tiny_teachers, tmp_path):
    sources = _sources(tiny_teachers, "deterministic")
    config = DistillConfig(student=TINY, learning_rate=1e-3, batch_size=16)
    paths = [_paths(tmp_path / "group" / str(seed)) for seed in (0, 1)]
    records = distill_students(sources, config, SCHEDULE, 50, [0, 1], 0, paths, tmp_path / "group" / "resume.pt",
                               tmp_path / "group" / "timing.json")
    timing = json.loads((tmp_path / "group" / "timing.json").read_text())
    assert timing["runs"] == 2 and not (tmp_path / "group" / "resume.pt").exists()
    for seed, record in zip((0, 1), records):
        alone = distill_student(sources, config, SCHEDULE, 50, seed, 0, _paths(tmp_path / f"alone{seed}"))
        a = load_student(paths[seed].checkpoint).student.state_dict()
        b = load_student(tmp_path / f"alone{seed}" / "student.pt").student.state_dict()
        for k in a:
            torch.testing.assert_close(a[k], b[k], rtol=1e-4, atol=1e-5)
        assert record["seed"] == seed and record["trained_with_seeds"] == [0, 1]
        assert alone["trained_with_seeds"] == [seed]
        header = paths[seed].curve.read_text().splitlines()[0].split("\t")
        assert "return_mean_stand" in header and not any("@" in column for column in header)
    state_0 = load_student(paths[0].checkpoint).student.state_dict()
    state_1 = load_student(paths[1].checkpoint).student.state_dict()
    assert not all(torch.equal(state_0[k], state_1[k]) for k in state_0)  # two seeds, two students


def test_config_errors_name_the_parameter():
    with pytest.raises(ConfigError, match="probe_source: expected one of"):
        DistillConfig(probe_source="dataset")
    with pytest.raises(ConfigError, match="loss: expected one of"):
        DistillConfig(loss="l1")
    with pytest.raises(ConfigError, match="num_states: expected a positive number of states for state_source online"):
        DistillConfig(state_source="online")
    with pytest.raises(ConfigError, match="hidden_sizes"):
        StudentConfig(hidden_sizes=())
    with pytest.raises(ValueError, match="Gaussian teachers"):
        Distiller(DistillConfig(loss="kl", student=TINY), [_targets(2, gaussian=False)], 24, 6, seeds=[0])
    with pytest.raises(ValueError, match="critic"):
        Distiller(DistillConfig(loss="q", student=TINY), [_targets(2, gaussian=False)], 24, 6, seeds=[0])


# ---- a whole run -------------------------------------------------------------------------------------------
SCHEDULE = TrainSchedule(steps=20, eval_every=10, eval_episodes=1, final_eval_episodes=2, checkpoint_every=10,
                         rollout_envs=2)


def _paths(root) -> RunPaths:
    return RunPaths(root / "student.pt", root / "metrics.json", root / "curve.tsv", root / "resume.pt",
                    root / "timing.json")


def _sources(tiny_teachers, actor: str) -> StudentSources:
    checkpoints, datasets = tiny_teachers
    return StudentSources(("stand", "walk"), (checkpoints[("stand", actor)], checkpoints[("walk", actor)]),
                          (datasets["stand"], datasets["walk"]))


@pytest.mark.parametrize("loss,source", [("mse", "offline"), ("q", "offline"), ("kl", "online")])
def test_distill_run_writes_student_metrics_and_curve(tiny_teachers, tmp_path, loss, source):
    actor = "gaussian" if loss == "kl" else "deterministic"
    config = DistillConfig(loss=loss, student=TINY, learning_rate=1e-3, batch_size=16, state_source=source,
                           num_states=120 if source == "online" else 0)
    metrics = distill_student(_sources(tiny_teachers, actor), config, SCHEDULE, 50, 0, 0, _paths(tmp_path))
    assert json.loads((tmp_path / "metrics.json").read_text()) == metrics
    for task in ("stand", "walk"):
        assert math.isfinite(metrics[task]["return_mean"]) and metrics[task]["eval_episodes"] == 2
        teacher = load_teacher(_sources(tiny_teachers, actor).teachers[("stand", "walk").index(task)])
        assert metrics[task]["teacher_return_mean"] == teacher.metrics["return_mean"]
    header, *rows = (tmp_path / "curve.tsv").read_text().splitlines()
    assert {"return_mean_stand", "return_mean_walk", "loss_stand", "loss_walk", "grad_cosine",
            "grad_cosine_stand-walk"} <= set(header.split("\t"))  # + the gradient-conflict curve
    assert len(rows) == 2 and not (tmp_path / "resume.pt").exists()
    # the last curve point is the final evaluation (its episodes, rolled out once), the others the curve's
    last = dict(zip(header.split("\t"), rows[-1].split("\t")))
    for task in ("stand", "walk"):
        assert float(last[f"return_mean_{task}"]) == metrics[task]["return_mean"]
    # the per-state tau curve (thesis 6.3.1): per hidden layer a tau-a and a tau-b column, in [-1, 1] at every
    # evaluation; tau-a <= tau-b in size (ties stay in tau-a's denominator)
    columns = header.split("\t")
    for layer in (1, 2):
        taus = {v: [float(row.split("\t")[columns.index(f"per_state_tau_{v}_layer{layer}")]) for row in rows]
                for v in ("a", "b")}
        for variant, values in taus.items():
            key = f"per_state_tau_{variant}_layer{layer}"
            assert all(-1 <= tau <= 1 for tau in values)
            assert metrics["per_state_tau"]["final"][key] == values[-1]
            assert -1 <= metrics["per_state_tau"]["at_init"][key] <= 1
        assert all(abs(a) <= abs(b) + 1e-12 for a, b in zip(taus["a"], taus["b"]))
    # the count actually drawn: every state of a dataset smaller than probe_states (the tiny ones here)
    smallest = min(len(read_dataset(d).arrays["observations"]) for d in _sources(tiny_teachers, actor).datasets)
    assert metrics["per_state_tau"]["probe_states_per_task"] == min(config.probe_states, smallest)
    assert metrics["per_state_tau"]["probe_source"] == "offline" and len(metrics["per_state_tau"]["probe_sha256"]) == 64
    loaded = load_student(tmp_path / "student.pt")
    assert loaded.tasks == ["stand", "walk"] and loaded.config == config
    assert loaded.checkpoint["states"][0]["source"] == source
    assert loaded.policy("walk")(np.zeros((3, 24))).shape == (3, 6)


def test_probe_states_zero_logs_no_tau_and_leaves_training_unchanged(tiny_teachers, tmp_path):
    sources = _sources(tiny_teachers, "deterministic")
    with_probe = DistillConfig(student=TINY, learning_rate=1e-3, batch_size=16)
    without = DistillConfig(student=TINY, learning_rate=1e-3, batch_size=16, probe_states=0)
    a = distill_student(sources, with_probe, SCHEDULE, 50, 0, 0, _paths(tmp_path / "a"))
    b = distill_student(sources, without, SCHEDULE, 50, 0, 0, _paths(tmp_path / "b"))
    assert "per_state_tau" in a and "per_state_tau" not in b
    assert "per_state_tau" not in (tmp_path / "b" / "curve.tsv").read_text()
    state_a = load_student(tmp_path / "a" / "student.pt").student.state_dict()
    state_b = load_student(tmp_path / "b" / "student.pt").student.state_dict()
    assert all(torch.equal(state_a[k], state_b[k]) for k in state_a)  # measuring does not touch training


def test_every_student_of_a_pairing_is_measured_on_the_same_probe_states(tiny_teachers, tmp_path):
    """Probe states of the tau curve depend on neither the loss nor the student seed (nor the states it
    distils on), so the curves of all students are comparable; evaluation episodes are shared too."""
    runs = [("mse", 0, "offline"), ("kl", 1, "offline"), ("mse", 1, "online")]
    records = []
    for loss, seed, source in runs:
        actor = "gaussian" if loss == "kl" else "deterministic"
        config = DistillConfig(loss=loss, student=TINY, batch_size=16, state_source=source,
                               num_states=60 if source == "online" else 0)
        records.append(distill_student(_sources(tiny_teachers, actor), config, SCHEDULE, 50, seed, 0,
                                       _paths(tmp_path / f"{loss}-{seed}-{source}")))
    hashes = {r["per_state_tau"]["probe_sha256"] for r in records}
    assert len(hashes) == 1 and None not in hashes


def test_visited_probe_source_measures_tau_on_each_evaluations_own_states(tiny_teachers, tmp_path):
    config = DistillConfig(student=TINY, batch_size=16, probe_source="visited", probe_states=20)
    metrics = distill_student(_sources(tiny_teachers, "deterministic"), config, SCHEDULE, 50, 0, 0, _paths(tmp_path))
    tau = metrics["per_state_tau"]
    assert tau["probe_source"] == "visited" and tau["probe_sha256"] is None
    assert set(tau["at_init"]) == set(tau["final"]) == {f"per_state_tau_{v}_layer{k}" for v in "ab" for k in (1, 2)}
    header, *rows = (tmp_path / "curve.tsv").read_text().splitlines()
    assert "per_state_tau_a_layer2" in header.split("\t") and len(rows) == 2
    offline = distill_student(_sources(tiny_teachers, "deterministic"), DistillConfig(
        student=TINY, batch_size=16, probe_states=20), SCHEDULE, 50, 0, 0, _paths(tmp_path / "offline"))
    assert offline["per_state_tau"]["final"] != tau["final"]  # other states, same student weights
    a = load_student(tmp_path / "student.pt").student.state_dict()
    b = load_student(tmp_path / "offline" / "student.pt").student.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)  # measuring does not touch training


def test_a_gaussian_student_can_act_by_its_mean_or_by_seeded_samples(tiny_teachers, tmp_path):
    config = DistillConfig(loss="kl", student=TINY, batch_size=16)
    distill_student(_sources(tiny_teachers, "gaussian"), config, SCHEDULE, 50, 0, 0, _paths(tmp_path))
    loaded = load_student(tmp_path / "student.pt")
    obs = np.random.default_rng(0).normal(size=(64, 24))
    mean = loaded.policy("walk")(obs)
    mu, sigma = loaded.student.distribution(torch.as_tensor(obs, dtype=torch.float32), 1)
    np.testing.assert_allclose(mean, mu.numpy(), rtol=1e-6)
    first, again = loaded.policy("walk", sample_seed=5)(obs), loaded.policy("walk", sample_seed=5)(obs)
    np.testing.assert_array_equal(first, again)
    assert not np.allclose(first, mean) and np.all(np.abs(first) <= 1)
    z = (first - mu.numpy()) / sigma.numpy()
    inside = np.abs(first) < 1  # unclipped samples are N(mu, sigma^2)
    assert abs(z[inside].mean()) < 0.2 and 0.8 < z[inside].std() < 1.2
    deterministic = Student(TINY, 24, 6, 2)
    with pytest.raises(ValueError, match="only a Gaussian"):
        student_policy(deterministic, 0, torch.device("cpu"), sample_seed=1)


def test_distill_rejects_a_teacher_of_the_wrong_kind_or_task(tiny_teachers, tmp_path):
    with pytest.raises(ValueError, match="needs a gaussian teacher"):
        distill_student(_sources(tiny_teachers, "deterministic"), DistillConfig(loss="kl", student=TINY), SCHEDULE,
                        50, 0, 0, _paths(tmp_path))
    checkpoints, datasets = tiny_teachers
    swapped = StudentSources(("stand", "walk"), (checkpoints[("walk", "deterministic")],
                                                 checkpoints[("stand", "deterministic")]),
                             (datasets["stand"], datasets["walk"]))
    with pytest.raises(ValueError, match="a teacher for task 'walk', expected one for 'stand'"):
        distill_student(swapped, DistillConfig(student=TINY), SCHEDULE, 50, 0, 0, _paths(tmp_path))
    assert not (tmp_path / "student.pt").exists()


@pytest.mark.parametrize("correction", ["none", "dagger"])
def test_interrupted_distillation_resumes_to_the_same_student(tiny_teachers, tmp_path, monkeypatch, correction):
    from mop_core.distill.corrections import DaggerConfig

    # dagger: its round at step 10, where the interrupted run's last resume file is written
    config = DistillConfig(student=TINY, learning_rate=1e-3, batch_size=16, correction=correction,
                           dagger=DaggerConfig(rounds=1, episodes=1))
    sources = _sources(tiny_teachers, "deterministic")
    distill_student(sources, config, SCHEDULE, 50, 0, 0, _paths(tmp_path / "a"))
    original, calls = Distiller.update, {"n": 0}

    def failing(self):
        calls["n"] += 1
        if calls["n"] == 15:
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(Distiller, "update", failing)
    with pytest.raises(KeyboardInterrupt):
        distill_student(sources, config, SCHEDULE, 50, 0, 0, _paths(tmp_path / "b"))
    assert (tmp_path / "b" / "resume.pt").exists() and not (tmp_path / "b" / "student.pt").exists()
    monkeypatch.setattr(Distiller, "update", original)
    distill_student(sources, config, SCHEDULE, 50, 0, 0, _paths(tmp_path / "b"))
    assert json.loads((tmp_path / "b" / "timing.json").read_text())["resumed_from_step"] == 10
    a = load_student(tmp_path / "a" / "student.pt").student.state_dict()
    b = load_student(tmp_path / "b" / "student.pt").student.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)


# ---- data sharing (thesis 6.4): union states and offline Q-switch targets ---------------------------
def _candidate(seed: int, source: str) -> Teacher:
    torch.manual_seed(seed)
    config = PBRLConfig(hidden_sizes=(8,), ensemble_size=3)
    return Teacher("stand", "medium", 0, config, DeterministicActor(24, 6, (8,)).requires_grad_(False),
                   EnsembleCritic(24, 6, (8,), 3).requires_grad_(False), source_task=source)


@pytest.mark.parametrize("judge", ["own", "target"])
def test_q_switch_labels_each_state_with_the_highest_valued_candidate_action(judge):
    """argmax_j Q_j(s, pi_j(s)) (min over the ensemble) state by state, judged by each candidate's own
    critics or all by the first (the target task's own teacher); the win shares sum to 1."""
    candidates = [_candidate(1, "stand"), _candidate(2, "walk"), _candidate(3, "run")]
    judges = candidates if judge == "own" else [candidates[0]] * 3
    states = torch.randn(200, 24, generator=torch.Generator().manual_seed(0)).numpy()
    target = q_switch_states("stand", states, candidates, judges, "min", {"source": "test"}, chunk=64)
    obs = torch.as_tensor(states)
    for k in range(len(states)):
        values = [float(j.critic(obs[k:k + 1], c.actor(obs[k:k + 1])).min()) for c, j in zip(candidates, judges)]
        best = int(np.argmax(values))
        torch.testing.assert_close(target.teacher_actions[k], candidates[best].actor(obs[k:k + 1])[0])
    shares = target.source["q_switch"]
    assert list(shares) == ["stand", "walk", "run"] and sum(shares.values()) == pytest.approx(1.0)
    assert sum(v > 0 for v in shares.values()) >= 2  # the switch does switch on random states
    assert target.source["source"] == "test" and target.teacher_std is None


def test_q_switch_with_one_candidate_is_that_teachers_action():
    only = _candidate(1, "stand")
    states = torch.randn(50, 24).numpy()
    target = q_switch_states("stand", states, [only], [only], "min", {})
    torch.testing.assert_close(target.teacher_actions, only.actor(torch.as_tensor(states)))
    assert target.source["q_switch"] == {"stand": 1.0}
    with pytest.raises(ValueError, match="one judge per candidate"):
        q_switch_states("stand", states, [only], [], "min", {})


def test_union_states_are_every_files_observations_in_order(tiny_teachers):
    _, datasets = tiny_teachers
    files = [datasets["stand"], datasets["walk"]]
    union = union_states(files, 0, np.random.default_rng(0))
    expected = np.concatenate([read_dataset(f).arrays["observations"] for f in files]).astype(np.float32)
    np.testing.assert_array_equal(union, expected)
    subset = union_states(files, 30, np.random.default_rng(0))
    assert len(subset) == 30 and {tuple(r) for r in subset} <= {tuple(r) for r in expected}


def test_data_sharing_students_learn_every_task_on_the_union(tiny_teachers, tmp_path):
    """DS: both tasks' teachers label the same union of states (the states of the two datasets)."""
    teachers, datasets = tiny_teachers
    files = (datasets["stand"], datasets["walk"])
    sources = StudentSources(("stand", "walk"), (teachers["stand", "deterministic"], teachers["walk", "deterministic"]),
                             files, state_datasets=files)
    config = DistillConfig(loss="mse", student=TINY, learning_rate=1e-3, batch_size=16)
    metrics = distill_student(sources, config, SCHEDULE, 50, 0, 0, _paths(tmp_path))
    checkpoint = torch.load(tmp_path / "student.pt", weights_only=False)
    n = sum(len(read_dataset(d).arrays["observations"]) for d in (datasets["stand"], datasets["walk"]))
    assert [s["source"] for s in checkpoint["states"]] == ["offline_union"] * 2
    assert [s["states"] for s in checkpoint["states"]] == [n, n] and "q_switch" not in metrics


# ---- state-shift corrections (thesis 5.3) ------------------------------------------
def test_weighted_states_are_drawn_in_proportion_to_their_weight():
    targets = _targets(1, gaussian=False, n=50)
    weights = torch.zeros(50)
    weights[[3, 7]] = torch.tensor([1.0, 3.0])
    targets[0].weights = weights
    distiller = Distiller(DistillConfig(student=TINY, batch_size=4000), [targets], 24, 6, [0])
    rows = distiller._draw([0])[0][0]
    assert set(rows.tolist()) == {3, 7}  # zero weight: never drawn
    assert (rows == 7).float().mean().item() == pytest.approx(0.75, abs=0.03)


def test_density_weights_favour_the_teachers_states_and_respect_the_clip():
    from mop_core.distill.corrections import ReweightConfig, density_weights

    rng = np.random.default_rng(0)
    teacher = rng.normal(0.0, 1.0, (3000, 4)).astype(np.float32)
    data = np.concatenate([rng.normal(0.0, 1.0, (300, 4)), rng.normal(4.0, 1.0, (2700, 4))]).astype(np.float32)
    weights, info = density_weights(data, teacher, ReweightConfig(clip=5.0, states=3000, epochs=10), seed=1,
                                    episode_rows=1)  # independent rows: each its own episode
    assert weights.shape == (3000,) and weights.max() <= 5.0 and (weights >= 0).all()
    assert weights[:300].mean() > 20 * weights[300:].mean()  # the teacher-like 10% carry the weight
    assert info["reweight_auc"] > 0.9 and 0 < info["reweight_clipped_share"] < 1
    assert info["reweight_ess_unclipped"] < info["reweight_ess"] < 1  # clipping spreads the weight


def test_dagger_rounds_are_evenly_spaced():
    from mop_core.distill.corrections import DaggerConfig

    assert DaggerConfig(rounds=3).round_starts(5000) == {1250: 1, 2500: 2, 3750: 3}
    assert DaggerConfig(rounds=1).round_starts(20) == {10: 1}
    with pytest.raises(ConfigError, match="rounds: expected a positive integer"):
        DaggerConfig(rounds=0)


def test_aggregated_states_join_training_and_survive_a_resume():
    targets = _targets(2, gaussian=False, n=32)
    distiller = Distiller(DistillConfig(student=TINY, batch_size=8), [targets], 24, 6, [0])
    new = torch.randn(5, 24)
    distiller.aggregate(0, 1, new, torch.zeros(5, 6))
    assert len(distiller.targets[0][1]) == 37 and len(distiller.targets[0][0]) == 32
    assert torch.equal(distiller.targets[0][1].states[32:], new) and len(distiller.base[0][1]) == 32
    distiller.update()
    state = distiller.state_dict()
    fresh = Distiller(DistillConfig(student=TINY, batch_size=8), [targets], 24, 6, [0])  # the states before it
    fresh.load_state_dict(state)
    assert len(fresh.targets[0][1]) == 37 and torch.equal(fresh.targets[0][1].states, distiller.targets[0][1].states)
    assert fresh.targets[0][1].source["aggregated_states"] == 5
    assert all(torch.equal(a, b) for a, b in zip(fresh.update().values(), distiller.update().values())
               if isinstance(a, torch.Tensor))


@pytest.mark.parametrize("correction", ["reweight", "dagger"])
def test_corrected_distillation_runs_and_records_its_correction_and_errors(tiny_teachers, tmp_path, correction):
    from mop_core.distill.corrections import DaggerConfig, ReweightConfig

    sources = _sources(tiny_teachers, "deterministic")
    # the teacher's states: its own dataset (any states serve the ratio here); held out: the other task's data
    sources = StudentSources(sources.tasks, sources.teachers, sources.datasets, heldout=sources.datasets[::-1],
                             references=sources.datasets)
    config = DistillConfig(student=TINY, learning_rate=1e-3, batch_size=16, correction=correction,
                           reweight=ReweightConfig(states=100, epochs=2), dagger=DaggerConfig(rounds=1, episodes=1))
    metrics = distill_students(sources, config, SCHEDULE, 50, [0, 1], 0, [_paths(tmp_path / "a"),
                                                                            _paths(tmp_path / "b")],
                               tmp_path / "resume.pt", None)
    for record in metrics:
        for task in ("stand", "walk"):
            errors = record[task]["action_mse"]
            assert set(errors) == {"train", "heldout", "visited"} and all(v >= 0 for v in errors.values())
            assert ("reweight" in record[task]) == (correction == "reweight")
        if correction == "dagger":  # one round of one 50-step episode per task, each run its own
            assert record["dagger"]["aggregated_states"] == {"stand": 50, "walk": 50}
    again = distill_students(sources, config, SCHEDULE, 50, [0, 1], 0, [_paths(tmp_path / "c"),
                                                                         _paths(tmp_path / "d")],
                             tmp_path / "resume2.pt", None)
    assert [m["stand"]["action_mse"] for m in again] == [m["stand"]["action_mse"] for m in metrics]  # repeatable


def test_reweighting_needs_reference_states(tiny_teachers, tmp_path):
    config = DistillConfig(student=TINY, batch_size=16, correction="reweight")
    with pytest.raises(ConfigError, match="correction: expected reweight only with the teachers' reference"):
        distill_student(_sources(tiny_teachers, "deterministic"), config, SCHEDULE, 50, 0, 0, _paths(tmp_path))
    with pytest.raises(ConfigError, match="correction: expected not reweight unless state_source is offline"):
        DistillConfig(correction="reweight", state_source="online", num_states=10)
