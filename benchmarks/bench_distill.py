"""Speed of distillation and of evaluation rollouts, measured in one run on this machine.

Prints, at the quick (params.yaml) and thesis (profiles/thesis.yaml) student and teacher sizes:
- distillation steps/s (MSE loss, 2 tasks) with the teachers' actions cached once per state (what
  the distill stage does) and with the frozen teachers re-run on every batch (what the reference
  code did), and their ratio;
- a group of R = 1, 2, 4, 8 students trained as one vectorised model (the distill stage's seeds):
  time per update of the group over one student's;
- evaluation env steps/s of a student policy: one walker at a time vs ``rollout_envs`` walkers
  stepped together (one batched policy call per step), and their ratio;
- a group of 3 students with each ranking regulariser (``distill_ranking``, at ``distill.ranking``'s
  settings): time per update over the plain group's;
- reweighted distillation's row draws (``distill.batch_size`` rows over a dataset's 100k states, by
  their weights): the inverse CDF the distiller uses vs ``torch.multinomial``, draws/s and their ratio;
- the curve evaluation of a group of 3 students (5 episodes each, one task): the runs one after
  another vs in one MuJoCo batch (``policies_returns_and_states``), and the policy on 2 torch threads
  vs 1 (what ``rollout.policy_threads`` enforces).

Run: ``python benchmarks/bench_distill.py [--threads N]``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
import yaml
from timing import rate

from mop_core.config import from_mapping
from mop_core.distill.checkpoint import student_policy
from mop_core.distill.config import DistillConfig
from mop_core.distill.distiller import Distiller, cumulative_weights, weighted_rows
from mop_core.distill.ranking import RANKING_LOSSES
from mop_core.distill.states import TaskStates, task_states, teacher_outputs
from mop_core.experiment.variants import Ranking
from mop_core.learning.nn import DeterministicActor
from mop_core.learning.runtime import configure_compute
from mop_core.walker.rollout import episode_returns, policies_returns_and_states, policy_threads, returns_and_states

ROOT = Path(__file__).resolve().parents[1]
STATES = 100_000  # per task (the quick profile's dataset size)


def profile(path: Path) -> tuple[DistillConfig, tuple[int, ...], int]:
    params = yaml.safe_load(path.read_text())
    raw = {k: v for k, v in params["distill"].items()
           if k not in ("losses", "pairings", "seeds", "teacher_seed", "threads", "schedule")}
    config = from_mapping(DistillConfig, raw | {"loss": "mse"}, "distill")
    return config, tuple(params["train_teachers"]["pbrl"]["hidden_sizes"]), params["eval"]["rollout_envs"]


class RecomputingDistiller(Distiller):
    """The same step, but every batch's teacher actions come from a fresh teacher forward pass."""

    def __init__(self, teachers: list[torch.nn.Module], *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.teachers = teachers

    def loss(self, rows, tasks=None):
        tasks = list(range(len(self.tasks))) if tasks is None else list(tasks)
        cached = self.targets
        live = [list(run) for run in cached]
        for run, run_rows in enumerate(rows):
            for t, r in zip(tasks, run_rows):
                target = cached[run][t]
                live[run][t] = TaskStates(target.task, target.states[r],
                                          teacher_outputs(self.teachers[t], target.states[r])[0], None, target.source)
        self.targets = live
        try:
            return super().loss([[torch.arange(len(r)) for r in run_rows] for run_rows in rows], tasks)
        finally:
            self.targets = cached


def _targets(teacher_sizes: tuple[int, ...], device: str = "cpu") -> tuple[list[torch.nn.Module], list[TaskStates]]:
    torch.manual_seed(0)
    teachers = [DeterministicActor(24, 6, teacher_sizes).requires_grad_(False) for _ in range(2)]
    states = [torch.randn(STATES, 24).numpy() for _ in teachers]
    return teachers, [task_states(f"task{i}", s, t, {}, device) for i, (s, t) in enumerate(zip(states, teachers))]


def distill_rates(name: str, config: DistillConfig, teacher_sizes: tuple[int, ...], steps: int) -> None:
    teachers, targets = _targets(teacher_sizes)
    cached = Distiller(config, [targets], 24, 6, [0])
    live = RecomputingDistiller(teachers, config, [targets], 24, 6, [0])

    def run(d):
        return lambda: [d.update() for _ in range(steps)]

    fast, slow = rate(run(cached), steps), rate(run(live), steps)
    print(f"{name}: distill steps/s (student {list(config.student.hidden_sizes)}, teacher {list(teacher_sizes)}, "
          f"batch {config.batch_size}/task x 2 tasks): cached {fast:.0f}, recomputed {slow:.0f}, "
          f"ratio {fast / slow:.2f}x")


def group_rates(name: str, config: DistillConfig, teacher_sizes: tuple[int, ...], steps: int,
                runs: tuple[int, ...] = (1, 2, 4, 8), device: str = "cpu") -> dict[int, float]:
    """Seconds per update of a group of R students (each run its own seed and sampling stream) over
    seconds per update of one student: the cost of R seeds trained as one model, relative to one."""
    _, targets = _targets(teacher_sizes, device)
    seconds = {}
    for r in runs:
        group = Distiller(config, [targets] * r, 24, 6, list(range(r)), device=device)
        seconds[r] = 1.0 / rate(lambda: ([group.update() for _ in range(steps)], _sync(device)), steps)
    cells = ", ".join(f"R={r}: {seconds[r] / seconds[1]:.2f}x ({seconds[1] * r / seconds[r]:.2f}x per run)"
                      for r in runs)
    print(f"{name}: student group (MSE, {list(config.student.hidden_sizes)}, batch {config.batch_size}/task x 2 "
          f"tasks, {device}) time per update / one run's: {cells}; one run {1e3 * seconds[1]:.2f} ms")
    return seconds


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def rollout_rates(envs: int, hidden: tuple[int, ...], episode_length: int = 200) -> None:
    from mop_core.distill.student import Student, StudentConfig

    student = Student(StudentConfig(hidden_sizes=hidden), 24, 6, 2).eval()
    policy = student_policy(student, 0, torch.device("cpu"))
    single = rate(lambda: episode_returns(policy, "walk", [0], episode_length, 1), episode_length, repeats=2)
    batched = rate(lambda: episode_returns(policy, "walk", list(range(envs)), episode_length, envs),
                   episode_length * envs, repeats=2)
    print(f"eval env steps/s (student {list(hidden)}): one env {single:.0f}, {envs} envs batched {batched:.0f}, "
          f"ratio {batched / single:.2f}x")


def ranking_rates(name: str, config: DistillConfig, teacher_sizes: tuple[int, ...], steps: int, runs: int = 3
                  ) -> None:
    """Time per update of a group of ``runs`` students with each ranking regulariser over the plain group's."""
    _, targets = _targets(teacher_sizes)
    seconds = {}
    for loss in ["", *RANKING_LOSSES]:
        group = Distiller(Ranking(loss).apply(config) if loss else config, [targets] * runs, 24, 6, list(range(runs)))
        seconds[loss] = 1.0 / rate(lambda: [group.update() for _ in range(steps)], steps)
    cells = ", ".join(f"{loss} {seconds[loss] / seconds['']:.2f}x" for loss in seconds if loss)
    print(f"{name}: ranking regulariser ({config.ranking.states} state(s)/task/step, {runs} runs, student "
          f"{list(config.student.hidden_sizes)}) time per update / plain group's: {cells}; plain "
          f"{1e3 * seconds['']:.2f} ms")


def group_eval_rates(hidden: tuple[int, ...], runs: int = 3, episodes: int = 5, episode_length: int = 300) -> None:
    """A group's curve evaluation: its runs' rollouts one after another vs stepped together, and the
    policy on 2 torch threads vs 1."""
    from mop_core.distill.student import Student, StudentConfig

    torch.manual_seed(0)
    policies = [student_policy(Student(StudentConfig(hidden_sizes=hidden), 24, 6, 2).eval(), 0, torch.device("cpu"))
                for _ in range(runs)]
    seeds = list(range(episodes))

    def two_threads(policy):
        def call(obs):
            with policy_threads(2):
                return policy(obs)
        return call

    steps = runs * episodes * episode_length
    one_by_one_2 = rate(lambda: [returns_and_states(two_threads(p), "walk", seeds, episode_length) for p in policies],
                        steps, repeats=2)
    one_by_one = rate(lambda: [returns_and_states(p, "walk", seeds, episode_length) for p in policies], steps,
                      repeats=2)
    together = rate(lambda: policies_returns_and_states(policies, "walk", seeds, episode_length), steps, repeats=2)
    print(f"group evaluation env steps/s ({runs} students {list(hidden)}, {episodes} episodes each): runs one by one "
          f"with the policy on 2 torch threads {one_by_one_2:.0f}, on 1 thread {one_by_one:.0f} "
          f"({one_by_one / one_by_one_2:.2f}x), runs in one batch {together:.0f} ({together / one_by_one_2:.2f}x)")


def weighted_draw_rates(batch_size: int, rows: int = STATES, draws: int = 2000) -> None:
    generator = torch.Generator().manual_seed(0)
    weights = torch.rand(rows, generator=generator, dtype=torch.float64).pow(8)  # heavy-tailed, as density ratios
    cdf = cumulative_weights(weights)
    assert cdf is not None

    def inverse_cdf():
        for _ in range(draws):
            weighted_rows(cdf, batch_size, generator)

    def multinomial():
        for _ in range(draws):
            torch.multinomial(weights, batch_size, replacement=True, generator=generator)

    ours, theirs = rate(inverse_cdf, draws), rate(multinomial, draws)
    print(f"weighted row draws/s ({batch_size} of {rows} rows): inverse CDF {ours:.0f}, torch.multinomial "
          f"{theirs:.0f} ({ours / theirs:.1f}x)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1, help="torch threads (the stage's distill.threads)")
    args = parser.parse_args()
    configure_compute(args.threads)
    print(f"torch {torch.__version__}, {args.threads} thread(s)")
    quick, quick_teacher, envs = profile(ROOT / "params.yaml")
    thesis, thesis_teacher, _ = profile(ROOT / "profiles" / "thesis.yaml")
    distill_rates("quick", quick, quick_teacher, steps=100)
    distill_rates("thesis", thesis, thesis_teacher, steps=20)
    group_rates("quick", quick, quick_teacher, steps=50)
    group_rates("thesis", thesis, thesis_teacher, steps=10)
    rollout_rates(envs, quick.student.hidden_sizes)
    ranking_rates("quick", quick, quick_teacher, steps=30)
    weighted_draw_rates(quick.batch_size)
    group_eval_rates(quick.student.hidden_sizes)


if __name__ == "__main__":
    main()
