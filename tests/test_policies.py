"""mop_core/policies.py: one loader for every policy checkpoint of a study. It dispatches on the
checkpoint's ``kind``; multi-task kinds act under a task id; anything else is refused naming the file."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mop_core.agents.pbrl import PBRLConfig, make_actor
from mop_core.agents.td3 import TD3Config
from mop_core.collect import BEHAVIOUR_KIND
from mop_core.config import InputFileError, to_dict
from mop_core.distill.checkpoint import STUDENT_KIND
from mop_core.distill.config import DistillConfig
from mop_core.distill.student import Student, StudentConfig
from mop_core.learning.nn import DeterministicActor, EnsembleCritic, with_task_id
from mop_core.learning.resume import RESUME_KIND
from mop_core.policies import POLICY_KINDS, TASK_CONDITIONED, checkpoint_kind, load_policy
from mop_core.storage.artifacts import save_checkpoint, state_sha256
from mop_core.teacher_policies import MULTITASK_KIND, TEACHER_KIND

TASKS = ["stand", "walk"]
HIDDEN = (8, 8)
OBS = np.random.default_rng(0).normal(size=(5, 24))


def _actions(net, x: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return net(torch.as_tensor(x, dtype=torch.float32)).numpy().astype(np.float64)


def _behaviour(path):
    torch.manual_seed(0)
    actor = DeterministicActor(24, 6, HIDDEN)
    save_checkpoint(path, {"kind": BEHAVIOUR_KIND, "task": "stand", "level": "medium",
                           "td3_config": to_dict(TD3Config(hidden_sizes=HIDDEN)), "obs_dim": 24, "act_dim": 6,
                           "actor": actor.state_dict()})
    return actor


def _teacher(path, actor_type: str):
    torch.manual_seed(1)
    config = PBRLConfig(actor=actor_type, hidden_sizes=HIDDEN, ensemble_size=2)
    actor = make_actor(config, 24, 6)
    critic = EnsembleCritic(24, 6, HIDDEN, 2)
    save_checkpoint(path, {"kind": TEACHER_KIND, "task": "walk", "level": "medium", "seed": 0, "study_seed": 0,
                           "pbrl_config": to_dict(config), "episode_length": 20, "obs_dim": 24, "act_dim": 6,
                           "actor": actor.state_dict(), "critic": critic.state_dict(),
                           "actor_sha256": state_sha256(actor.state_dict()), "metrics": {"return_mean": 1.0}})
    return actor


def _multitask(path):
    torch.manual_seed(2)
    config = PBRLConfig(hidden_sizes=HIDDEN, ensemble_size=2)
    actor = make_actor(config, 24 + len(TASKS), 6)
    save_checkpoint(path, {"kind": MULTITASK_KIND, "tasks": TASKS, "level": "medium", "seed": 0, "study_seed": 0,
                           "pbrl_config": to_dict(config), "obs_dim": 24, "act_dim": 6, "actor": actor.state_dict()})
    return actor


def _student(path, loss: str):
    """Saved as tests/test_shared_computation.py saves one."""
    torch.manual_seed(3)
    config = DistillConfig(loss=loss, student=StudentConfig(hidden_sizes=HIDDEN))
    student = Student(config.student, 24, 6, len(TASKS), gaussian=loss == "kl").eval()
    save_checkpoint(path, {"kind": STUDENT_KIND, "tasks": TASKS, "distill_config": to_dict(config), "obs_dim": 24,
                           "act_dim": 6, "student": student.state_dict()})
    return student


def test_the_kinds_of_policy_checkpoint():
    # pinned: checkpoints written before a rename must stay loadable
    assert POLICY_KINDS == ("td3_behaviour", "pbrl_teacher", "pbrl_multitask", "mop_student")
    assert set(TASK_CONDITIONED) == {"pbrl_multitask", "mop_student"}
    assert checkpoint_kind({"kind": "pbrl_teacher"}) == "pbrl_teacher"
    assert checkpoint_kind({"step": 1}) is None and checkpoint_kind([1]) is None


def test_a_behaviour_snapshot_acts_with_its_actor(tmp_path):
    actor = _behaviour(tmp_path / "medium.pt")
    policy = load_policy(tmp_path / "medium.pt")
    actions = policy(OBS)
    assert actions.shape == (5, 6) and actions.dtype == np.float64
    np.testing.assert_array_equal(actions, _actions(actor, OBS))
    np.testing.assert_array_equal(load_policy(str(tmp_path / "medium.pt"), task="walk")(OBS), actions)  # task unused


@pytest.mark.parametrize("actor_type", ["deterministic", "gaussian"])
def test_a_teacher_acts_with_its_actor_a_gaussian_one_by_its_mean(tmp_path, actor_type):
    actor = _teacher(tmp_path / "teacher.pt", actor_type)
    actions = load_policy(tmp_path / "teacher.pt")(OBS)
    assert actions.shape == (5, 6) and actions.dtype == np.float64
    expected = _actions(actor, OBS)
    if actor_type == "gaussian":
        expected = _actions(lambda x: actor.distribution(x)[0], OBS)
    np.testing.assert_array_equal(actions, expected)


def test_a_multitask_baseline_acts_under_the_task_id_it_is_given(tmp_path):
    path = tmp_path / "multitask.pt"
    actor = _multitask(path)
    for index, task in enumerate(TASKS):
        actions = load_policy(path, task)(OBS)
        np.testing.assert_array_equal(actions, _actions(lambda x: actor(with_task_id(x, index, 2)), OBS))
    assert not np.array_equal(load_policy(path, "stand")(OBS), load_policy(path, "walk")(OBS))
    with pytest.raises(ValueError) as err:
        load_policy(path)
    assert str(err.value) == f"task: a pbrl_multitask checkpoint acts under a task id; name the task ({path})"
    with pytest.raises(ValueError, match=r"^task: expected one of the baseline's tasks \['stand', 'walk'\], got 'run'"):
        load_policy(path, "run")


def test_a_student_acts_under_its_task_id(tmp_path):
    path = tmp_path / "student.pt"
    student = _student(path, "mse")
    for index, task in enumerate(TASKS):
        np.testing.assert_array_equal(load_policy(path, task)(OBS), _actions(lambda x: student(x, index), OBS))
    with pytest.raises(ValueError) as err:
        load_policy(path)
    assert str(err.value) == f"task: a mop_student checkpoint acts under a task id; name the task ({path})"
    with pytest.raises(ValueError, match="^sample_seed: only a Gaussian"):
        load_policy(path, "walk", sample_seed=0)


def test_a_gaussian_student_acts_by_its_mean_or_samples_with_a_seed(tmp_path):
    path = tmp_path / "student.pt"
    student = _student(path, "kl")
    mean = load_policy(path, "walk")(OBS)
    np.testing.assert_array_equal(mean, _actions(lambda x: student(x, 1), OBS))
    sampling, again = load_policy(path, "walk", sample_seed=7), load_policy(path, "walk", sample_seed=7)
    first, second = sampling(OBS), sampling(OBS)
    np.testing.assert_array_equal(again(OBS), first)  # the seed fixes the sequence of samples
    np.testing.assert_array_equal(again(OBS), second)
    assert not np.array_equal(first, second) and not np.array_equal(first, mean)
    assert np.abs(first).max() <= 1.0
    generator = torch.Generator().manual_seed(7)
    expected = _actions(lambda x: student.actor.rsample(with_task_id(x, 1, 2), generator)[0], OBS)
    np.testing.assert_array_equal(first, expected)
    assert not np.array_equal(load_policy(path, "walk", sample_seed=8)(OBS), first)


def test_a_checkpoint_of_another_kind_is_refused_naming_the_file(tmp_path):
    resume = save_checkpoint(tmp_path / "resume.pt", {"kind": RESUME_KIND, "step": 10})
    with pytest.raises(InputFileError) as err:
        load_policy(resume, "stand")
    assert str(err.value) == (f"{resume}: not a policy checkpoint of this study (kind 'training_resume'; expected one "
                              "of td3_behaviour, pbrl_teacher, pbrl_multitask, mop_student); rerun the stage that "
                              "writes it")
    foreign = save_checkpoint(tmp_path / "weights.pt", {"weight": torch.zeros(2)})
    with pytest.raises(InputFileError, match=r"weights\.pt: not a policy checkpoint of this study \(kind None;"):
        load_policy(foreign)
    state_only = save_checkpoint(tmp_path / "list.pt", [torch.zeros(2)])  # type: ignore[arg-type]
    with pytest.raises(InputFileError, match=r"list\.pt: not a policy checkpoint of this study \(kind None;"):
        load_policy(state_only)
    with pytest.raises(InputFileError, match=r"missing\.pt: checkpoint not found$"):
        load_policy(tmp_path / "missing.pt")
    broken = tmp_path / "broken.pt"
    broken.write_bytes(b"not a checkpoint")
    with pytest.raises(InputFileError, match=r"broken\.pt: not a readable torch checkpoint"):
        load_policy(broken)


def test_the_checkpoints_the_stages_write_load(tiny_collected, tiny_teachers):
    """The files collect_task and train_teacher write, not hand-made ones: the loader keeps up with the writers."""
    from mop_core.agents.td3 import actor_from_checkpoint
    from mop_core.storage.artifacts import load_checkpoint
    from mop_core.teacher_policies import load_teacher

    root, _ = tiny_collected
    for level in ("medium", "expert"):
        path = root / "behaviour" / "stand" / f"{level}.pt"
        actor = actor_from_checkpoint(load_checkpoint(path, BEHAVIOUR_KIND))
        np.testing.assert_array_equal(load_policy(path)(OBS), _actions(actor, OBS))
    checkpoints, _ = tiny_teachers
    for (task, actor_type), path in checkpoints.items():
        teacher = load_teacher(path)
        assert (teacher.task, teacher.config.actor) == (task, actor_type)
        np.testing.assert_array_equal(load_policy(path, task)(OBS), teacher.act(OBS))
