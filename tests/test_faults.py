"""Faults a demanding user meets: damaged or mismatched files, NaNs, full disks, leftover
temporary files, concurrent and orphaned processes. Each case once failed silently, or with an
error that did not name its file."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import pytest
import torch
from conftest import ROOT

from mop_core.config import InputFileError, OutputFileError
from mop_core.data import DatasetError, read_dataset, read_dataset_attrs, read_json, write_json
from mop_core.learning.runtime import TrainingDivergedError
from mop_core.learning.schedule import TrainSchedule
from mop_core.learning.training import RunPaths, train_loop
from mop_core.policies import load_policy
from mop_core.storage.artifacts import load_checkpoint, read_curve, save_checkpoint


# ---- damaged files name themselves ----------------------------------------------------------------
@pytest.mark.parametrize("damage", ["empty", "truncated", "garbage", "json"])
def test_a_damaged_checkpoint_names_its_file(tiny_teachers, tmp_path, damage):
    from mop_core.teacher_policies import load_teacher

    checkpoints, _ = tiny_teachers
    good = checkpoints[("stand", "deterministic")].read_bytes()
    path = tmp_path / "teacher.pt"
    path.write_bytes({"empty": b"", "truncated": good[: len(good) // 2], "garbage": b"not a checkpoint\n" * 9,
                      "json": b'{"kind": "pbrl_teacher"}'}[damage])
    with pytest.raises(InputFileError, match=f"^{path}: "):
        load_teacher(path)
    with pytest.raises(InputFileError, match=f"^{path}: "):
        load_policy(path)


def test_a_checkpoint_of_another_kind_names_its_file(tiny_teachers):
    checkpoints, _ = tiny_teachers
    path = checkpoints[("stand", "deterministic")]
    with pytest.raises(InputFileError, match=f"^{path}: expected a 'mop_student' checkpoint, found 'pbrl_teacher'"):
        load_checkpoint(path, "mop_student")


@pytest.mark.parametrize("content", ["", '{"return_mean": 1.', "\x00\x01garbage"])
def test_a_damaged_json_names_its_file(tmp_path, content):
    path = tmp_path / "metrics.json"
    path.write_text(content)
    with pytest.raises(InputFileError, match=f"^{path}: not valid JSON"):
        read_json(path)
    with pytest.raises(InputFileError, match=f"^{tmp_path / 'missing.json'}: file not found"):
        read_json(tmp_path / "missing.json")


@pytest.mark.parametrize("content,defect", [("", "empty or garbled"), ("step\treturn_mean\n10\t3.0\n20\n", "line 3"),
                                            ("garbage\n1\n", "no 'step' column")])
def test_a_damaged_curve_names_its_file(tmp_path, content, defect):
    path = tmp_path / "curve.tsv"
    path.write_text(content)
    with pytest.raises(InputFileError, match=f"^{path}: .*{defect}"):
        read_curve(path)


def _copy(path: Path, tmp_path: Path) -> Path:
    copy = tmp_path / path.name
    shutil.copy(path, copy)
    return copy


def test_a_shortened_array_is_named_as_itself(tiny_collected, tmp_path):
    root, _ = tiny_collected
    path = _copy(root / "datasets" / "stand-medium.hdf5", tmp_path)
    with h5py.File(path, "a") as h5:
        observations = h5["observations"][()]
        del h5["observations"]
        h5["observations"] = observations[:-10]
    with pytest.raises(DatasetError, match=rf"^{path}: 'observations' has {len(observations) - 10} rows, the other "
                                           rf"arrays {len(observations)}"):
        read_dataset(path)


# ---- wrong data in the right place ----------------------------------------------------------------
def test_a_dataset_in_another_task_or_levels_slot_is_refused(tiny_collected, tmp_path):
    from mop_core.agents.pbrl import PBRLConfig
    from mop_core.relabel import RelabelConfig, relabel_dataset
    from mop_core.teachers import DataSource, TeacherConfig, train_teacher

    root, _ = tiny_collected
    stand_medium = root / "datasets" / "stand-medium.hdf5"
    read_dataset(stand_medium, task="stand", level="medium")
    with pytest.raises(DatasetError, match="holds stand-medium data .* expected task 'walk'"):
        read_dataset(stand_medium, task="walk")
    with pytest.raises(DatasetError, match="holds stand-medium data .* expected level 'expert'"):
        read_dataset(stand_medium, level="expert")
    relabel = tmp_path / "relabel.hdf5"
    config = RelabelConfig(physics_check_transitions=0)
    with pytest.raises(DatasetError, match="expected task 'walk'"):
        relabel_dataset(stand_medium, relabel, ["stand", "walk"], config, source_task="walk", level="medium")
    relabel_dataset(stand_medium, relabel, ["stand", "walk"], config, source_task="stand", level="medium")
    teacher = TeacherConfig(PBRLConfig(hidden_sizes=(8,), batch_size=8), TrainSchedule(steps=2, rollout_envs=1), 50)
    paths = RunPaths(*(tmp_path / name for name in ("t.pt", "m.json", "c.tsv", "r.pt")))
    with pytest.raises(DatasetError, match="expected level 'expert'"):  # medium data in the expert slot
        train_teacher("stand", DataSource(stand_medium, relabel, "stand", "stand", "expert"), teacher, 0, 0, paths)
    assert not paths.checkpoint.exists()


def test_relabel_verifies_the_datasets_checksum(tiny_collected, tmp_path):
    from mop_core.relabel import RelabelConfig, relabel_dataset

    root, _ = tiny_collected
    path = _copy(root / "datasets" / "stand-medium.hdf5", tmp_path)
    with h5py.File(path, "a") as h5:  # a finite, plausible edit that passes every shape and value check
        h5["actions"][5, 0] = 0.5 * float(h5["actions"][5, 0])
    read_dataset(path)
    with pytest.raises(DatasetError, match=f"^{path}: content does not match its content_sha256"):
        relabel_dataset(path, tmp_path / "r.hdf5", ["stand"], RelabelConfig(physics_check_transitions=0))
    assert not (tmp_path / "r.hdf5").exists()


def test_a_teacher_trained_with_other_settings_is_refused(tiny_teachers):
    from mop_core.agents.pbrl import PBRLConfig
    from mop_core.teachers import TeacherConfig, check_teacher_checkpoint

    checkpoints, datasets = tiny_teachers
    path = checkpoints[("stand", "deterministic")]
    sha = read_dataset_attrs(datasets["stand"])["content_sha256"]
    schedule = TrainSchedule(steps=20, eval_every=20, eval_episodes=1, final_eval_episodes=2, checkpoint_every=20,
                             rollout_envs=2)
    pbrl = PBRLConfig(hidden_sizes=(16, 16), ensemble_size=3, batch_size=16, ood_actions=1, learning_rate=1e-3)
    config = TeacherConfig(pbrl, schedule, episode_length=50)
    check_teacher_checkpoint(path, "stand", "medium", 0, 0, config, sha)  # as trained: accepted
    cases = [
        (dict(config=TeacherConfig(PBRLConfig(**{**pbrl.__dict__, "learning_rate": 2e-3}), schedule, 50)),
         "pbrl.learning_rate=0.001, the study expects 0.002"),
        (dict(config=TeacherConfig(pbrl, TrainSchedule(**{**schedule.__dict__, "steps": 40}), 50)),
         "schedule.steps=20, the study expects 40"),
        (dict(level="expert"), "level='medium', the study expects 'expert'"),
        (dict(seed=1), "seed=0, the study expects 1"),
        (dict(task="walk"), "task='stand', the study expects 'walk'"),
        (dict(sha="0" * 64), "dataset content_sha256="),
    ]
    for change, message in cases:
        args = dict(task="stand", level="medium", seed=0, config=config, sha=sha) | change
        with pytest.raises(InputFileError, match=f"^{path}: teacher trained with {message}"):
            check_teacher_checkpoint(path, args["task"], args["level"], args["seed"], 0, args["config"], args["sha"])


# ---- training faults ------------------------------------------------------------------------------
class Counter(torch.nn.Module):
    """A toy learner whose loss at step k is k (or NaN from ``nan_at``): enough to drive train_loop."""

    def __init__(self, nan_at: int = 0, bad_weight_at: int = 0, stop_at: int = 0):
        super().__init__()
        self.weight = torch.nn.Parameter(torch.zeros(2))
        self.register_buffer("count", torch.zeros((), dtype=torch.long))
        self.nan_at, self.bad_weight_at, self.stop_at = nan_at, bad_weight_at, stop_at

    def update(self) -> dict[str, float]:
        self.count += 1
        step = int(self.count)
        if step == self.stop_at:
            raise KeyboardInterrupt  # an interrupted run (Ctrl-C, kill)
        if step == self.bad_weight_at:
            with torch.no_grad():
                self.weight[0] = float("nan")
        return {"loss": float("nan") if step == self.nan_at else float(step)}


def _train(agent: Counter, tmp_path: Path, steps: int = 10, eval_every: int = 5, checkpoint_every: int = 5):
    schedule = TrainSchedule(steps=steps, eval_every=eval_every, checkpoint_every=checkpoint_every, eval_episodes=1)
    paths = RunPaths(*(tmp_path / name for name in ("final.pt", "metrics.json", "curve.tsv", "resume.pt")))
    curve, _, resumed = train_loop(agent, agent.update, lambda seeds: {"return_mean": 0.0}, schedule, {"eval": 0},
                                   torch.Generator().manual_seed(0), paths.resume, "fingerprint", "toy run", False)
    return curve, resumed, paths


def test_a_nan_loss_stops_the_run_naming_it_and_keeps_the_last_good_resume_file(tmp_path):
    with pytest.raises(TrainingDivergedError, match=r"^toy run: loss = nan at step 7; stopped; the resume file "):
        _train(Counter(nan_at=7), tmp_path)
    assert torch.load(tmp_path / "resume.pt", weights_only=False)["step"] == 5


def test_nan_weights_stop_the_run_before_they_are_saved(tmp_path):
    with pytest.raises(TrainingDivergedError, match=r"^toy run: non-finite weights \(weight\) at step 5"):
        _train(Counter(bad_weight_at=4), tmp_path)
    assert not (tmp_path / "resume.pt").exists()


def test_a_resumed_curve_equals_an_uninterrupted_one_when_checkpoints_fall_inside_an_eval_window(tmp_path):
    whole, _, _ = _train(Counter(), tmp_path / "whole", checkpoint_every=3)
    with pytest.raises(KeyboardInterrupt):
        _train(Counter(stop_at=8), tmp_path / "cut", checkpoint_every=3)  # resume file at step 6: window 6..10
    resumed, resumed_from, _ = _train(Counter(), tmp_path / "cut", checkpoint_every=3)
    assert resumed_from == 6
    assert resumed == whole == [{"step": 5, "return_mean": 0.0, "loss": 3.0}, {"step": 10, "return_mean": 0.0,
                                                                               "loss": 8.0}]


# ---- full disk, leftover temporary files ----------------------------------------------------------
def _disk_full_on_next_write(path: Path) -> None:
    """The next atomic write of ``path`` goes to /dev/full (its temporary name is a symlink there)."""
    (path.parent / f".{path.name}.tmp-{os.getpid()}").symlink_to("/dev/full")


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_full_disk_names_the_file_and_keeps_the_previous_one(tmp_path):
    path = tmp_path / "teacher.pt"
    save_checkpoint(path, {"kind": "x", "w": torch.zeros(3)})
    before = path.read_bytes()
    _disk_full_on_next_write(path)
    with pytest.raises(OutputFileError, match=f"^{path}: could not be written, no space left on device"):
        save_checkpoint(path, {"kind": "x", "w": torch.ones(1000)})
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["teacher.pt"]
    metrics = tmp_path / "metrics.json"
    _disk_full_on_next_write(metrics)
    with pytest.raises(OutputFileError, match=f"^{metrics}: could not be written, no space left on device"):
        write_json(metrics, {"x": list(range(5000))})


def test_leftover_temporary_files_are_invisible_to_dvc():
    teacher_tmp = "data/teachers/medium-deterministic/.stand-medium-deterministic-0.pt.tmp-4242"
    result = subprocess.run(["dvc", "check-ignore", teacher_tmp,
                             "data/datasets/.walk-expert.hdf5.tmp-17"], cwd=ROOT, capture_output=True, text=True,
                            env=os.environ | {"PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"})
    assert result.returncode == 0, result.stdout + result.stderr
    assert len(result.stdout.split()) == 2


# ---- concurrent and orphaned processes ------------------------------------------------------------
def _python(code: str, cwd: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=os.environ | {"PYTHONPATH": str(ROOT / "stages")})


def test_a_second_process_of_the_same_run_is_refused(tmp_path):
    holder = _python("""
        import sys, time, common
        sys.argv = ["stages/distill.py", "--loss", "mse", "--seed", "0"]
        common.run_stage(lambda: (print("started", flush=True), time.sleep(30)))
    """, tmp_path)
    assert holder.stdout.readline().strip() == "started"
    try:
        second = subprocess.run([sys.executable, "-c", "import sys, common; sys.argv = ['stages/distill.py', "
                                 "'--loss', 'mse', '--seed', '0']; common.run_stage(lambda: print('ran'))"],
                                cwd=tmp_path, capture_output=True, text=True,
                                env=os.environ | {"PYTHONPATH": str(ROOT / "stages")})
        other = subprocess.run([sys.executable, "-c", "import sys, common; sys.argv = ['stages/distill.py', "
                                "'--loss', 'mse', '--seed', '1']; common.run_stage(lambda: print('ran'))"],
                               cwd=tmp_path, capture_output=True, text=True,
                               env=os.environ | {"PYTHONPATH": str(ROOT / "stages")})
    finally:
        holder.kill()
        holder.wait()
    assert second.returncode == 2 and "ran" not in second.stdout
    assert second.stderr.startswith("error: data/locks/distill-loss-mse-seed-0.lock: this run is already in progress "
                                    f"(pid {holder.pid}, started "), second.stderr
    assert other.returncode == 0 and other.stdout == "ran\n"  # another matrix entry runs
    after = subprocess.run([sys.executable, "-c", "import sys, common; sys.argv = ['stages/distill.py', '--loss', "
                            "'mse', '--seed', '0']; common.run_stage(lambda: print('ran'))"], cwd=tmp_path,
                           capture_output=True, text=True, env=os.environ | {"PYTHONPATH": str(ROOT / "stages")})
    assert after.returncode == 0 and after.stdout == "ran\n"  # the kernel released the killed holder's lock


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


def _wait_dead(pids: list[int], seconds: float = 10.0) -> list[int]:
    deadline = time.time() + seconds
    while time.time() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.1)
    return [p for p in pids if _alive(p)]


def sleepy_job(seconds: float) -> int:
    os.write(1, f"{os.getpid()}\n".encode())  # one write: two workers' lines never interleave
    time.sleep(seconds)
    return os.getpid()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_killing_a_stage_kills_its_workers_and_killing_dvc_kills_the_stage(tmp_path):
    # a stage process (run_stage) whose worker pool (parallel_map, as eval and shared_computation use) is busy
    stage = _python("""
        import sys, common
        sys.path.insert(0, %r)
        from test_faults import sleepy_job
        from mop_core.learning.runtime import parallel_map
        common.run_stage(lambda: parallel_map(sleepy_job, [(60,), (60,)], 2, "jobs"))
    """ % str(ROOT / "tests"), tmp_path)
    workers = [int(stage.stdout.readline()) for _ in range(2)]
    os.kill(stage.pid, signal.SIGKILL)
    stage.wait()
    assert _wait_dead(workers) == [], "workers outlived their stage"

    # dvc repro's child: the stage dies with the process that started it
    parent = _python("""
        import subprocess, sys, time
        code = "import common, time; common.run_stage(lambda: time.sleep(60))"
        child = subprocess.Popen([sys.executable, "-c", code])
        print(child.pid, flush=True)
        time.sleep(60)
    """, tmp_path)
    child = int(parent.stdout.readline())
    time.sleep(1.0)  # let the child reach run_stage
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait()
    assert _wait_dead([child]) == [], "the stage outlived dvc"


def test_a_stage_reports_a_damaged_dataset_in_one_line(tmp_path):
    """Dataset errors used to end the relabel stage with a full traceback."""
    shutil.copytree(ROOT / "stages", tmp_path / "stages", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "profiles" / "tiny.yaml", tmp_path / "params.yaml")
    for task in ("stand", "walk"):
        path = tmp_path / "data" / "datasets" / f"{task}-medium.hdf5"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"\x89HDF not really\n" * 20)
    result = subprocess.run([sys.executable, "stages/relabel.py"], cwd=tmp_path, capture_output=True, text=True)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.startswith("error: data/datasets/stand-medium.hdf5: cannot be read as HDF5 (truncated or "
                                    "corrupt?)") and result.stderr.count("\n") == 1
    assert not (tmp_path / "data" / "relabelled").exists()


# ---- a stage's command line --------------------------------------------------------------------------
def test_every_stage_answers_help_and_refuses_an_unknown_argument_before_any_compute(tmp_path):
    """`python stages/collect.py --help` once started the whole collect stage (it took no flags, so it
    read none): every stage script parses its command line, its own flags or none (``run_stage(main,
    __doc__)``), before it reads a parameter. Checked on every script's code, run for collect (in an empty
    directory: a stage that computed would fail there, not print its usage)."""
    import ast

    for script in sorted((ROOT / "stages").glob("*.py")):
        if script.name == "common.py":
            continue
        tree = ast.parse(script.read_text())
        parses = any(isinstance(n, ast.Attribute) and n.attr == "parse_args" for n in ast.walk(tree))
        passes_doc = any(isinstance(n, ast.Call) and getattr(n.func, "id", "") == "run_stage" and len(n.args) == 2
                         for n in ast.walk(tree))
        assert parses != passes_doc, f"{script.name}: parse its flags or pass its docstring to run_stage, one of them"
    env = {**os.environ, "PYTHONPATH": str(ROOT / "stages")}
    shown = subprocess.run([sys.executable, str(ROOT / "stages/collect.py"), "--help"], cwd=tmp_path, env=env,
                           capture_output=True, text=True)
    assert shown.returncode == 0 and "collect stage: per task" in shown.stdout
    refused = subprocess.run([sys.executable, str(ROOT / "stages/collect.py"), "--workers", "4"], cwd=tmp_path,
                             env=env, capture_output=True, text=True)
    assert refused.returncode == 2 and "unrecognized arguments: --workers 4" in refused.stderr
    assert not any(tmp_path.iterdir())
