"""Speed of the collect and relabel building blocks, measured in one run on this machine.

Prints: walkers built/s (dm_control's suite parsing the XML model each time, as before, vs
``WalkerEnv`` from its task's template, sharing the compiled model); dm_control env steps/s; batched
stepping of many walkers with a batched policy (members stepped through dm_control, as before issue
16, vs our VectorWalkerEnv's raw MuJoCo step in 1 and 2 threads), and MuJoCo's multi-threaded
open-loop ``mujoco.rollout`` (the ceiling), with ratios; relabel transitions/s (vectorised formula vs
physics replay, target >= 1M/s vectorised); TD3 updates/s at the quick (params.yaml) and thesis
(profiles/thesis.yaml) sizes. Each figure is the median of a few timed repeats after a warm-up. Run:
``python benchmarks/bench_collect.py [--quick-only]``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import mujoco
import numpy as np
import torch
import yaml
from mujoco import rollout
from timing import rate

from mop_core.agents.td3 import TD3, TD3Config
from mop_core.config import from_mapping
from mop_core.data import ReplayBuffer
from mop_core.data.hdf5 import Dataset
from mop_core.learning.runtime import configure_compute, set_step_threads
from mop_core.relabel import relabel_rewards
from mop_core.walker.envs import VectorStep, VectorWalkerEnv, WalkerEnv

ROOT = Path(__file__).resolve().parents[1]


def walkers_built_per_second(count: int = 20) -> tuple[float, float]:
    from mop_core.walker.envs import _suite

    def suite():
        for seed in range(count):
            _suite().load("walker", "walk", task_kwargs={"random": seed, "time_limit": float("inf")})

    def templated():
        for seed in range(count):
            WalkerEnv("walk", seed)

    return rate(suite, count), rate(templated, count)


def env_steps_per_second(steps: int = 2000) -> float:
    env = WalkerEnv("walk", 0)
    env.reset()
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, 6))

    def run():
        for a in actions:
            env.step(a)
    return rate(run, steps)


def _actor() -> torch.nn.Module:
    torch.manual_seed(0)
    return torch.nn.Sequential(torch.nn.Linear(24, 256), torch.nn.ReLU(), torch.nn.Linear(256, 256), torch.nn.ReLU(),
                               torch.nn.Linear(256, 6), torch.nn.Tanh())


class DmControlVectorEnv(VectorWalkerEnv):
    """The batched env as it was before batched stepping: each member stepped through dm_control's own step."""

    def step(self, actions: np.ndarray) -> VectorStep:
        steps = [env.step(a) for env, a in zip(self.envs, actions)]
        return VectorStep(np.stack([s.observation for s in steps]), np.array([s.reward for s in steps]),
                          np.array([s.timeout for s in steps]), np.stack([s.physics for s in steps]),
                          np.stack([s.features for s in steps]))


def vector_env_steps_per_second(num_envs: int = 16, steps: int = 200, env_class: type = VectorWalkerEnv,
                                threads: int = 1) -> float:
    """Closed-loop rollout steps/s: ``num_envs`` walkers, one policy forward per control step, the
    walkers stepped in ``threads`` threads."""
    set_step_threads(threads)
    env = env_class("walk", list(range(num_envs)), episode_length=10**9)
    actor = _actor()
    obs = env.reset()

    def run():
        nonlocal obs
        for _ in range(steps):
            with torch.no_grad():
                action = actor(torch.as_tensor(obs, dtype=torch.float32)).numpy()
            obs = env.step(action).observation
    return rate(run, num_envs * steps)


def mujoco_rollout_steps_per_second(num_walkers: int = 64, control_steps: int = 100, threads: int = 2) -> float:
    """Open-loop control steps/s of many walkers in MuJoCo's C rollout (10 physics steps each)."""
    physics = WalkerEnv("walk", 0).physics
    model = physics.model.ptr
    datas = [mujoco.MjData(model) for _ in range(threads)]
    state_size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    initial = np.zeros((num_walkers, state_size))
    mujoco.mj_getState(model, physics.data.ptr, initial[0], mujoco.mjtState.mjSTATE_FULLPHYSICS)
    initial[:] = initial[0]
    control = np.repeat(np.random.default_rng(0).uniform(-1, 1, (num_walkers, control_steps, 1, 6)), 10, axis=2)
    control = control.reshape(num_walkers, control_steps * 10, 6)

    def run():
        rollout.rollout(model, datas, initial, control, persistent_pool=True)
    return rate(run, num_walkers * control_steps)


def relabel_rates(n: int = 1_000_000, n_physics: int = 5000) -> tuple[float, float]:
    rng = np.random.default_rng(0)
    physics = WalkerEnv("walk", 0)
    states = []
    physics.reset()
    for _ in range(n_physics):
        states.append(physics.step(rng.uniform(-1, 1, 6)).physics)
    features = np.column_stack([rng.uniform(0, 1.5, n), rng.uniform(-1, 1, n), rng.normal(0, 2, n)])
    big = Dataset(Path("bench"), {"reward_features": features}, {})
    small = Dataset(Path("bench"), {"next_physics": np.array(states)}, {})
    tasks = ["stand", "walk", "run"]
    vectorised = rate(lambda: relabel_rewards(big, tasks, "vectorised"), n * len(tasks))
    replay = rate(lambda: relabel_rewards(small, tasks, "physics"), n_physics * len(tasks), repeats=1)
    return vectorised, replay


def td3_updates_per_second(config: TD3Config, updates: int) -> float:
    agent = TD3(config, 24, 6, seed=0)
    buffer = ReplayBuffer(20_000, 24, 6, 18, 3)
    buffer.observations.normal_(), buffer.next_observations.normal_(), buffer.actions.uniform_(-1, 1)
    buffer.size = buffer.capacity

    def run():
        for _ in range(updates):
            agent.update(buffer.sample(config.batch_size, agent.generator))
    return rate(run, updates)


def td3_config(profile: Path) -> TD3Config:
    return from_mapping(TD3Config, yaml.safe_load(profile.read_text())["collect"]["td3"], "collect.td3")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick-only", action="store_true", help="skip the (slow) thesis-size TD3 update")
    args = parser.parse_args()
    configure_compute(1)
    print(f"torch {torch.__version__}, mujoco {mujoco.__version__}, 1 torch thread per measurement")
    suite, templated = walkers_built_per_second()
    print(f"walkers built: suite.load {suite:,.0f}/s, WalkerEnv from the task's template {templated:,.0f}/s "
          f"({templated / suite:.1f}x)")
    single = env_steps_per_second()
    print(f"dm_control walker, one env:                 {single:10,.0f} steps/s")
    one_policy = vector_env_steps_per_second(num_envs=1, steps=1000)
    print(f"one env + a 256x256 policy per step:        {one_policy:10,.0f} steps/s")
    before = vector_env_steps_per_second(env_class=DmControlVectorEnv)
    print(f"16 envs, dm_control steps (the old path): {before:10,.0f} steps/s  ({before / one_policy:.2f}x one env "
          f"+ policy)")
    for threads in (1, 2):
        vector = vector_env_steps_per_second(threads=threads)
        print(f"VectorWalkerEnv, 16 envs, {threads} step thread(s): {vector:10,.0f} steps/s  ({vector / before:.2f}x "
              f"dm_control steps; {vector / single:.2f}x the bare env)")
    set_step_threads(1)
    for threads in (1, 2):
        batched = mujoco_rollout_steps_per_second(threads=threads)
        print(f"mujoco.rollout, 64 walkers, {threads} thread(s):    {batched:10,.0f} steps/s  "
              f"({batched / single:.2f}x one env; open loop, no observations)")
    vectorised, replay = relabel_rates()
    print(f"relabel, vectorised formula:                {vectorised:10,.0f} transitions/s (target >= 1,000,000)")
    print(f"relabel, physics replay:                    {replay:10,.0f} transitions/s  "
          f"(vectorised is {vectorised / replay:,.0f}x faster)")
    quick = td3_config(ROOT / "params.yaml")
    q = td3_updates_per_second(quick, 100)
    print(f"TD3 update, quick size {list(quick.hidden_sizes)} batch {quick.batch_size}: {q:8.1f} updates/s")
    if not args.quick_only:
        thesis = td3_config(ROOT / "profiles" / "thesis.yaml")
        t = td3_updates_per_second(thesis, 5)
        print(f"TD3 update, thesis size {list(thesis.hidden_sizes)} batch {thesis.batch_size}: {t:8.1f} updates/s "
              f"(quick is {q / t:.0f}x faster per update)")


if __name__ == "__main__":
    main()
