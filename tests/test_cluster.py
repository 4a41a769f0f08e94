"""mop_cluster: the DAG and its stale entries, what each entry asks for, the refusals before compute.

The tiny study through ``mop-cluster repro`` on a two-node Ray cluster is in tests/test_pipeline.py
(it compares with that module's serial run)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml

from mop_cluster.cli import main
from mop_cluster.coordinator import ClusterError, _check_committed, coordinator_lock
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

