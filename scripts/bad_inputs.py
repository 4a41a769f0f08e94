"""Try bad inputs against every stage of a tiny study and count how each is answered.

    python scripts/bad_inputs.py [--workspace DIR] [--keep] [--json OUT]

Builds a tiny study (profiles/tiny.yaml, a real ``dvc repro``) in a scratch copy of the repository
(or reuses ``--workspace``), then, one case at a time, breaks one thing - a parameter, a command
line argument, a file (empty, truncated, garbled, swapped, edited) or the process environment (a run
already in progress) - runs the stage a user would run next, restores the workspace and classifies
the answer:

- **named**: exit status 2, no traceback, one ``error:`` line that names the key, argument or file;
- **silent**: exit status 0 (the stage went on as if nothing was wrong);
- **unclear**: anything else (a traceback, another status, an error that does not name the culprit).

Each stage runs from the workspace with its own ``mop_core`` first on the path, so the script
measures the code of the workspace it was given (e.g. an older commit's checkout). Prints a table
per stage and the totals; ``--json`` writes every case's outcome and the error line it produced.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import yaml

ROOT = Path(__file__).resolve().parents[1]
PROJECT = ["dvc.yaml", "stages", "mop_core", "profiles", "pyproject.toml", ".dvc/config", ".dvc/.gitignore",
           ".gitignore", ".dvcignore"]
STAGE = {
    "params": ["stages/check_params.py"],
    "collect": ["stages/collect.py"],
    "relabel": ["stages/relabel.py"],
    "teacher": ["stages/train_teachers.py", "--level", "medium", "--actor", "deterministic", "--tasks", "stand",
                "--seeds", "0"],
    "multitask": ["stages/train_multitask.py", "--level", "medium"],
    "student_inputs": ["stages/student_inputs.py"],
    "distill": ["stages/distill.py", "--entry", "mse-medium"],
    "compose": ["stages/compose.py"],
    "state_shift": ["stages/state_shift.py"],
    "eval": ["stages/eval.py"],
    "shared_computation": ["stages/shared_computation.py"],
    "report": ["stages/report.py"],
}


@dataclass
class Case:
    name: str  # what is wrong
    stage: str  # the STAGE key run afterwards
    breaks: Callable[[Path], None]  # breaks the workspace (restored afterwards)
    culprit: str  # what the error line must name
    args: tuple[str, ...] | None = None  # replaces the stage's command line arguments


# ---- ways to break things --------------------------------------------------------------------------
def set_param(key: str, value) -> Callable[[Path], None]:
    def breaks(ws: Path) -> None:
        params = yaml.safe_load((ws / "params.yaml").read_text())
        *path, last = key.split(".")
        node = params
        for part in path:
            node = node[part]
        node[last] = value
        (ws / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    return breaks


def write_params_text(text: str) -> Callable[[Path], None]:
    return lambda ws: (ws / "params.yaml").write_text(text)


def empty(rel: str) -> Callable[[Path], None]:
    return lambda ws: (ws / rel).write_bytes(b"")


def truncate(rel: str) -> Callable[[Path], None]:
    def breaks(ws: Path) -> None:
        data = (ws / rel).read_bytes()
        (ws / rel).write_bytes(data[: len(data) // 2])
    return breaks


def garble(rel: str) -> Callable[[Path], None]:
    return lambda ws: (ws / rel).write_bytes(b"\x00garbage\xff" * 64)


def copy_over(src: str, dst: str) -> Callable[[Path], None]:
    return lambda ws: shutil.copy(ws / src, ws / dst)


def remove(rel: str) -> Callable[[Path], None]:
    return lambda ws: (ws / rel).unlink()


def edit_hdf5(rel: str, how: str) -> Callable[[Path], None]:
    def breaks(ws: Path) -> None:
        import h5py

        with h5py.File(ws / rel, "a") as h5:
            if how == "tamper":
                h5["actions"][3, 1] = 0.5 * float(h5["actions"][3, 1])
            elif how == "shorten":
                observations = h5["observations"][()]
                del h5["observations"]
                h5["observations"] = observations[:-7]
            elif how == "drop_key":
                del h5["next_observations"]
            elif how == "nan":
                h5["observations"][4, 2] = float("nan")
            elif how == "attr":
                del h5.attrs["level"]
    return breaks


def held(stage: str) -> Callable[[Path], None]:
    """Another process holds this run (a lock file naming a live pid); only code with run locks sees it."""
    def breaks(ws: Path) -> None:
        argv = STAGE[stage]
        name = "-".join([Path(argv[0]).stem, *(a.lstrip("-") for a in argv[1:])])
        lock = ws / "data" / "locks" / f"{name}.lock"
        lock.parent.mkdir(parents=True, exist_ok=True)
        holder = subprocess.Popen([sys.executable, "-c", "import fcntl, sys, time; f = open(sys.argv[1], 'a+'); "
                                   "fcntl.flock(f, fcntl.LOCK_EX); f.write('pid %d: holder\\n' % __import__('os')"
                                   ".getpid()); f.flush(); print('ok', flush=True); time.sleep(120)", str(lock)],
                                  stdout=subprocess.PIPE, text=True)
        holder.stdout.readline()
        HOLDERS.append(holder)
    return breaks


HOLDERS: list[subprocess.Popen] = []


def cases() -> list[Case]:  # noqa: C901 (a flat list of cases)
    p = []

    def param(key, value, stage, culprit=None):
        p.append(Case(f"{key} = {value!r}", stage, set_param(key, value), culprit or key))

    # study
    for key, value in [("study.tasks", []), ("study.tasks", ["stand", "stand"]), ("study.tasks", ["fly"]),
                       ("study.tasks", "stand"), ("study.levels", ["replay"]), ("study.levels", ["medium", "medium"]),
                       ("study.seed", -1), ("study.seed", 1.5), ("study.episode_length", 0),
                       ("study.device", "tpu"), ("study.progress", "yes"), ("study.task", ["stand"])]:
        param(key, value, "collect")
    # collect
    for key, value in [("collect.td3.learning_rate", float("inf")), ("collect.td3.learning_rate", float("nan")),
                       ("collect.td3.learning_rate", -1.0), ("collect.td3.hidden_sizes", []),
                       ("collect.td3.hidden_sizes", [0]), ("collect.td3.batch_size", 0),
                       ("collect.td3.batch_size", 10**9), ("collect.td3.gamma", 1.5), ("collect.td3.tau", 0.0),
                       ("collect.td3.policy_delay", 0), ("collect.td3.exploration_noise", float("nan")),
                       ("collect.td3.lr", 0.001), ("collect.schedule.total_steps", 0),
                       ("collect.schedule.medium_step", 10**6), ("collect.schedule.medium_target_return", float("nan")),
                       ("collect.schedule.warmup_steps", -1), ("collect.schedule.eval_every", 0),
                       ("collect.schedule.total_step", 100), ("collect.datasets.expert_episodes", 0),
                       ("collect.datasets.action_noise", float("inf")), ("collect.datasets.action_noise", -1.0),
                       ("collect.parallel.workers", 0), ("collect.parallel.threads_per_worker", "2")]:
        param(key, value, "collect")
    # relabel
    for key, value in [("relabel.method", "fast"), ("relabel.tolerance", float("inf")), ("relabel.tolerance", -1.0),
                       ("relabel.physics_check_transitions", -5), ("relabel.tol", 1e-6)]:
        param(key, value, "relabel")
    # train_teachers
    for key, value in [("train_teachers.pbr", {"batch_size": 16}), ("train_teachers.thread", 2),
                       ("train_teachers.actors", ["det"]), ("train_teachers.actors", []),
                       ("train_teachers.seeds", [-1]), ("train_teachers.threads", 0),
                       ("train_teachers.pbrl.learning_rate", float("inf")), ("train_teachers.pbrl.batch_size", 10**9),
                       ("train_teachers.pbrl.ensemble_size", 1), ("train_teachers.pbrl.gamma", 1.0),
                       ("train_teachers.pbrl.target_entropy", float("nan")),
                       ("train_teachers.pbrl.log_std_max", float("inf")), ("train_teachers.pbrl.log_std_min", 1.0),
                       ("train_teachers.pbrl.beta_ood_decay", 0.0), ("train_teachers.pbrl.ood_actions", -1),
                       ("train_teachers.pbrl.hidden_sizes", [-16]), ("train_teachers.pbrl.actor", "gaussian"),
                       ("train_teachers.pbrl.critic_tau", float("nan")), ("train_teachers.schedule.steps", 0),
                       ("train_teachers.schedule.eval_every", 0), ("train_teachers.schedule.rollout_envs", 0),
                       ("train_teachers.schedule.stepz", 10)]:
        param(key, value, "teacher")
    for key, value in [("train_teachers.seeds", [0, 0]), ("train_teachers.actors", ["deterministic", "gaussian",
                                                                                     "deterministic"])]:
        param(key, value, "params")  # a grid list: the params stage (dvc repro runs it first)
    # train_multitask
    for key, value in [("train_multitask.levels", ["expert"]), ("train_multitask.levels", ["medium", "medium"]),
                       ("train_multitask.seeds", [0, 0]), ("train_multitask.seeds", [-1]),
                       ("train_multitask.level", ["medium"])]:
        param(key, value, "multitask")
    # distill
    for key, value in [("distill.seeds", [0, 0]), ("distill.seeds", []), ("distill.losses", ["mse", "mse"]),
                       ("distill.losses", ["l1"]), ("distill.pairings", ["medium", "medium+medium"]),
                       ("distill.pairings", ["expert"]), ("distill.pairings", ["medium+medium+medium"]),
                       ("distill.teacher_seed", 5), ("distill.threads", 0), ("distill.learning_rate", float("inf")),
                       ("distill.learning_rate", 0.0), ("distill.lr_schedule", "linear"), ("distill.batch_size", 0),
                       ("distill.batch_size", 10**9), ("distill.num_states", -1), ("distill.state_source", "replay"),
                       ("distill.probe_states", -1), ("distill.probe_source", "x"), ("distill.q_reduction", "max"),
                       ("distill.student.hidden_sizes", []), ("distill.student.log_std_max", float("nan")),
                       ("distill.schedule.steps", 0), ("distill.loss", "mse"), ("distill.step_per_tasks", True)]:
        param(key, value, "distill")
    # eval, shared_computation
    for key, value in [("eval.episodes", 1), ("eval.rollout_envs", 0), ("eval.workers", 0), ("eval.bootstrap_reps", 0),
                       ("eval.gaussian_student_action", "median"), ("eval.episode", 3)]:
        param(key, value, "eval")
    for key, value in [("shared_computation.episodes", 0), ("shared_computation.threads", 0),
                       ("shared_computation.workers", -1), ("shared_computation.episode", 3)]:
        param(key, value, "shared_computation")
    # the params file itself
    p.append(Case("an unknown section 'distil'", "collect", lambda ws: (ws / "params.yaml").write_text(
        (ws / "params.yaml").read_text() + "distil:\n  seeds: [0]\n"), "distil"))
    p.append(Case("params.yaml is not YAML", "collect", write_params_text("study: {tasks: [stand\n"), "params.yaml"))
    p.append(Case("params.yaml is empty", "collect", write_params_text(""), "params.yaml"))
    p.append(Case("params.yaml is a list", "relabel", write_params_text("- study\n"), "params.yaml"))
    # command lines
    teacher = STAGE["teacher"][1:]
    for args, culprit in [(("--tasks", "fly"), "--tasks"), (("--level", "expert"), "--level"),
                          (("--actor", "stochastic"), "--actor"), (("--seeds", "-1"), "--seed")]:
        changed = list(teacher)
        changed[changed.index(args[0]) + 1] = args[1]
        p.append(Case(f"train_teachers {' '.join(args)}", "teacher", lambda ws: None, culprit, tuple(changed)))
    distill = STAGE["distill"][1:]
    for args, culprit in [(("--entry", "mse-expert"), "--entry"), (("--entry", "l2-medium"), "--entry"),
                          (("--seeds", "-2"), "--seeds")]:
        changed = [*distill, "--seeds", "0"] if args[0] == "--seeds" else list(distill)
        changed[changed.index(args[0]) + 1] = args[1]
        p.append(Case(f"distill {' '.join(args)}", "distill", lambda ws: None, culprit, tuple(changed)))
    multitask = STAGE["multitask"][1:]
    for args, culprit in [(("--level", "expert"), "--level"), (("--seeds", "5"), "--seeds")]:
        changed = [*multitask, "--seeds", "0"] if args[0] == "--seeds" else list(multitask)
        changed[changed.index(args[0]) + 1] = args[1]
        p.append(Case(f"train_multitask {' '.join(args)}", "multitask", lambda ws: None, culprit, tuple(changed)))
    # files
    ds, rl = "data/datasets/stand-medium.hdf5", "data/relabelled/stand-medium.hdf5"
    teacher_pt = "data/teachers/medium-deterministic/stand-medium-deterministic-0.pt"
    student_pt = "data/students/mse-medium/mse-medium-0.pt"
    for how, fault in [("empty", empty), ("truncated", truncate), ("garbled", garble)]:
        p.append(Case(f"dataset {how}", "relabel", fault(ds), ds))
        p.append(Case(f"relabel file {how}", "teacher", fault(rl), rl))
        p.append(Case(f"teacher checkpoint {how} (distill)", "distill", fault(teacher_pt), teacher_pt))
        p.append(Case(f"teacher checkpoint {how} (eval)", "eval", fault(teacher_pt), teacher_pt))
        p.append(Case(f"student checkpoint {how} (shared_computation)", "shared_computation", fault(student_pt),
                      student_pt))
        p.append(Case(f"student checkpoint {how} (eval)", "eval", fault(student_pt), student_pt))
        p.append(Case(f"behaviour snapshot {how}", "eval", fault("data/behaviour/walk/expert.pt"),
                      "data/behaviour/walk/expert.pt"))
        p.append(Case(f"multitask checkpoint {how}", "eval", fault("data/multitask/medium/medium-0.pt"),
                      "data/multitask/medium/medium-0.pt"))
        p.append(Case(f"collect metrics {how}", "eval", fault("results/collect/metrics.json"),
                      "results/collect/metrics.json"))
        p.append(Case(f"student metrics {how} (shared_computation)", "shared_computation",
                      fault("results/students/metrics/mse-medium/mse-medium-0.json"),
                      "results/students/metrics/mse-medium/mse-medium-0.json"))
        p.append(Case(f"student curve {how} (eval)", "eval",
                      fault("results/students/curves/mse-medium/mse-medium-0.tsv"),
                      "results/students/curves/mse-medium/mse-medium-0.tsv"))
        p.append(Case(f"eval metrics {how} (report)", "report", fault("results/eval/metrics.json"),
                      "results/eval/metrics.json"))
    for how in ("tamper", "shorten", "drop_key", "nan", "attr"):
        p.append(Case(f"dataset {how}", "relabel", edit_hdf5(ds, how), ds))
    p.append(Case("walk's dataset in stand's slot (relabel)", "relabel",
                  copy_over("data/datasets/walk-medium.hdf5", ds), ds))
    p.append(Case("expert data in the medium slot (relabel)", "relabel",
                  copy_over("data/datasets/stand-expert.hdf5", ds), ds))
    p.append(Case("relabel file of another dataset", "teacher", copy_over("data/relabelled/walk-medium.hdf5", rl), rl))
    p.append(Case("walk's teacher in stand's slot", "distill",
                  copy_over(teacher_pt.replace("stand-", "walk-"), teacher_pt), teacher_pt))
    p.append(Case("gaussian teacher in the deterministic slot", "distill",
                  copy_over("data/teachers/medium-gaussian/stand-medium-gaussian-0.pt", teacher_pt), teacher_pt))
    p.append(Case("teachers trained with another learning rate", "distill",
                  set_param("train_teachers.pbrl.learning_rate", 0.002), teacher_pt))
    p.append(Case("teachers trained for fewer steps", "distill", set_param("train_teachers.schedule.steps", 80),
                  teacher_pt))
    p.append(Case("dataset missing", "teacher", remove(ds), ds))
    p.append(Case("student checkpoint missing", "eval", remove(student_pt), student_pt))
    p.append(Case("a student's run already in progress", "distill", held("distill"), "locks/distill"))
    p.append(Case("eval already in progress", "eval", held("eval"), "locks/eval"))
    p.append(Case("a teacher diverges (learning rate 1e30)", "teacher",
                  set_param("train_teachers.pbrl.learning_rate", 1e30), "teachers medium-deterministic"))
    return p + provenance_cases()


def rerun(stage: str, key: str, value) -> Callable[[Path], None]:
    """A stage's outputs rebuilt with ``key`` = ``value``, then params.yaml as it was: files that look
    right but were made under other settings."""
    def breaks(ws: Path) -> None:
        before = (ws / "params.yaml").read_text()
        set_param(key, value)(ws)
        result = run([sys.executable, *STAGE[stage]], ws, timeout=300)
        (ws / "params.yaml").write_text(before)
        if result.returncode != 0:
            raise RuntimeError(f"{stage} with {key}={value!r} failed: {result.stderr[-500:]}")
    return breaks


def write_text(rel: str, text: str) -> Callable[[Path], None]:
    return lambda ws: (ws / rel).write_text(text)


def provenance_cases() -> list[Case]:
    """The later families' inputs swapped, rebuilt under other settings or emptied (issue 40): composed
    datasets, reference episodes, checkpoints of other widths, emptied records."""
    online, random99 = "data/composed/stand-medium-online.hdf5", "data/composed/stand-medium-random99.hdf5"
    reference, expert = "data/composed/stand-medium-reference.hdf5", "data/datasets/stand-expert.hdf5"
    teacher_pt = "data/teachers/medium-deterministic/stand-medium-deterministic-0.pt"
    student_pt, w8_pt = "data/students/mse-medium/mse-medium-0.pt", "data/students/mse-w8-medium/mse-w8-medium-0.pt"
    on_online, reweight = ("--entry", "mse-on_online_w8-medium"), ("--entry", "mse-reweight_random99_w8-medium")
    p = []
    for name, breaks in [("walk's composed online data in stand's slot",
                          copy_over(online.replace("stand-", "walk-"), online)),
                         ("random99 in online's slot", copy_over(random99, online)),
                         ("collect's stand-medium in the composed online slot",
                          copy_over("data/datasets/stand-medium.hdf5", online)),
                         ("composed with state_shift.episodes 4, params say 2", rerun("compose", "state_shift.episodes",
                                                                                      4))]:
        p.append(Case(f"{name} (student_inputs)", "student_inputs", breaks, online))
        p.append(Case(f"{name} (distill)", "distill", breaks, online, on_online))
    p.append(Case("composed with state_shift.episodes 4, params say 2 (state_shift)", "state_shift",
                  rerun("compose", "state_shift.episodes", 4), online))
    walk_reference = copy_over(reference.replace("stand-", "walk-"), reference)
    p.append(Case("walk's reference episodes in stand's slot (state_shift)", "state_shift", walk_reference, reference))
    p.append(Case("walk's reference episodes in stand's slot (reweighted students)", "distill", walk_reference,
                  reference, reweight))
    p.append(Case("walk-expert in stand-expert's slot (state_shift)", "state_shift",
                  copy_over(expert.replace("stand-", "walk-"), expert), expert))
    other_widths = rerun("teacher", "train_teachers.pbrl.hidden_sizes", [8, 8])
    p.append(Case("a teacher of other widths (compose)", "compose", other_widths, teacher_pt))
    p.append(Case("a teacher of other widths (eval)", "eval", other_widths, teacher_pt))
    for stage in ("eval", "shared_computation"):
        p.append(Case(f"a width-16 student in the width-8 slot ({stage})", stage, copy_over(student_pt, w8_pt), w8_pt))
    p.append(Case("state_shift metrics emptied to {} (report)", "report",
                  write_text("results/state_shift/metrics.json", "{}"), "results/state_shift/metrics.json"))
    p.append(Case("eval metrics a JSON list (report)", "report", write_text("results/eval/metrics.json", "[]"),
                  "results/eval/metrics.json"))
    return p


# ---- running -------------------------------------------------------------------------------------
def run(cmd: list[str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    env = os.environ | {"MOP_PROGRESS": "0", "PYTHONPATH": str(cwd),
                        "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def copy_project(source: Path, target: Path) -> None:
    """The files a study needs (code, DAG, profiles), with the tiny profile as params.yaml."""
    for name in PROJECT:
        src = source / name
        if src.is_dir():
            shutil.copytree(src, target / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        elif src.exists():
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(src, target / name)
    shutil.copy(source / "profiles" / "tiny.yaml", target / "params.yaml")


def committed_project(source: Path, target: Path) -> Path:
    """:func:`copy_project`, committed in a new git repository (what DVC experiments and mop-cluster need)."""
    copy_project(source, target)
    for args in (["init", "-q"], ["add", "-A"], ["-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "tiny"]):
        subprocess.run(["git", *args], cwd=target, check=True, capture_output=True)
    return target


def build_workspace(source: Path, target: Path) -> None:
    committed_project(source, target)
    result = run(["dvc", "repro"], target, timeout=3600)
    if result.returncode != 0:
        raise SystemExit(f"dvc repro failed in {target}:\n{result.stdout}\n{result.stderr}")


def classify(result: subprocess.CompletedProcess | None, culprit: str) -> tuple[str, str]:
    if result is None:
        return "unclear", "timed out"
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    last = lines[-1] if lines else ""
    if result.returncode == 0:
        return "silent", ""
    named = (result.returncode == 2 and "Traceback" not in result.stderr and culprit in last
             and (last.startswith("error:") or "error:" in last))
    return ("named" if named else "unclear"), last[:300]


def snapshot(ws: Path, backup: Path | None = None) -> Path:
    """A copy of ``ws``'s params, data and results in ``backup`` (a new folder; default: a temporary one,
    which the caller removes) for :func:`restore`."""
    backup = Path(tempfile.mkdtemp(prefix="bad-inputs-backup-")) if backup is None else backup
    backup.mkdir(parents=True, exist_ok=True)
    for name in ("params.yaml", "data", "results"):
        src = ws / name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, backup / name)
    return backup


def restore(ws: Path, backup: Path) -> None:
    for name in ("data", "results"):
        shutil.rmtree(ws / name, ignore_errors=True)
        shutil.copytree(backup / name, ws / name)
    shutil.copy(backup / "params.yaml", ws / "params.yaml")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workspace", type=Path, help="a tiny study already reproduced (default: build one)")
    parser.add_argument("--source", type=Path, default=ROOT, help="the checkout whose code is measured")
    parser.add_argument("--keep", action="store_true", help="keep the scratch workspace")
    parser.add_argument("--json", type=Path, help="write every case's outcome here")
    args = parser.parse_args()
    ws = args.workspace
    if ws is None:
        ws = Path(tempfile.mkdtemp(prefix="bad-inputs-"))
        started = time.perf_counter()
        build_workspace(args.source.resolve(), ws)
        print(f"tiny study reproduced in {ws} ({time.perf_counter() - started:.0f} s)", flush=True)
    backup = snapshot(ws)
    outcomes = []
    try:
        for case in cases():
            case.breaks(ws)
            args_ = case.args if case.args is not None else STAGE[case.stage][1:]
            cmd = [sys.executable, STAGE[case.stage][0], *args_]
            try:
                result = run(cmd, ws, timeout=300)
            except subprocess.TimeoutExpired:
                result = None
            finally:
                for holder in HOLDERS:
                    holder.kill()
                    holder.wait()
                HOLDERS.clear()
                restore(ws, backup)
            verdict, line = classify(result, case.culprit)
            outcomes.append({"case": case.name, "stage": case.stage, "verdict": verdict, "error": line})
            print(f"{verdict:8s} {case.stage:18s} {case.name}: {line[:150]}", flush=True)
    finally:
        shutil.rmtree(backup, ignore_errors=True)
        if args.workspace is None and not args.keep:
            shutil.rmtree(ws, ignore_errors=True)
    by_stage: dict[str, dict[str, int]] = {}
    for o in outcomes:
        counts = by_stage.setdefault(o["stage"], {"tried": 0, "named": 0, "silent": 0, "unclear": 0})
        counts["tried"] += 1
        counts[o["verdict"]] += 1
    print("\n| stage | tried | named clearly | silent | unclear |\n|---|---|---|---|---|")
    for stage, c in by_stage.items():
        print(f"| {stage} | {c['tried']} | {c['named']} | {c['silent']} | {c['unclear']} |")
    total = {k: sum(c[k] for c in by_stage.values()) for k in ("tried", "named", "silent", "unclear")}
    print(f"| **all** | {total['tried']} | {total['named']} | {total['silent']} | {total['unclear']} |")
    if args.json:
        args.json.write_text(json.dumps({"totals": total, "by_stage": by_stage, "cases": outcomes}, indent=2) + "\n")


if __name__ == "__main__":
    main()
