"""record/: the git-tracked results of the last recorded quick study (scripts/record.py). Every
output of dvc.lock under results/ is there with the md5 dvc.lock gives it, and nothing else is;
results/ itself is DVC's (cached, git-ignored), so no stale result of another profile or run can
sit in git."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest
import yaml
from conftest import ROOT

sys.path.insert(0, str(ROOT / "scripts"))
from record import check_record, output_md5, readme_with_timings, recorded_outputs, timing_table  # noqa: E402

RECORD = ROOT / "record"


RECORDS = [RECORD, *(d for d in sorted(RECORD.iterdir()) if (d / "dvc.lock").is_file())]  # + other profiles


@pytest.mark.parametrize("record", RECORDS, ids=lambda d: d.relative_to(ROOT).as_posix())
def test_the_record_is_exactly_what_its_dvc_lock_describes(record):
    assert check_record(record) == []


def test_recording_the_quick_study_again_keeps_another_profiles_record_inside_it(tmp_path):
    from record import write_record

    root = tmp_path / "project"
    (root / "results").mkdir(parents=True)
    (root / "results" / "a.txt").write_text("new\n")
    lock = {"stages": {"s": {"outs": [{"path": "results/a.txt", "md5": output_md5(root / "results" / "a.txt")}]}}}
    (root / "dvc.lock").write_text(yaml.safe_dump(lock))
    (root / "record" / "evidence").mkdir(parents=True)
    (root / "record" / "evidence" / "dvc.lock").write_text("stages: {}\n")
    (root / "record" / "stale.txt").write_text("old\n")
    speed = {"td3_updates_per_second": 150.0, "pbrl_group_updates_per_second": 40.0,
             "rollout_control_steps_per_second": 9000.0, "when": "2026-12-02 12:00 UTC"}
    write_record(root, root / "record", readme=False, speed=speed)
    assert (root / "record" / "evidence" / "dvc.lock").read_text() == "stages: {}\n"
    assert "TD3 150 updates/s" in timing_table(root / "record")  # the day's probe is quoted with the times
    assert (root / "record" / "results" / "a.txt").read_text() == "new\n"
    assert not (root / "record" / "stale.txt").exists()


def test_a_new_record_says_whether_its_machine_rounds_as_the_replaced_ones(tmp_path, capsys):
    """collect's timing record names the machine that trained the data (the probe's, where it has none)."""
    from record import write_record

    root = tmp_path / "project"
    timing = root / "results" / "timings" / "collect.json"
    timing.parent.mkdir(parents=True)
    speed = {"td3_updates_per_second": 150.0, "pbrl_group_updates_per_second": 40.0,
             "rollout_control_steps_per_second": 9000.0, "when": "2026-12-05 12:00 UTC",
             "float_path": {"torch_updates": "probe", "mujoco": "probe"}}
    said = []
    for trained in ("aaa", "aaa", "ccc", None):  # the first record, the same path, torch's moved, no fingerprint
        timing.write_text(json.dumps({"seconds": 1.0} | ({"float_path": {"torch_updates": trained, "mujoco": "b"}}
                                                          if trained else {})))
        lock = {"stages": {"collect": {"outs": [{"path": "results/timings/collect.json", "md5": output_md5(timing)}]}}}
        (root / "dvc.lock").write_text(yaml.safe_dump(lock))
        write_record(root, root / "record", readme=False, speed=speed)
        said.append(next(line for line in capsys.readouterr().out.splitlines() if line.startswith("float path:")))
    assert said[0].startswith("float path: none in the replaced record")
    assert said[1] == "float path: as the replaced record's"
    assert said[2].startswith("float path: torch_updates rounded otherwise")
    assert said[3].startswith("float path: mujoco, torch_updates rounded otherwise")  # the new probe's


def test_the_readmes_time_table_is_the_records_generated_one():
    readme = (ROOT / "README.md").read_text()
    assert readme_with_timings(readme, RECORD) == readme, "rerun `python scripts/record.py`"
    assert timing_table(RECORD) in readme


def test_the_record_holds_the_report_and_the_headline_numbers():
    import yaml

    outputs = recorded_outputs(yaml.safe_load((RECORD / "dvc.lock").read_text()))
    assert {"results/report.md", "results/metrics.json", "results/eval/metrics.json"} <= set(outputs)
    assert any(path.startswith("results/timings/") for path in outputs)


def test_a_changed_missing_or_extra_file_is_reported(tmp_path):
    copy = tmp_path / "record"
    shutil.copytree(RECORD, copy)
    (copy / "results" / "report.md").write_text("typed by hand\n")
    (copy / "results" / "metrics.json").unlink()
    (copy / "results" / "notes.txt").write_text("not an output\n")
    problems = check_record(copy)
    assert any(p.startswith("results/report.md: md5") for p in problems)
    assert "results/metrics.json: missing" in problems
    assert "results/notes.txt: not an output in dvc.lock" in problems


def test_an_empty_directory_output_may_be_absent_from_a_checkout(tmp_path):
    """git keeps no empty directory, so a fresh clone lacks an output that was one (the single-task
    students' per-state tau folders); any other missing directory is still a problem."""
    import yaml

    copy = tmp_path / "record"
    shutil.copytree(RECORD, copy)
    lock = yaml.safe_load((copy / "dvc.lock").read_text())
    empty = [path for path, md5 in recorded_outputs(lock).items() if md5.endswith(".dir")
             and not any(p.is_file() for p in (copy / path).rglob("*"))]
    assert empty, "the record has no empty directory output to test with"
    for path in empty:
        shutil.rmtree(copy / path, ignore_errors=True)
    assert check_record(copy) == []
    full = next(path for path, md5 in recorded_outputs(lock).items() if md5.endswith(".dir") and path not in empty)
    shutil.rmtree(copy / full)
    assert f"{full}: missing" in check_record(copy)


def test_git_tracks_no_stage_output():
    tracked = subprocess.run(["git", "ls-files", "results", "data"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout.split()
    assert all(path.endswith(".gitignore") for path in tracked), tracked


def test_the_speed_probe_measures_every_rate_it_quotes():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from speed_probe import probe, summary

    result = probe(quick=True)
    rates = [v for k, v in result.items() if k.endswith("_per_second")]
    assert len(rates) == 3 and all(r > 0 for r in rates)
    assert "updates/s" in summary(result) and result["machine"]["cpus"] >= 1
    assert set(result["float_path"]) == {"torch_updates", "torch_acting", "mujoco"}
    assert "float path torch_updates " in summary(result)


def test_a_stage_the_pipeline_no_longer_defines_leaves_dvc_lock_before_recording(tmp_path):
    """DVC keeps the lock entries of stages removed from dvc.yaml (treeverse/dvc#5293): a profile that
    drops a family would otherwise record outputs no stage of it makes."""
    from record import prune_lock

    subprocess.run(["dvc", "init", "--no-scm", "-q"], cwd=tmp_path, check=True)
    (tmp_path / "dvc.yaml").write_text("stages:\n  kept:\n    matrix:\n      n: [1]\n    cmd: echo ${item.n}\n")
    entry = {"cmd": "echo", "outs": [{"path": "results/x", "md5": "0" * 32}]}
    (tmp_path / "dvc.lock").write_text(yaml.safe_dump({"schema": "2.0", "stages": {"kept@1": entry, "gone@2": entry}}))
    assert prune_lock(tmp_path) == ["gone@2"]
    assert set(yaml.safe_load((tmp_path / "dvc.lock").read_text())["stages"]) == {"kept@1"}
    assert prune_lock(tmp_path) == []
