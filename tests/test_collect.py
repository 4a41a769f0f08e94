"""The collect step on the tiny profile: snapshots, datasets, determinism, parameter errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import collect_paths

from mop_core.collect import LEVELS, CollectConfig, ScheduleConfig, collect_task, random_returns, task_seeds
from mop_core.config import ConfigError, from_mapping
from mop_core.data import read_dataset


def test_collect_writes_three_valid_datasets(tiny_collected, tiny_collect_config):
    root, summary = tiny_collected
    cfg = tiny_collect_config
    length = cfg.episode_length
    for level in LEVELS:
        ds = read_dataset(root / "datasets" / f"stand-{level}.hdf5", verify_checksum=True)
        assert ds.attrs["task"] == "stand" and ds.attrs["level"] == level
        metrics = json.loads((root / "metrics" / f"stand-{level}.json").read_text())
        assert metrics["transitions"] == len(ds)
    expert = read_dataset(root / "datasets" / "stand-expert.hdf5")
    assert len(expert) == cfg.datasets.expert_episodes * length
    replay = read_dataset(root / "datasets" / "stand-medium_replay.hdf5")
    assert len(replay) == cfg.schedule.warmup_steps + cfg.schedule.medium_step  # all seen up to medium
    medium_ckpt = torch.load(root / "behaviour" / "stand" / "medium.pt", weights_only=False)
    expert_ckpt = torch.load(root / "behaviour" / "stand" / "expert.pt", weights_only=False)
    assert medium_ckpt["gradient_steps"] == cfg.schedule.medium_step
    assert expert_ckpt["gradient_steps"] == cfg.schedule.total_steps
    assert expert.attrs["behaviour_sha256"] == expert_ckpt["sha256"] != medium_ckpt["sha256"]
    assert summary["snapshots"]["expert"]["return_mean"] == expert_ckpt["return_mean"]
    curve = (root / "curves" / "stand.tsv").read_text().splitlines()
    assert curve[0].startswith("step\tenv_step\treturn_mean")
    assert len(curve) > 2


def test_same_seed_gives_byte_identical_datasets(tiny_collected, tiny_collect_config, tmp_path):
    root, _ = tiny_collected
    collect_task("stand", tiny_collect_config, 0, collect_paths(tmp_path, "stand"))
    for level in LEVELS:
        name = f"stand-{level}.hdf5"
        assert (tmp_path / "datasets" / name).read_bytes() == (root / "datasets" / name).read_bytes()


def test_task_seeds_do_not_depend_on_other_tasks():
    assert task_seeds(0, "walk") == task_seeds(0, "walk")
    assert task_seeds(0, "walk") != task_seeds(0, "stand") != task_seeds(1, "stand")
    assert len(set(task_seeds(0, "walk").values())) == len(task_seeds(0, "walk"))  # one stream per purpose


def test_td3_replay_sampler_warmup_and_noise_draw_from_different_seeds(tiny_collect_config, monkeypatch):
    """The replay sampler, the warm-up actions and TD3's noise generator (exploration and target smoothing)
    were once all seeded with the agent's seed: correlated streams. Each now has its own."""
    import mop_core.collect as collect
    from mop_core.data import ReplayBuffer

    seen: dict[str, set[int]] = {"sampler": set(), "noise": set(), "warmup": set()}
    sample, default_rng = ReplayBuffer.sample, np.random.default_rng

    def record_sample(self, batch_size, generator):
        seen["sampler"].add(generator.initial_seed())
        return sample(self, batch_size, generator)

    def record_rng(seed=None):
        seen["warmup"].add(int(seed))
        return default_rng(seed)

    class RecordingTD3(collect.TD3):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            seen["noise"].add(self.generator.initial_seed())

    monkeypatch.setattr(ReplayBuffer, "sample", record_sample)
    monkeypatch.setattr(collect, "TD3", RecordingTD3)
    monkeypatch.setattr(collect.np.random, "default_rng", record_rng)
    schedule = ScheduleConfig(**{**tiny_collect_config.schedule.__dict__, "total_steps": 20, "medium_step": 10,
                                 "warmup_steps": 50, "eval_every": 20})
    collect.train_behaviour("stand", CollectConfig(tiny_collect_config.td3, schedule, tiny_collect_config.datasets,
                                                   tiny_collect_config.episode_length), 0, torch.device("cpu"), False)
    seeds = task_seeds(0, "stand")
    assert seen == {"sampler": {seeds["sampler"]}, "noise": {seeds["agent"]}, "warmup": {seeds["warmup"]}}
    assert len({seeds["sampler"], seeds["agent"], seeds["warmup"]}) == 3


def test_collect_measures_the_random_policys_return(tiny_collected, tiny_collect_config):
    _, summary = tiny_collected
    random = summary["random"]
    assert random["episodes"] == tiny_collect_config.schedule.random_episodes
    assert 0 <= random["return_mean"] <= tiny_collect_config.episode_length  # rewards lie in [0, 1]
    seeds = task_seeds(0, "stand")
    envs = tiny_collect_config.datasets.rollout_envs
    again = random_returns("stand", random["episodes"], seeds["random_episodes"], tiny_collect_config.episode_length,
                           envs, seeds["random_policy"])
    assert float(again.mean()) == pytest.approx(random["return_mean"], rel=1e-12)  # repeatable
    other = random_returns("stand", random["episodes"], seeds["random_episodes"], tiny_collect_config.episode_length,
                           envs, seeds["random_policy"] + 1)
    assert float(other.mean()) != random["return_mean"]


def test_medium_by_target_return(tiny_collect_config, tmp_path):
    cfg = tiny_collect_config
    schedule = ScheduleConfig(**{**cfg.schedule.__dict__, "medium_target_return": -1.0})
    config = CollectConfig(cfg.td3, schedule, cfg.datasets, cfg.episode_length)
    summary = collect_task("walk", config, 0, collect_paths(tmp_path, "walk"))
    # every return is >= -1, so the first evaluation is the medium snapshot
    assert summary["snapshots"]["medium"]["gradient_steps"] == cfg.schedule.eval_every
    replay = read_dataset(tmp_path / "datasets" / "walk-medium_replay.hdf5")
    assert len(replay) == cfg.schedule.warmup_steps + cfg.schedule.eval_every
    assert replay.arrays["timeouts"][-1]


def test_a_target_return_per_task_is_read_for_its_task_and_named_when_missing(tiny_params):
    from mop_core.config import ConfigError, from_mapping
    from mop_core.study_params import check_params

    raw = dict(tiny_params["collect"]["schedule"]) | {"medium_target_return": {"stand": 458.85, "walk": 681}}
    schedule = from_mapping(ScheduleConfig, raw, "collect.schedule")
    assert schedule.medium_target("walk") == 681.0 and isinstance(schedule.medium_target("walk"), float)
    assert from_mapping(ScheduleConfig, raw | {"medium_target_return": 500}, "s").medium_target("stand") == 500.0
    with pytest.raises(ConfigError, match=r"collect.schedule.medium_target_return.walk: expected a number"):
        from_mapping(ScheduleConfig, raw | {"medium_target_return": {"walk": "high"}}, "collect.schedule")
    with pytest.raises(ConfigError, match=r"collect.schedule.medium_target_return: expected a number or a mapping"):
        from_mapping(ScheduleConfig, raw | {"medium_target_return": [1, 2]}, "collect.schedule")
    params = json.loads(json.dumps(tiny_params))
    params["collect"]["schedule"]["medium_target_return"] = {"stand": 458.85}
    with pytest.raises(ConfigError, match=r"collect.schedule.medium_target_return: expected a target return for "
                                          r"every study task \('walk' is missing\)"):
        check_params(params)


@pytest.mark.parametrize("key,value,message", [
    ("schedule.medium_step", 400, r"collect.schedule.medium_step: expected fewer gradient steps than total_steps=300"),
    ("schedule.total_steps", 0, r"collect.schedule.total_steps: expected a positive integer"),
    ("datasets.expert_episodes", -2, r"collect.datasets.expert_episodes: expected a positive integer"),
    ("td3.hidden_sizes", [0, 4], r"collect.td3.hidden_sizes: expected a non-empty list of positive widths"),
    ("td3.batch_size", "big", r"collect.td3.batch_size: expected an integer"),
    ("td3.learnin_rate", 0.1, r"collect.td3.learnin_rate: unknown parameter"),
])
def test_bad_parameters_name_the_key(tiny_params, key, value, message):
    raw = json.loads(json.dumps({k: v for k, v in tiny_params["collect"].items() if k != "parallel"}))
    section, name = key.split(".")
    raw[section][name] = value
    with pytest.raises(ConfigError, match=message):
        from_mapping(CollectConfig, raw, "collect")


def test_rollout_returns_match_stored_rewards(tiny_collected):
    root, summary = tiny_collected
    ds = read_dataset(root / "datasets" / "stand-expert.hdf5")
    episode_returns = ds.arrays["rewards"].reshape(-1, ds.attrs["episode_length"]).sum(1)
    metrics = summary["datasets"]["expert"]
    assert np.isclose(episode_returns.mean(), metrics["return_mean"], rtol=1e-5)


def test_an_interrupted_behaviour_run_resumes_to_the_same_snapshots_datasets_and_curve(
        tiny_collected, tiny_collect_config, tmp_path, monkeypatch):
    """The TD3 run writes a resume file at episode ends (every ``checkpoint_every`` updates); killed
    after one and started again, it ends byte for byte where an uninterrupted run ends."""
    import dataclasses

    import mop_core.collect as collect

    root, _ = tiny_collected
    cfg = tiny_collect_config
    cfg = dataclasses.replace(cfg, schedule=dataclasses.replace(cfg.schedule, checkpoint_every=50))
    paths = dataclasses.replace(collect_paths(tmp_path, "stand"), resume=tmp_path / "resume" / "collect-stand.pt")
    evaluations, real = [], collect.episode_returns

    def killed_at_the_third_evaluation(*args, **kwargs):
        evaluations.append(1)
        if len(evaluations) == 3:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(collect, "episode_returns", killed_at_the_third_evaluation)
    with pytest.raises(KeyboardInterrupt):
        collect_task("stand", cfg, 0, paths)
    state = torch.load(paths.resume, weights_only=False)
    assert state["kind"] == "training_resume" and 0 < state["step"] < cfg.schedule.total_steps
    assert state["env_step"] % cfg.episode_length == 0  # resumed at an episode boundary
    evaluations.clear()
    monkeypatch.setattr(collect, "episode_returns", lambda *a, **k: evaluations.append(1) or real(*a, **k))
    collect_task("stand", cfg, 0, paths)
    assert not paths.resume.exists()  # a finished run leaves no resume file
    curve = (tmp_path / "curves" / "stand.tsv").read_text().splitlines()[1:]
    curve_steps = [int(line.split("\t")[0]) for line in curve]
    after_resume = sum(step > state["step"] for step in curve_steps)
    assert len(evaluations) == after_resume + 3  # it resumed: only the later curve points, 2 snapshots, R_random
    for level in LEVELS:  # checkpoint_every changes nothing but when resume files are written
        name = f"stand-{level}.hdf5"
        assert (tmp_path / "datasets" / name).read_bytes() == (root / "datasets" / name).read_bytes()
    for level in ("medium", "expert"):  # no time or version inside: the same weights are the same bytes
        resumed = (tmp_path / "behaviour" / "stand" / f"{level}.pt").read_bytes()
        assert resumed == (root / "behaviour" / "stand" / f"{level}.pt").read_bytes()
    assert (tmp_path / "curves" / "stand.tsv").read_bytes() == (root / "curves" / "stand.tsv").read_bytes()


def _criterion_config(cfg, **schedule):
    """The tiny collect config with an expert criterion (stand only) and ``schedule`` changes."""
    fields = {**cfg.schedule.__dict__, "medium_target_return": {"stand": 290.0}, "expert_return": {"stand": 600.0},
              "expert_eval_episodes": 7, "snapshot_eval_episodes": 3, "eval_every": 100, "total_steps": 600,
              "medium_step": 100} | schedule
    return CollectConfig(cfg.td3, ScheduleConfig(**fields), cfg.datasets, cfg.episode_length)


def test_an_expert_criterion_stops_training_there_and_medium_is_the_snapshot_measured_nearest_its_target(
        tiny_collect_config, monkeypatch):
    """Curve returns 100, 300, 500, 700 at steps 100..400: the criterion 600 is checked at step 400 (7 fresh
    episodes: 620), so training stops there; of the earlier snapshots, measured over 3 episodes, the one
    nearest 290 is medium (step 300 measures 280), whatever their curve returns were."""
    import mop_core.collect as collect

    config = _criterion_config(tiny_collect_config)
    curve, measured = iter([100.0, 300.0, 500.0, 700.0]), iter([400.0, 95.0, 280.0])
    calls = []

    def scripted(policy, task, seeds, length, envs=10):
        n = len(seeds)
        calls.append(n)
        value = next(curve) if n == config.schedule.eval_episodes else 620.0 if n == 7 else next(measured)
        return np.full(n, value)

    monkeypatch.setattr(collect, "episode_returns", scripted)
    medium, expert, buffer, rows = collect.train_behaviour("stand", config, 0, torch.device("cpu"), False)
    assert [r["step"] for r in rows] == [100, 200, 300, 400]  # stopped at the criterion, not at 600
    assert expert.gradient_steps == 400 and expert.curve_return == 620.0
    assert buffer.size == config.schedule.warmup_steps + 400
    # candidates by curve distance to 290: steps 200 (300), 100 (100), 300 (500); measured 400, 95, 280
    assert medium.gradient_steps == 300
    assert calls == [2, 2, 2, 2, 7, 3, 3, 3]


def test_an_expert_criterion_never_met_stops_collect_naming_the_task_and_its_best_return(tiny_collect_config,
                                                                                         tmp_path):
    from mop_core.learning.runtime import CriterionNotMetError

    config = _criterion_config(tiny_collect_config, expert_return={"stand": 1e6}, total_steps=200)
    with pytest.raises(CriterionNotMetError, match=r"collect stand: .*expert criterion 1000000.0 .*expert_return"
                                                   r"\.stand.* total_steps=200 .*best evaluation"):
        collect_task("stand", config, 0, collect_paths(tmp_path, "stand"))
    assert not list(tmp_path.rglob("*.hdf5")) and not list(tmp_path.rglob("*.pt"))  # no "expert" below it
    curve = collect_paths(tmp_path, "stand").curve.read_text().splitlines()  # but the curve that shows why
    assert curve[0].split("\t")[:3] == ["step", "env_step", "return_mean"] and len(curve) == 1 + 200 // 100


def test_a_missed_criterion_is_retried_from_fresh_seeds_and_the_error_names_every_attempt(tiny_collect_config,
                                                                                          tmp_path):
    from mop_core.learning.runtime import CriterionNotMetError

    assert task_seeds(0, "stand", 0) == task_seeds(0, "stand")  # the first attempt is the plain run
    assert set(task_seeds(0, "stand", 1).values()).isdisjoint(task_seeds(0, "stand").values())
    config = _criterion_config(tiny_collect_config, expert_return={"stand": 1e6}, total_steps=200, attempts=2)
    with pytest.raises(CriterionNotMetError, match=r"attempt 1: collect stand: .* attempt 2: collect stand: ") as err:
        collect_task("stand", config, 0, collect_paths(tmp_path, "stand"))
    assert not list(tmp_path.rglob("*.hdf5")) and len(err.value.curve) == 200 // 100
    with pytest.raises(ConfigError, match="attempts: expected 1 without an expert criterion"):
        _criterion_config(tiny_collect_config, expert_return=None, attempts=2)


def test_collect_metrics_carry_the_check_that_made_the_expert():
    from mop_core.collect import collect_metrics

    snapshot = {"return_mean": 1.0, "gradient_steps": 1}
    summary = {"snapshots": {"medium": snapshot, "expert": snapshot},
               "random": {"return_mean": 0.0, "return_std": 0.0, "episodes": 1}}
    assert "expert_criterion" not in collect_metrics({"stand": summary})["stand"]
    criterion = {"expert_criterion": 900.0, "expert_criterion_return": 912.3, "expert_criterion_episodes": 20}
    assert collect_metrics({"stand": summary | {"criterion": criterion}})["stand"].items() >= criterion.items()


@pytest.mark.parametrize("schedule, error", [
    ({"medium_target_return": None}, "medium_target_return: expected a target return per task when expert_return"),
    ({"expert_return": {"stand": 200.0}}, "expert_return.stand: expected a return above medium_target_return"),
    ({"expert_eval_episodes": 0}, "expert_eval_episodes: expected a positive integer"),
])
def test_expert_criterion_settings_are_checked(tiny_collect_config, schedule, error):
    with pytest.raises(ConfigError, match=error):
        _criterion_config(tiny_collect_config, **schedule)


def test_the_params_stage_names_a_study_task_without_an_expert_criterion(tiny_params):
    from mop_core.study_params import check_params

    params = json.loads(json.dumps(tiny_params))
    params["collect"]["schedule"] |= {"medium_target_return": {"stand": 290.0, "walk": 300.0},
                                      "expert_return": {"stand": 600.0}}
    with pytest.raises(ConfigError, match="expert_return: expected a criterion for every study task .'walk'"):
        check_params(params)


def test_the_behaviour_seeds_script_sets_existing_keys_and_refuses_a_typo(tiny_params):
    import sys

    from conftest import ROOT

    sys.path.insert(0, str(ROOT / "scripts"))
    from behaviour_seeds import with_overrides

    params = with_overrides(json.loads(json.dumps(tiny_params)),
                            ["collect.td3.layer_norm=true", "collect.schedule.expert_return={stand: 900, walk: 850}"])
    assert params["collect"]["td3"]["layer_norm"] is True
    assert params["collect"]["schedule"]["expert_return"] == {"stand": 900, "walk": 850}
    with pytest.raises(SystemExit, match="--set collect.td3.layer_nrom: no such parameter"):
        with_overrides(params, ["collect.td3.layer_nrom=true"])
