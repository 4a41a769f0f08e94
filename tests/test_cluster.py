"""mop_cluster: the DAG and its stale entries, what each entry asks for, the refusals before compute.

The tiny study through ``mop-cluster repro`` on a two-node Ray cluster is in tests/test_pipeline.py
(it compares with that module's serial run)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml

from mop_cluster.cli import main
from mop_cluster.coordinator import ClusterError, _check_committed, coordinator_lock, sharing
from mop_cluster.dag import StageGraph
from mop_cluster.resources import entry_resources, family


def test_order_puts_every_entry_after_its_upstream_and_the_closure_follows_readers():
    graph = StageGraph({"report": ("eval",), "eval": ("distill@a", "distill@b"), "distill@a": ("collect",),
                        "distill@b": ("collect",), "collect": ()})
    order = graph.order()
    for entry, ups in graph.upstream.items():
        assert all(order.index(up) < order.index(entry) for up in ups)
    assert graph.downstream_closure({"distill@b"}) == {"distill@b", "eval", "report"}
    checked = StageGraph({"params": (), "collect": ("params",), "eval": ("collect",)})  # the params check's
    assert checked.downstream_closure({"params"}) == {"params"}  # output is the same for any valid file
    with pytest.raises(ValueError, match="cycle"):
        StageGraph({"a": ("b",), "b": ("a",)}).order()


def test_a_worker_tells_its_entry_the_cpus_and_the_gpu_share_ray_gave_it(tmp_path, monkeypatch):
    """MOP_THREADS sizes threads: auto; MOP_GPU_SHARE caps the memory a group sizes its waves by."""
    from mop_cluster import worker

    seen = []
    monkeypatch.setattr(worker, "_clone", lambda sharing, commit, clone: None)
    monkeypatch.setattr(worker, "drop_lock_entries", lambda lock, stale: None)
    monkeypatch.setattr(worker, "_dvc", lambda args, clone, env, *rest, **kw: seen.append(env) or "")
    sharing = worker.Sharing(str(tmp_path), cache_dir=str(tmp_path))
    for gpus in (0.25, 0.0, 1.0):
        worker.run_entry(sharing, "HEAD", "distill@a", str(tmp_path / "scratch"), 3, (), gpus)
    assert [env.get("MOP_GPU_SHARE") for env in seen] == ["0.25", None, None]  # a whole GPU: no cap
    assert all(env["MOP_THREADS"] == "3" for env in seen)


def test_each_entry_asks_for_the_threads_its_params_declare(tmp_path, tiny_params):
    params = dict(tiny_params)
    params["collect"] = {**params["collect"], "parallel": {"workers": 2, "threads_per_worker": 3}}
    params["distill"] = {**params["distill"], "threads": 4}
    file = tmp_path / "params.yaml"
    file.write_text(yaml.safe_dump(params))
    sized = entry_resources(["collect", "distill_width@8", "student_inputs", "train_teachers@medium-gaussian"],
                            file, gpus_per_run=0.25)
    assert sized["collect"].cpus == 6 and sized["collect"].gpus == 0.0  # workers x threads per worker
    assert sized["distill_width@8"].cpus == 4 and sized["distill_width@8"].gpus == 0.25
    assert sized["student_inputs"].cpus == 1
    assert sized["train_teachers@medium-gaussian"].gpus == 0.25
    assert family("distill_corrected@dagger-random99-8") == "distill"
    params["distill"]["threads"] = 0
    file.write_text(yaml.safe_dump(params))
    with pytest.raises(ValueError, match="distill.threads: expected a positive integer"):
        entry_resources(["distill@mse-medium"], file)


def test_a_second_coordinator_is_refused_naming_the_first(tmp_path):
    with coordinator_lock(tmp_path):
        with pytest.raises(ClusterError, match=f"another mop-cluster \\(pid {os.getpid()}\\)"):
            with coordinator_lock(tmp_path):
                pass
    with coordinator_lock(tmp_path):  # released: a later coordinator starts
        pass


def test_uncommitted_params_are_refused_before_any_compute(tmp_path):
    import subprocess

    for args in (["init", "-q"], ["-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "--allow-empty",
                                  "-m", "x"]):
        subprocess.run(["git", *args], cwd=tmp_path, check=True)
    (tmp_path / "params.yaml").write_text("a: 1\n")
    (tmp_path / "dvc.lock").write_text("")
    subprocess.run(["git", "add", "."], cwd=tmp_path, check=True)
    subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "p"], cwd=tmp_path, check=True)
    (tmp_path / "dvc.lock").write_text("changed")  # the coordinator writes it: allowed
    assert len(_check_committed(tmp_path)) == 40
    (tmp_path / "params.yaml").write_text("a: 2\n")
    with pytest.raises(ClusterError, match="params.yaml: uncommitted changes"):
        _check_committed(tmp_path)


def test_bad_arguments_name_the_flag(capsys):
    assert main(["repro", "--workers", "0"]) == 2
    assert "error: --workers: expected a positive number" in capsys.readouterr().err
    assert main(["repro", "--gpus-per-run", "2"]) == 2
    assert "error: --gpus-per-run" in capsys.readouterr().err


def test_the_makespan_lies_between_the_critical_path_and_the_serial_time():
    from mop_cluster.makespan import schedule

    graph = StageGraph({"collect": (), "t@1": ("collect",), "t@2": ("collect",), "t@3": ("collect",),
                        "eval": ("t@1", "t@2", "t@3")})
    seconds = {"collect": 10.0, "t@1": 30.0, "t@2": 20.0, "t@3": 20.0, "eval": 5.0}
    one, two, many = (schedule(graph, seconds, n) for n in (1, 2, 8))
    assert one.makespan == one.serial == 85.0 and one.utilisation == 1.0
    assert many.makespan == many.critical_path == 45.0  # collect -> t@1 -> eval
    assert two.makespan == 55.0  # t@1 first (longest remaining path), t@2 and t@3 one after another beside it
    assert two.utilisation == 85.0 / (2 * 55.0)


def test_a_partial_records_unreached_entries_are_named_and_count_zero(tmp_path):
    import json as json_

    from mop_cluster.makespan import measured_seconds, unrecorded

    graph = StageGraph({"collect": (), "t@1": ("collect",), "eval": ("t@1",)})
    timing = tmp_path / "results" / "timings" / "collect.json"
    timing.parent.mkdir(parents=True)
    timing.write_text(json_.dumps({"seconds": 12.5}))
    (tmp_path / "dvc.lock").write_text(yaml.safe_dump({"stages": {"collect": {"outs": [
        {"path": "results/timings/collect.json", "md5": "x"}]}, "t@1": {"outs": []}}}))
    assert unrecorded(tmp_path, graph) == ["eval"]
    assert measured_seconds(tmp_path, graph) == {"collect": 12.5, "t@1": 0, "eval": 0}


def test_plan_prints_the_makespan_of_a_profiles_dag(capsys):
    from mop_core.plan import main as plan

    root = Path(__file__).resolve().parents[1]
    plan([str(root / "profiles" / "tiny.yaml"), "--rates", str(root / "benchmarks" / "gpu" / "rates.json"),
          "--workers", "1", "64"])
    out = capsys.readouterr().out
    rows = [line.split("|") for line in out.splitlines() if line.startswith("| 1 |") or line.startswith("| 64 |")]
    one, many = ([float(cell) for cell in row[2:5]] for row in rows)  # makespan, critical path, serial
    assert one[0] == one[2] and many[0] == many[1] <= one[0]  # 1 worker: serial; 64: the critical path
    assert "entries (a stage's hours split evenly over its entries)" in out


def test_a_sweep_is_the_grid_of_every_set_and_a_misspelt_key_is_refused():
    from mop_cluster.experiments import set_values, sweep

    assert sweep(["distill.learning_rate=3e-4,1e-3", "eval.episodes=5"]) == [
        ("distill.learning_rate=0.0003", "eval.episodes=5"), ("distill.learning_rate=0.001", "eval.episodes=5")]
    with pytest.raises(ValueError, match="-S distill.learning_rate: expected key=value"):
        sweep(["distill.learning_rate"])
    text = set_values("distill:\n  learning_rate: 0.001  # a comment\n  seeds: [0]\n",
                      ("distill.learning_rate=3e-4", "distill.seeds=[0,1]"))
    assert yaml.safe_load(text) == {"distill": {"learning_rate": 3e-4, "seeds": [0, 1]}} and "# a comment" in text
    with pytest.raises(KeyError, match="-S distill.learning_rat=1: not a params.yaml key"):
        set_values(text, ("distill.learning_rat=1",))


def test_an_experiment_commit_holds_its_values_and_leaves_the_workspace_alone(tmp_path):
    import subprocess

    from mop_cluster.experiments import experiment_commit

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=tmp_path, check=True, capture_output=True, text=True).stdout

    git("init", "-q")
    (tmp_path / "params.yaml").write_text("distill:\n  learning_rate: 0.001  # a comment\n")
    (tmp_path / "other.txt").write_text("x\n")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "study")
    head = git("rev-parse", "HEAD").strip()
    commit = experiment_commit(tmp_path, head, ("distill.learning_rate=3e-4",))
    assert yaml.safe_load(git("show", f"{commit}:params.yaml")) == {"distill": {"learning_rate": 3e-4}}
    assert git("show", f"{commit}:other.txt") == "x\n" and git("rev-parse", f"{commit}^").strip() == head
    assert git("rev-parse", "HEAD").strip() == head and git("status", "--porcelain") == ""  # workspace untouched
    assert git("rev-parse", f"refs/mop-cluster/{commit}").strip() == commit  # kept from git gc


def test_an_entry_with_threads_auto_asks_for_the_auto_share(tmp_path, tiny_params):
    params = {**tiny_params, "distill": {**tiny_params["distill"], "threads": "auto"}}
    file = tmp_path / "params.yaml"
    file.write_text(yaml.safe_dump(params))
    assert entry_resources(["distill@mse-medium"], file, auto_cpus=3)["distill@mse-medium"].cpus == 3
    assert main(["repro", "--auto-threads", "0"]) == 2


def _study(tmp_path: Path, **params_changes) -> Path:
    """The tiny study committed in a fresh repository (what mop-cluster's workers clone)."""
    import subprocess
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    from bad_inputs import committed_project

    study = committed_project(Path(__file__).resolve().parents[1], tmp_path / "study")
    if params_changes:
        params = yaml.safe_load((study / "params.yaml").read_text())
        for key, value in params_changes.items():
            section, name = key.split("__")
            params[section][name] = value
        (study / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
        subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qam", "p"], cwd=study,
                       check=True, capture_output=True)
    return study


CLUSTER_ENV = {"RAY_USAGE_STATS_ENABLED": "0", "MOP_PROGRESS": "0"}


@pytest.mark.slow
def test_a_failing_entry_stops_the_run_naming_it_with_the_last_lines_of_its_log(tmp_path):
    import subprocess

    study = _study(tmp_path, distill__learning_rate=-1.0)  # the params entry refuses it
    result = subprocess.run(["mop-cluster", "repro", "--workers", "2"], cwd=study, capture_output=True, text=True,
                            env=os.environ | CLUSTER_ENV, timeout=600)
    assert result.returncode == 2, result.stdout + result.stderr
    assert "error: params: dvc repro failed; last lines of its log:" in result.stderr, result.stderr
    assert "error: distill.learning_rate: expected a positive" in result.stderr, result.stderr
    assert not (study / "data" / "datasets").exists()  # nothing after it ran


def _processes_under(path: Path) -> list[str]:
    """Command lines of the live processes whose working directory is ``path`` or below it."""
    found = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and Path(os.readlink(proc / "cwd")).is_relative_to(path):
                found.append((proc / "cmdline").read_text().replace("\0", " "))
        except OSError:  # gone, or not ours
            continue
    return found


@pytest.mark.slow
@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_ctrl_c_stops_every_worker_and_leaves_no_process_behind(tmp_path, signame):
    """Ctrl-C, and SIGTERM (a scheduler's cancel) the same way."""
    import signal
    import subprocess
    import time

    study = _study(tmp_path)
    coordinator = subprocess.Popen(["mop-cluster", "repro", "--workers", "2"], cwd=study, env=os.environ | CLUSTER_ENV,
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    scratch = study / ".dvc" / "tmp" / "mop-cluster"
    deadline = time.time() + 300
    while not any("stages/" in cmd for cmd in _processes_under(scratch)):  # a worker's stage command runs
        assert coordinator.poll() is None and time.time() < deadline, coordinator.communicate()[0]
        time.sleep(0.5)
    coordinator.send_signal(getattr(signal, signame))
    out, _ = coordinator.communicate(timeout=300)  # ~2 s on idle cores; Ray's shutdown is slow on loaded ones
    assert coordinator.returncode == 130 and "error: interrupted: every entry stopped" in out, out
    time.sleep(2)
    assert _processes_under(scratch) == [], out
    assert not (study / ".dvc" / "tmp" / "mop-cluster.pid").exists()  # the next coordinator may start


def _processes_with(token: str) -> list[str]:
    """Command lines of the live processes that mention ``token``."""
    found = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and token in (cmd := (proc / "cmdline").read_text().replace("\0", " ")):
                found.append(cmd)
        except OSError:  # gone, or not ours
            continue
    return found


def test_the_reaper_kills_the_command_and_its_children_when_its_parent_is_killed(tmp_path):
    import signal
    import subprocess
    import sys
    import time
    import uuid

    token = f"reaper-test-{uuid.uuid4().hex}"
    sleeper = f"import time; time.sleep(120)  # {token}"
    # the parent (a Ray worker's stand-in) starts the reaper, whose command starts a grandchild, then waits
    parent_code = (f"import os, subprocess, sys, time\n"
                   f"subprocess.Popen([sys.executable, '-m', 'mop_cluster.reaper', str(os.getpid()), 'sh', '-c', "
                   f"{f'{sys.executable} -c {sleeper!r} & {sys.executable} -c {sleeper!r}; wait'!r}], "
                   f"start_new_session=True)\n"
                   f"time.sleep(120)")
    parent = subprocess.Popen([sys.executable, "-c", parent_code])
    deadline = time.time() + 30
    while len([c for c in _processes_with(token) if c.startswith(sys.executable)]) < 2:
        assert time.time() < deadline, _processes_with(token)
        time.sleep(0.1)
    parent.send_signal(signal.SIGKILL)  # as Ray's shutdown kills its workers: no handler of the parent runs
    parent.wait()
    deadline = time.time() + 10
    while _processes_with(token) and time.time() < deadline:
        time.sleep(0.1)
    assert _processes_with(token) == []


def _git_run(args: list[str], cwd: Path) -> str:
    import subprocess

    return subprocess.run(args, cwd=cwd, check=True, capture_output=True, text=True).stdout


PIPELINE = """stages:
  source:
    cmd: cat seed.txt > source.txt
    deps: [seed.txt]
    outs: [source.txt]
  upper:
    cmd: tr a-z A-Z < source.txt > upper.txt && echo ${suffix} >> upper.txt
    deps: [source.txt]
    params: [suffix]
    outs: [upper.txt]
  copy:
    matrix:
      n: [1, 2]
    cmd: head -c ${item.n} upper.txt > copy${item.n}.txt
    deps: [upper.txt]
    outs:
      - copy${item.n}.txt
"""


def _remote_project(tmp_path: Path) -> tuple[Path, Path, Path]:
    """A small DVC project whose default remote (a directory) is committed, and a bare git repository
    it is pushed to: what machines that share no filesystem reach."""
    work, origin, remote = tmp_path / "work", tmp_path / "origin.git", tmp_path / "remote"
    work.mkdir()
    _git_run(["git", "init", "-q", "--bare", str(origin)], tmp_path)
    for command in (["git", "init", "-q"], ["dvc", "init", "-q"], ["dvc", "remote", "add", "-d", "store", str(remote)]):
        _git_run(command, work)
    (work / "dvc.yaml").write_text(PIPELINE)
    (work / "seed.txt").write_text("source\n")  # a stage without dependencies is never run-cached
    (work / "params.yaml").write_text("suffix: a\n")
    (work / ".gitignore").write_text("/source.txt\n/upper.txt\n/copy1.txt\n/copy2.txt\n")
    _git_run(["git", "add", "-A"], work)
    _git_run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "pipeline"], work)
    _git_run(["git", "push", "-q", str(origin), "HEAD:refs/heads/main"], work)
    return work, origin, remote


@pytest.mark.slow
def test_through_a_dvc_remote_the_workers_share_no_cache_and_the_workspace_restores_every_entry(tmp_path):
    """--git-url and --dvc-remote: each worker clones the bare repository and has a cache of its own; what
    it reads comes from the remote (dvc repro --pull) and what it ran goes there (dvc push --run-cache).
    The workspace's closing dvc repro --pull executes nothing, and the outputs are the pipeline's. Then a
    sweep of two values the same way: two DVC experiments, each dvc exp run --pull executing nothing."""
    import subprocess

    work, origin, remote = _remote_project(tmp_path)
    command = ["mop-cluster", "repro", "--workers", "2", "--git-url", str(origin), "--dvc-remote"]
    result = subprocess.run(command, cwd=work, capture_output=True, text=True, env=os.environ | CLUSTER_ENV,
                            timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "4 entries (4 ran on workers, 0 restored)" in result.stdout, result.stdout
    assert "the workspace's dvc repro executed 0 stage(s)" in result.stdout, result.stdout
    assert (work / "copy2.txt").read_text() == "SO" and (work / "upper.txt").read_text() == "SOURCE\na\n"
    assert list((remote / "runs").rglob("*")), "no run-cache record reached the remote"
    assert json.loads(_git_run(["dvc", "status", "--json"], work) or "{}") == {}

    # a sweep the same way: the combinations' commits go to the bare repository for the workers to fetch
    _git_run(["git", "add", "dvc.lock"], work)
    _git_run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "lock"], work)
    _git_run(["git", "push", "-q", str(origin), "HEAD:refs/heads/main"], work)
    sweep = ["mop-cluster", "exp", "run", "-S", "suffix=b,c", "--workers", "2", "--git-url", str(origin),
             "--dvc-remote"]
    result = subprocess.run(sweep, cwd=work, capture_output=True, text=True, env=os.environ | CLUSTER_ENV,
                            timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "2 experiment(s) (6 entries ran on workers" in result.stdout, result.stdout
    assert result.stdout.count("dvc exp run executed 0 stage(s)") == 2, result.stdout
    shown = json.loads(_git_run(["dvc", "exp", "show", "--json"], work))
    suffixes = {rev["data"]["params"]["params.yaml"]["data"]["suffix"]
                for base in shown for experiment in base.get("experiments") or [] for rev in experiment["revs"]}
    assert suffixes == {"b", "c"}
    assert (work / "upper.txt").read_text() == "SOURCE\na\n"  # the workspace as it was


def test_remote_mode_refuses_an_unpushed_head_and_an_uncommitted_remote_before_any_compute(tmp_path):
    work, origin, _ = _remote_project(tmp_path)
    (work / "note.txt").write_text("x")
    _git_run(["git", "add", "note.txt"], work)
    _git_run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "unpushed"], work)
    with pytest.raises(ClusterError, match="is no branch or tag tip there; git push it first"):
        sharing(work, _git_run(["git", "rev-parse", "HEAD"], work).strip(), str(origin))
    with pytest.raises(ClusterError, match="not a git repository"):
        sharing(work, "0" * 40, str(tmp_path / "nowhere"))
    _git_run(["dvc", "remote", "add", "--local", "-d", "mine", str(tmp_path / "mine")], work)
    with pytest.raises(ClusterError, match="default: mine, committed: store"):
        sharing(work, "0" * 40, None, dvc_remote=True)
    assert sharing(work, "0" * 40).cache_dir == str(work / ".dvc" / "cache")


def test_dropping_lock_entries_keeps_the_others_and_ignores_a_missing_lock(tmp_path):
    from mop_cluster.worker import drop_lock_entries

    lock = tmp_path / "dvc.lock"
    drop_lock_entries(lock, ["a"])  # no lock: nothing to do
    assert not lock.exists()
    lock.write_text(yaml.safe_dump({"schema": "2.0", "stages": {"a": {"cmd": "x"}, "b@1": {"cmd": "y"}}}))
    drop_lock_entries(lock, ["b@1", "not-there"])
    assert yaml.safe_load(lock.read_text()) == {"schema": "2.0", "stages": {"a": {"cmd": "x"}}}


def _recorded_elsewhere(tmp_path: Path) -> tuple[Path, Path]:
    """A fresh clone whose committed dvc.lock records outputs its cache lacks (a record made elsewhere; here
    a timestamp that differs on every run), and the file each command appends its stage's name to."""
    counter, first, clone = tmp_path / "runs.txt", tmp_path / "first", tmp_path / "clone"
    first.mkdir()
    for command in (["git", "init", "-q"], ["dvc", "init", "-q"]):
        _git_run(command, first)
    (first / "dvc.yaml").write_text(f"""stages:
  source:
    cmd: echo source >> {counter} && date +%s%N > source.txt
    deps: [seed.txt]
    outs: [source.txt]
  copy:
    matrix:
      n: [1, 2]
    cmd: echo copy >> {counter} && cp source.txt copy${{item.n}}.txt && echo ${{suffix}} >> copy${{item.n}}.txt
    deps: [source.txt]
    params: [suffix]
    outs: ["copy${{item.n}}.txt"]
""")
    (first / "seed.txt").write_text("seed\n")
    (first / "params.yaml").write_text("suffix: a\n")
    (first / ".gitignore").write_text("/source.txt\n/copy1.txt\n/copy2.txt\n")
    _git_run(["dvc", "repro", "-q"], first)
    _git_run(["git", "add", "-A"], first)
    _git_run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "a record"], first)
    _git_run(["git", "clone", "-q", str(first), str(clone)], tmp_path)
    counter.unlink()
    return clone, counter


@pytest.mark.slow
def test_a_committed_lock_from_another_run_does_not_make_workers_run_upstream_again(tmp_path):
    """DVC trusts a lock entry whose dependencies match and never asks the run cache, so in a fresh clone of
    a record made elsewhere each worker ran its upstream again and the workspace's closing dvc repro ran
    all. Each stage's command must run once, on a worker, and the closing dvc repro execute nothing."""
    import subprocess

    clone, counter = _recorded_elsewhere(tmp_path)
    result = subprocess.run(["mop-cluster", "repro", "--workers", "2"], cwd=clone, capture_output=True, text=True,
                            env=os.environ | CLUSTER_ENV, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "the workspace's dvc repro executed 0 stage(s)" in result.stdout, result.stdout
    assert sorted(counter.read_text().split()) == ["copy", "copy", "source"]
    assert (clone / "copy1.txt").read_text() == (clone / "source.txt").read_text() + "a\n"
    assert json.loads(_git_run(["dvc", "status", "--json"], clone) or "{}") == {}


@pytest.mark.slow
def test_a_sweep_in_a_fresh_clone_runs_the_shared_upstream_once_and_dvc_exp_run_restores_all(tmp_path):
    """mop-cluster exp run in the same fresh clone: the entry no value changes (source) is one job for both
    experiments, not one per experiment; each dvc exp run restores everything (the committed lock's
    matching entries would have made it run source again); the workspace's dvc.lock stays as it was."""
    import subprocess

    clone, counter = _recorded_elsewhere(tmp_path)
    lock = (clone / "dvc.lock").read_text()
    sweep = ["mop-cluster", "exp", "run", "-S", "suffix=b,c", "--workers", "2"]
    result = subprocess.run(sweep, cwd=clone, capture_output=True, text=True, env=os.environ | CLUSTER_ENV,
                            timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "2 experiment(s) (5 entries ran on workers" in result.stdout, result.stdout
    assert result.stdout.count("dvc exp run executed 0 stage(s)") == 2, result.stdout
    assert sorted(counter.read_text().split()) == ["copy"] * 4 + ["source"]
    assert (clone / "dvc.lock").read_text() == lock
    assert _git_run(["git", "status", "--porcelain", "--untracked-files=no"], clone) == ""
    again = subprocess.run(sweep[:4] + ["suffix=b", "--workers", "2"], cwd=clone, capture_output=True, text=True,
                           env=os.environ | CLUSTER_ENV, timeout=600)  # a value run before: restored, not rerun
    assert again.returncode == 0, again.stdout + again.stderr
    assert "1 experiment(s) (0 entries ran on workers" in again.stdout, again.stdout
    assert sorted(counter.read_text().split()) == ["copy"] * 4 + ["source"]


def test_targets_are_resolved_as_dvc_repro_reads_them_with_what_they_read_from():
    graph = StageGraph({"collect": (), "teachers@a": ("collect",), "teachers@b": ("collect",),
                        "distill@x": ("teachers@a",), "eval": ("distill@x", "teachers@b")})
    assert graph.resolve(("teachers",)) == {"teachers@a", "teachers@b"}
    assert graph.upstream_closure(graph.resolve(("distill@x",))) == {"distill@x", "teachers@a", "collect"}
    with pytest.raises(ValueError, match=r"^target 'distil': no such stage or entry in dvc.yaml \(stages: collect, "):
        graph.resolve(("distil",))


@pytest.mark.slow
def test_targets_run_only_what_they_read_from_and_an_unknown_one_is_refused_before_compute(tmp_path):
    """mop-cluster repro TARGET, as dvc repro TARGET: copy@1 and its upstream run on workers, copy@2 does not,
    and the closing dvc repro copy@1 executes nothing; a misspelt target stops the run before any entry."""
    import subprocess

    clone, counter = _recorded_elsewhere(tmp_path)
    refused = subprocess.run(["mop-cluster", "repro", "--workers", "2", "cpy"], cwd=clone, capture_output=True,
                             text=True, env=os.environ | CLUSTER_ENV, timeout=600)
    assert refused.returncode == 2 and "error: target 'cpy': no such stage or entry" in refused.stderr, refused.stderr
    assert not counter.exists()
    result = subprocess.run(["mop-cluster", "repro", "--workers", "2", "copy@1"], cwd=clone, capture_output=True,
                            text=True, env=os.environ | CLUSTER_ENV, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "2 entries (2 ran on workers, 0 restored)" in result.stdout, result.stdout
    assert "the workspace's dvc repro executed 0 stage(s)" in result.stdout, result.stdout
    assert sorted(counter.read_text().split()) == ["copy", "source"]
    assert (clone / "copy1.txt").exists() and not (clone / "copy2.txt").exists()
