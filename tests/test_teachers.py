"""Teacher training runs on real (tiny) datasets: files written, resume after an interruption,
the checkpoint's contents, and the multi-task baseline's data routing."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from mop_core.agents.pbrl import PBRLConfig
from mop_core.agents.pbrl_group import PBRLGroup
from mop_core.agents.pbrl_multitask_group import MultiTaskPBRLGroup
from mop_core.data import TransitionTensors
from mop_core.learning.schedule import TrainSchedule
from mop_core.learning.training import RunPaths
from mop_core.multitask import train_multitask
from mop_core.relabel import RelabelConfig, relabel_dataset
from mop_core.teacher_policies import load_teacher
from mop_core.teachers import (
    DataSource,
    TeacherConfig,
    TeacherJob,
    load_source,
    load_sources,
    teacher_probe,
    train_teacher,
    train_teacher_group,
)

PBRL_TINY = PBRLConfig(hidden_sizes=(16, 16), ensemble_size=3, batch_size=16, ood_actions=1, learning_rate=1e-3)
SCHEDULE = TrainSchedule(steps=40, eval_every=20, eval_episodes=2, final_eval_episodes=2, checkpoint_every=10,
                         rollout_envs=2)


@pytest.fixture(scope="module")
def sources(tiny_collected, tmp_path_factory):
    """D_{stand->stand} (medium) and D_{stand->walk} (expert) from the tiny collect run."""
    root, _ = tiny_collected
    out = tmp_path_factory.mktemp("relabelled")
    files = {}
    for level in ("medium", "expert"):
        relabel_dataset(root / "datasets" / f"stand-{level}.hdf5", out / f"stand-{level}.hdf5", ["stand", "walk"],
                        RelabelConfig(physics_check_transitions=0))
        files[level] = (root / "datasets" / f"stand-{level}.hdf5", out / f"stand-{level}.hdf5")
    return {"stand": DataSource(*files["medium"], "stand"), "walk": DataSource(*files["expert"], "walk")}


def _paths(root) -> RunPaths:
    return RunPaths(root / "teacher.pt", root / "metrics.json", root / "curve.tsv", root / "resume" / "r.pt",
                    root / "timing.json")


def _resumed_from(paths: RunPaths) -> int:
    return json.loads(paths.timing.read_text())["resumed_from_step"]


def _config(actor: str = "deterministic", schedule: TrainSchedule = SCHEDULE) -> TeacherConfig:
    return TeacherConfig(PBRLConfig(**{**PBRL_TINY.__dict__, "actor": actor}), schedule, episode_length=50)


@pytest.mark.parametrize("actor", ["deterministic", "gaussian"])
def test_teacher_run_writes_checkpoint_metrics_and_curve(sources, tmp_path, actor):
    paths = _paths(tmp_path)
    metrics = train_teacher("stand", sources["stand"], _config(actor), 0, 0, paths)
    assert json.loads(paths.metrics.read_text()) == metrics
    _, summary = load_source(sources["stand"], 50)
    assert metrics["dataset_return_mean"] == pytest.approx(summary["return_mean"])
    assert metrics["eval_episodes"] == 2 and np.isfinite(metrics["return_mean"])
    header, *rows = paths.curve.read_text().splitlines()
    assert header.split("\t")[:3] == ["step", "return_mean", "return_std"] and len(rows) == 2
    assert not paths.resume.exists()  # removed once the final checkpoint is written
    teacher = load_teacher(paths.checkpoint)  # rebuilt from the checkpoint alone
    assert teacher.config.actor == actor and teacher.task == "stand" and teacher.level == "medium"
    obs = torch.randn(5, 24)
    assert teacher.critic(obs, torch.zeros(5, 6)).shape == (3, 5)
    assert teacher.act(obs.numpy()).shape == (5, 6)


def test_a_trained_gaussian_teachers_spread_is_inside_its_bounds(sources, tmp_path):
    """On its own dataset's states no sigma sits at either bound of log sigma (with a hard clamp about
    two thirds of them sat at the upper bound from initialisation on, and the entropy term could not
    move them), and the logged entropy lies strictly between the bounds' entropies."""
    paths = _paths(tmp_path)
    train_teacher("stand", sources["stand"], _config("gaussian"), 0, 0, paths)
    teacher = load_teacher(paths.checkpoint)
    states, _ = load_source(sources["stand"], 50)
    _, std = teacher.actor.distribution(states.observations)
    log_std = std.log()
    low, high = teacher.config.log_std_min, teacher.config.log_std_max
    assert (log_std - low).min() > 1e-3 and (high - log_std).min() > 1e-3
    header, *rows = paths.curve.read_text().splitlines()
    entropy = float(rows[-1].split("\t")[header.split("\t").index("entropy")])
    per_dim = 0.5 * np.log(2 * np.pi * np.e)
    assert 6 * (per_dim + low) < entropy < 6 * (per_dim + high)


def test_interrupted_run_resumes_to_the_same_weights(sources, tmp_path, monkeypatch):
    reference = train_teacher("stand", sources["stand"], _config(), 0, 0, _paths(tmp_path / "a"))
    ref_state = torch.load(tmp_path / "a" / "teacher.pt", weights_only=False)

    paths = _paths(tmp_path / "b")
    original = PBRLGroup.update
    calls = {"n": 0}

    def interrupt(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 26:  # after the step-20 evaluation and the step-20 resume checkpoint
            raise KeyboardInterrupt
        return original(self, *args, **kwargs)

    monkeypatch.setattr(PBRLGroup, "update", interrupt)
    with pytest.raises(KeyboardInterrupt):
        train_teacher("stand", sources["stand"], _config(), 0, 0, paths)
    monkeypatch.setattr(PBRLGroup, "update", original)
    assert paths.resume.is_file() and not paths.checkpoint.exists() and not paths.metrics.exists()

    resumed = train_teacher("stand", sources["stand"], _config(), 0, 0, paths)
    assert _resumed_from(paths) == 20
    state = torch.load(paths.checkpoint, weights_only=False)
    for key in ("actor", "critic"):
        for name, tensor in ref_state[key].items():
            torch.testing.assert_close(state[key][name], tensor, rtol=0, atol=0)
    assert resumed["return_mean"] == reference["return_mean"]


@pytest.mark.parametrize("actor", ["deterministic", "gaussian"])
def test_a_teacher_group_trains_each_run_as_it_would_train_alone(sources, tmp_path, actor):
    """Two tasks (their own data) and two seeds in one group: each run's weights, curve and metrics are
    the run's alone, to float rounding; the group writes one timing record for its 4 runs."""
    config = _config(actor)
    jobs = [TeacherJob(task, sources[task], seed, _paths(tmp_path / f"{task}-{seed}"))
            for task in ("stand", "walk") for seed in (0, 3)]
    timing = tmp_path / "group-timing.json"
    records = train_teacher_group(jobs, config, 0, tmp_path / "group-resume.pt", timing)
    assert json.loads(timing.read_text())["runs"] == 4 and not (tmp_path / "group-resume.pt").exists()
    if actor == "deterministic":  # a group too large for its device trains in waves: the same runs
        teacher_probe(config, load_sources(jobs[0].sources, config.episode_length, "cpu")[0], "cpu")(2)  # runs here
        waved = [replace(job, paths=_paths(tmp_path / "waves" / f"{job.task}-{job.seed}")) for job in jobs]
        wave_records = train_teacher_group(waved, config, 0, tmp_path / "waves-resume.pt", timing, max_group=3)
        assert json.loads(timing.read_text())["waves"] == [2, 2] and not list(tmp_path.glob("waves-resume*"))
        for job, wave_job, record, wave_record in zip(jobs, waved, records, wave_records):
            whole, wave = (torch.load(j.paths.checkpoint, weights_only=False) for j in (job, wave_job))
            for name, tensor in whole["actor"].items():
                torch.testing.assert_close(wave["actor"][name], tensor, atol=1e-5, rtol=1e-4)
            assert wave_record["seed"] == record["seed"] and wave_record["task"] == record["task"]
    for job, record in zip(jobs, records):
        alone = _paths(tmp_path / "alone" / f"{job.task}-{job.seed}")
        expected = train_teacher(job.task, job.source, config, job.seed, 0, alone)
        found, reference = (torch.load(p.checkpoint, weights_only=False) for p in (job.paths, alone))
        for key in ("actor", "critic"):
            for name, tensor in reference[key].items():
                torch.testing.assert_close(found[key][name], tensor, atol=1e-4, rtol=1e-3)
        assert record["task"] == job.task and record["seed"] == job.seed
        assert record["return_mean"] == pytest.approx(expected["return_mean"], rel=0.05, abs=1.0)
        group_curve, alone_curve = (p.curve.read_text().splitlines() for p in (job.paths, alone))
        assert group_curve[0] == alone_curve[0] and len(group_curve) == len(alone_curve)  # same columns


def test_a_rerun_after_an_interrupted_wave_restores_the_finished_waves(sources, tmp_path, monkeypatch):
    """Waves [1, 1]: the second is interrupted; the rerun restores the first from its kept resume file
    (no update of it again), resumes the second, and ends with the uninterrupted run's weights and no
    wave resume file."""
    config = _config()
    jobs = [TeacherJob("stand", sources["stand"], seed, _paths(tmp_path / "ref" / str(seed))) for seed in (0, 1)]
    train_teacher_group(jobs, config, 0, tmp_path / "ref.pt", None, max_group=1)
    jobs = [replace(job, paths=_paths(tmp_path / "run" / str(job.seed))) for job in jobs]
    original, calls = PBRLGroup.update, {"n": 0}

    def interrupt(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 40 + 26:  # the second wave, after its step-20 resume file
            raise KeyboardInterrupt
        return original(self, *args, **kwargs)

    monkeypatch.setattr(PBRLGroup, "update", interrupt)
    with pytest.raises(KeyboardInterrupt):
        train_teacher_group(jobs, config, 0, tmp_path / "run.pt", None, max_group=1)
    monkeypatch.setattr(PBRLGroup, "update", original)
    assert sorted(p.name for p in tmp_path.glob("run-wave*")) == ["run-wave0.pt", "run-wave1.pt"]
    (tmp_path / "run-wave7.pt").write_bytes(b"a wave of an earlier split")
    timing = tmp_path / "timing.json"
    train_teacher_group(jobs, config, 0, tmp_path / "run.pt", timing, max_group=1)
    assert json.loads(timing.read_text())["resumed_from_step"] == [40, 20]
    assert not list(tmp_path.glob("run-wave*"))
    for seed in (0, 1):
        found, reference = (torch.load(tmp_path / d / str(seed) / "teacher.pt", weights_only=False)
                            for d in ("run", "ref"))
        for name, tensor in reference["actor"].items():
            torch.testing.assert_close(found["actor"][name], tensor, rtol=0, atol=0)


def test_resume_file_of_another_config_or_a_broken_one_restarts_cleanly(sources, tmp_path, capsys):
    paths = _paths(tmp_path)
    paths.resume.parent.mkdir(parents=True)
    paths.resume.write_bytes(b"not a checkpoint")
    metrics = train_teacher("stand", sources["stand"], _config(), 0, 0, paths)
    assert metrics["gradient_steps"] == 40 and _resumed_from(paths) == 0
    assert "ignoring resume file" in capsys.readouterr().out

    # a resume file left by a different configuration is not reused
    other = _config(schedule=TrainSchedule(**{**SCHEDULE.__dict__, "steps": 60}))
    from mop_core.storage.artifacts import save_checkpoint
    save_checkpoint(paths.resume, {"kind": "training_resume", "fingerprint": "something else", "step": 30})
    train_teacher("stand", sources["stand"], other, 0, 0, paths)
    assert _resumed_from(paths) == 0 and "restarting from step 0" in capsys.readouterr().out


def test_multitask_critics_see_only_their_own_tasks_rewards(sources, tmp_path, monkeypatch):
    seen: dict[int, list[torch.Tensor]] = {}
    original = MultiTaskPBRLGroup._step

    def record(self, batch, *args, **kwargs):  # each task's critics, the rows of every run of the group
        seen.setdefault(self.task, []).append(batch.rewards.clone())
        return original(self, batch, *args, **kwargs)

    monkeypatch.setattr(MultiTaskPBRLGroup, "_step", record)
    schedule = TrainSchedule(steps=10, eval_every=10, eval_episodes=1, final_eval_episodes=1, checkpoint_every=10,
                             rollout_envs=1)
    paths = [replace(_paths(tmp_path), checkpoint=tmp_path / f"{s}.pt", metrics=tmp_path / f"{s}.json",
                     curve=tmp_path / f"{s}.tsv") for s in (0, 1)]
    records = train_multitask(["stand", "walk"], [sources["stand"], sources["walk"]], _config(schedule=schedule),
                              [0, 1], 0, paths, paths[0].resume, paths[0].timing)
    assert [r["seed"] for r in records] == [0, 1] and all(set(r) >= {"stand", "walk"} for r in records)
    assert records[0]["gradient_steps_per_task"] == 10 and records[0]["stand"] != records[1]["stand"]
    timing = json.loads(paths[0].timing.read_text())
    assert timing["runs"] == 2 and timing["steps"] == 10 and not paths[0].resume.exists()
    for path, record in zip(paths, records):
        assert json.loads(path.metrics.read_text()) == record
        # the learning curve is on the teachers' axis: steps per task, not updates over both tasks (Figure 5.3)
        header, *rows = path.curve.read_text().splitlines()
        assert [int(row.split("\t")[0]) for row in rows] == [10]
        assert {"critic_loss_in_stand", "critic_loss_in_walk", "grad_cosine_stand-walk"} <= set(header.split("\t"))
        assert not any("@" in column for column in header.split("\t"))
        cosine = float(rows[0].split("\t")[header.split("\t").index("grad_cosine")])
        assert -1 <= cosine <= 1  # the shared actor's gradient conflict (thesis 5.1.2 as a number)
    stand_rewards = set(load_source(sources["stand"], 50)[0].rewards.tolist())
    walk_rewards = set(load_source(sources["walk"], 50)[0].rewards.tolist())
    per_critic = [torch.cat(seen[task]).flatten().tolist() for task in (0, 1)]
    assert [len(r) for r in per_critic] == [10 * 2 * 16, 10 * 2 * 16]
    assert set(per_critic[0]) <= stand_rewards and set(per_critic[1]) <= walk_rewards
    assert not set(per_critic[1]) <= stand_rewards  # walk rewards of the expert data are not stand's


def test_a_multitask_seed_trained_in_a_group_equals_it_trained_alone(sources, tmp_path):
    """Seed 1 of a group of seeds [0, 1] (and of waves of one run each) ends as seed 1 trained alone, to
    float rounding: its own initialisation, minibatches, draws and episode seeds."""
    schedule = TrainSchedule(steps=6, eval_every=3, eval_episodes=1, final_eval_episodes=1, checkpoint_every=3,
                             rollout_envs=1)
    def run(where: str, seeds: list[int], max_group: int | None = None) -> Path:
        paths = [replace(_paths(tmp_path / where), checkpoint=tmp_path / where / f"{s}.pt") for s in seeds]
        train_multitask(["stand", "walk"], [sources["stand"], sources["walk"]], _config(schedule=schedule), seeds, 0,
                        paths, paths[0].resume, paths[0].timing, max_group=max_group)
        return paths[-1].checkpoint
    alone, grouped, waves = run("alone", [1]), run("group", [0, 1]), run("waves", [0, 1], max_group=1)
    expected = torch.load(alone, weights_only=False)
    for path in (grouped, waves):
        found = torch.load(path, weights_only=False)
        assert found["seed"] == 1 and found["metrics"].keys() == expected["metrics"].keys()
        for key, value in expected["actor"].items():
            torch.testing.assert_close(found["actor"][key], value, atol=1e-5, rtol=1e-4)
        for critic, reference in zip(found["critics"], expected["critics"], strict=True):
            for key, value in reference.items():
                torch.testing.assert_close(critic[key], value, atol=1e-5, rtol=1e-4)
    assert json.loads((tmp_path / "waves" / "timing.json").read_text())["waves"] == [1, 1]


# ---- data sharing (thesis 6.4): teachers on the union of relabelled datasets -----------------------
def test_a_union_of_relabelled_datasets_is_their_concatenation_under_one_reward(sources):
    """U_j D_{j->walk}: the medium file with its walk rewards, then the expert file with its walk rewards."""
    medium = DataSource(sources["stand"].dataset, sources["stand"].relabel, "walk")
    expert = sources["walk"]
    union, summary = load_sources([medium, expert], 50)
    parts = [load_source(s, 50)[0] for s in (medium, expert)]
    for field in ("observations", "actions", "rewards", "next_observations", "terminals", "timeouts"):
        torch.testing.assert_close(getattr(union, field), torch.cat([getattr(p, field) for p in parts]))
    singles = [load_source(s, 50)[1] for s in (medium, expert)]
    assert summary["transitions"] == sum(s["transitions"] for s in singles)
    assert summary["content_sha256"] == "+".join(s["content_sha256"] for s in singles)
    assert summary["reward_task"] == "walk" and summary["source_task"] == "stand+stand"
    assert summary["level"] == "medium+expert"
    episodes = [s["complete_episodes"] for s in singles]
    expected = sum(s["return_mean"] * n for s, n in zip(singles, episodes)) / sum(episodes)
    assert summary["return_mean"] == pytest.approx(expected) and summary["complete_episodes"] == sum(episodes)
    with pytest.raises(ValueError, match="one reward task"):
        load_sources([medium, sources["stand"]], 50)


def test_a_data_sharing_teacher_draws_its_batches_from_every_file_of_its_union(sources, tmp_path, monkeypatch):
    seen: list[torch.Tensor] = []
    original = TransitionTensors.sample

    def record(self, batch_size, generator):
        batch = original(self, batch_size, generator)
        seen.append(batch.observations.clone())
        return batch

    monkeypatch.setattr(TransitionTensors, "sample", record)
    medium = DataSource(sources["stand"].dataset, sources["stand"].relabel, "walk")
    job = TeacherJob("walk", medium, 0, _paths(tmp_path / "ds"), (sources["walk"],))
    assert job.sources == (medium, sources["walk"])
    schedule = TrainSchedule(steps=30, eval_every=30, eval_episodes=1, final_eval_episodes=1, checkpoint_every=30,
                             rollout_envs=1)
    record_ = train_teacher_group([job], _config(schedule=schedule), 0, tmp_path / "r.pt", None)[0]
    assert record_["task"] == "walk"
    drawn = torch.cat(seen)
    first = load_source(medium, 50)[0].observations
    rows = {tuple(row.tolist()) for row in first}
    from_first = sum(tuple(row.tolist()) in rows for row in drawn)
    assert 0 < from_first < len(drawn)  # both files' transitions are drawn
    checkpoint = torch.load(job.paths.checkpoint, weights_only=False)
    assert checkpoint["dataset"]["content_sha256"].count("+") == 1
    assert load_teacher(job.paths.checkpoint).source_task == "stand+stand"
