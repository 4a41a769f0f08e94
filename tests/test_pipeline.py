"""End to end: a real `dvc repro` of the tiny profile in a temporary git repository."""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import torch
import yaml
from conftest import ROOT, TEST_DEVICE

from mop_core.float_path import float_path
from mop_core.learning.runtime import available_cores

sys.path.insert(0, str(ROOT / "scripts"))
from bad_inputs import classify, committed_project, copy_project, provenance_cases, restore, snapshot  # noqa: E402
from bad_inputs import run as run_stage_script  # noqa: E402

pytestmark = pytest.mark.slow


def _run(args: list[str] | str, cwd: Path, check: bool = True) -> subprocess.CompletedProcess:
    """``args`` in ``cwd`` as a user runs it: Python writes its bytecode caches beside the code (its default;
    they once made every clone's dependency hashes its own), no progress bars. A string runs in bash."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env |= {"MOP_PROGRESS": "0", "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    if isinstance(args, str):
        args = ["bash", "-c", f"set -euo pipefail; {args}"]
    result = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True)
    if check and result.returncode != 0:
        raise AssertionError(f"{' '.join(args)} failed ({result.returncode}):\n{result.stdout}\n{result.stderr}")
    return result


@pytest.fixture(scope="module")
def repo(tmp_path_factory) -> Path:
    repo = tmp_path_factory.mktemp("study")
    copy_project(ROOT, repo)  # code, DAG, profiles; the tiny profile as params.yaml
    if TEST_DEVICE != "cpu":  # the suite on a GPU machine (benchmarks/gpu_check.sh): every stage on CUDA
        params = yaml.safe_load((repo / "params.yaml").read_text())
        params["study"]["device"] = TEST_DEVICE
        (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    _run(["git", "init", "-q"], repo)
    _run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "add", "-A"], repo)
    _run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "tiny study"], repo)
    _run(["dvc", "repro"], repo)
    return repo


def test_repro_trains_the_data_sharing_teachers_and_students(repo):
    """Thesis 6.4: DS and OQS teachers on relabelled data, students of them on the union of the datasets."""
    for name in ("ds-medium-deterministic/stand-from-stand+walk-medium-deterministic-0",
                 "oqs-medium-deterministic/walk-from-stand-medium-deterministic-0"):
        checkpoint = torch.load(repo / "data" / "teachers" / f"{name}.pt", weights_only=False)
        assert checkpoint["dataset"]["content_sha256"].count("+") == name.count("+")
    for recipe in ("mse-ds", "mse-oqs_own", "mse-oqs_target"):
        student = torch.load(repo / "data" / "students" / f"{recipe}-medium" / f"{recipe}-medium-0.pt",
                             weights_only=False)
        assert [s["source"] for s in student["states"]] == ["offline_union"] * 2
        if "oqs" in recipe:  # each target task's win shares over its candidates (D_{j->i} for every j)
            shares = student["metrics"]["q_switch"]
            assert set(shares) == {"stand", "walk"} and set(shares["stand"]) == {"stand", "walk"}
            assert all(abs(sum(s.values()) - 1) < 1e-6 for s in shares.values())
    evaluation = json.loads((repo / "results" / "eval" / "metrics.json").read_text())
    for task in ("stand", "walk"):
        for group in ("teacher_ds_medium_deterministic", "student_mse-oqs_target_medium"):
            assert evaluation[task][group]["n"] == 3
    shared = json.loads((repo / "results" / "shared_computation" / "metrics.json").read_text())
    assert {"mse-ds_medium", "mse-oqs_own_medium", "mse-oqs_target_medium"} <= set(shared["groups"])


def test_repro_runs_the_substitute_task_set_on_its_base_tasks_relabelled_data(repo):
    """data_sharing.substitutes [stand_still]: relabel adds its reward column, its teachers train with the
    OQS ones, its set's students (distill_substitute) are evaluated on stand_still, normalised by an R_random
    the eval stage measured, and measured and reported like the study set's."""
    import h5py

    with h5py.File(repo / "data" / "relabelled" / "stand-medium.hdf5") as h5:
        assert {"stand", "walk", "stand_still"} <= set(h5["rewards"])
    teachers = repo / "data" / "teachers" / "oqs-medium-deterministic"
    assert (teachers / "stand_still-from-stand-medium-deterministic-0.pt").is_file()
    payload = torch.load(repo / "data/students/mse-mop-stand_still-medium/mse-mop-stand_still-medium-0.pt",
                         weights_only=False)
    assert payload["tasks"] == ["stand_still", "walk"]
    evaluation = json.loads((repo / "results" / "eval" / "metrics.json").read_text())
    assert evaluation["normalisation"]["stand_still"]["random_source"] == "eval stage"
    for group in ("student_mse-mop_stand_still-medium", "student_mse-oqs_own_stand_still-medium",
                  "teacher_from_stand_medium_deterministic"):
        assert evaluation["stand_still"][group]["n"] == 3 and "normalised" in evaluation["stand_still"][group]
    iqm = evaluation["aggregate"]["iqm_normalised"]
    assert iqm["student_mse-mop_stand_still-medium"]["tasks"] == "stand_still, walk"
    assert iqm["teacher_from_stand_medium_deterministic"]["tasks"] == "walk"  # the study set's OQS teacher only
    shares = json.loads((repo / "results/students/metrics/mse-oqs_own-stand_still-medium/"
                         "mse-oqs_own-stand_still-medium-0.json").read_text())["q_switch"]
    assert set(shares) == {"stand_still", "walk"} and set(shares["stand_still"]) == {"stand", "walk"}
    shared = json.loads((repo / "results" / "shared_computation" / "metrics.json").read_text())
    assert list(shared["groups"]["mse-mop_stand_still-medium"]["pairs"]) == ["stand_still-walk"]
    report = (repo / "results" / "report.md").read_text()
    assert "### Second task set: {stand_still, walk} (stand_still on stand's data)" in report
    assert (repo / "results" / "report" / "sharing_stand_still.png").read_bytes()[:4] == b"\x89PNG"


def test_repro_trains_single_task_students_as_the_no_sharing_reference(repo):
    """common_structure.single_task: per task a one-task student group (distill_single), evaluated on its
    task only, and per seed the pair measured as one student's two ids in shared_computation."""
    for task in ("stand", "walk"):
        batch = f"mse-single_{task}-medium"
        payload = torch.load(repo / "data" / "students" / batch / f"{batch}-0.pt", weights_only=False)
        assert payload["tasks"] == [task]
        evaluation = json.loads((repo / "results" / "eval" / "metrics.json").read_text())
        assert evaluation[task][f"student_{batch.removesuffix('-medium')}_medium"]["n"] == 3
        other = "walk" if task == "stand" else "stand"
        assert f"student_{batch.removesuffix('-medium')}_medium" not in evaluation[other]
    shared = json.loads((repo / "results" / "shared_computation" / "metrics.json").read_text())
    null = shared["groups"]["mse-single_medium"]
    assert null["members"] == ["mse-single_medium-0"] and "no_sharing" in null
    assert list(null["pairs"]["stand-walk"]) == ["layer1", "layer2"]
    assert shared["students"]["mse-single_medium-0"]["networks"] == ["mse-single_stand-medium-0",
                                                                      "mse-single_walk-medium-0"]


def test_repro_composes_datasets_measures_their_shift_and_trains_students_on_them(repo):
    from mop_core.data import read_dataset

    for task in ("stand", "walk"):
        online = read_dataset(repo / "data" / "composed" / f"{task}-medium-online.hdf5")
        random99 = read_dataset(repo / "data" / "composed" / f"{task}-medium-random99.hdf5")
        assert len(online) == len(random99) == 2 * 50 and online.attrs["teacher_episodes"] == 2
        assert random99.attrs["teacher_episodes"] == 1 and random99.attrs["rest"] == "random"
        # the teacher's episode is the online dataset's first one (shared pools); the rest is random
        assert (random99.arrays["observations"][:50] == online.arrays["observations"][:50]).all()
        assert not (random99.arrays["actions"][50:] == online.arrays["actions"][50:]).all()
        assert (repo / "data" / "composed" / f"{task}-medium-reference.hdf5").is_file()
        heldout = read_dataset(repo / "data" / "composed" / f"{task}-medium-random99_heldout.hdf5")
        assert len(heldout) == 50 and heldout.attrs["heldout"] == 1 and heldout.attrs["teacher_episodes"] == 0
    metrics = json.loads((repo / "results" / "state_shift" / "metrics.json").read_text())
    for task in ("stand", "walk"):
        assert set(metrics["shift"][task]) == {"reference", "expert", "medium", "medium_replay", "online", "random99"}
        assert 0 <= metrics["shift"][task]["random99"]["auc"] <= 1
    assert set(metrics["students"]) == {"offline_w16", "offline_w8", "on_online_w8", "on_random99_w8", "data50",
                                        "reweight_random99_w8", "dagger_random99_w8"}
    assert metrics["students"]["data50"]["stand"]["return"]["n"] == 1  # the tiny profile's one seed
    # part 5: every student's action error on its training states and visited states; held-out where it has some
    assert set(metrics["students"]["data50"]["walk"]["action_mse"]) == {"train", "heldout", "visited"}
    assert set(metrics["students"]["offline_w8"]["walk"]["action_mse"]) == {"train", "visited"}
    assert set(metrics["students"]["dagger_random99_w8"]["walk"]["action_mse"]) == {"train", "heldout", "visited"}
    # part 6: the correcting students against the plain ones on the same data and width
    assert {c: metrics["corrections"][f"{c}_random99_w8"]["plain"] for c in ("reweight", "dagger")} == {
        "reweight": "on_random99_w8", "dagger": "on_random99_w8"}
    assert metrics["corrections"]["reweight_random99_w8"]["stand"]["reweight"]["reweight_ess"] > 0
    students = repo / "data" / "students"
    checkpoint = torch.load(students / "mse-on_random99_w8-medium" / "mse-on_random99_w8-medium-0.pt",
                            weights_only=False)
    assert checkpoint["distill_config"]["student"]["hidden_sizes"] == [8, 8]
    assert checkpoint["states"][0]["dataset"].endswith("composed/stand-medium-random99.hdf5")
    sizes = torch.load(students / "mse-data50-medium" / "mse-data50-medium-0.pt", weights_only=False)
    assert sizes["states"][0]["data_fraction"] == 0.5 and sizes["states"][0]["states"] == 100  # 2 of 3 episodes
    report = (repo / "results" / "report.md").read_text()
    assert "## 5b. State distribution shift (thesis 5.2)" in report and "| stand | random99 |" in report
    assert "### Dataset size" in report and "| 50% |" in report
    assert "### Where the students go wrong" in report and "### Correcting the shift" in report
    dagger = torch.load(students / "mse-dagger_random99_w8-medium" / "mse-dagger_random99_w8-medium-0.pt",
                        weights_only=False)
    assert dagger["distill_config"]["correction"] == "dagger" and dagger["metrics"]["dagger"]["aggregated_states"] == {
        "stand": 50, "walk": 50}  # the tiny profile's one round of one 50-step episode per task


def test_repro_produces_datasets_teachers_and_metrics(repo):
    for task in ("stand", "walk"):
        for level in ("expert", "medium", "medium_replay"):
            assert (repo / "data" / "datasets" / f"{task}-{level}.hdf5").is_file()
        assert (repo / "data" / "relabelled" / f"{task}-medium.hdf5").is_file()  # the tiny study's level
        for actor in ("deterministic", "gaussian"):
            name = f"{task}-medium-{actor}-0"
            assert (repo / "data" / "teachers" / f"medium-{actor}" / f"{name}.pt").is_file()
            assert (repo / "results" / "teachers" / "curves" / f"medium-{actor}" / f"{name}.tsv").is_file()
    assert (repo / "data" / "multitask" / "medium" / "medium-0.pt").is_file()
    for loss in ("mse", "q", "kl"):
        assert (repo / "data" / "students" / f"{loss}-medium" / f"{loss}-medium-0.pt").is_file()
        assert (repo / "results" / "students" / "curves" / f"{loss}-medium" / f"{loss}-medium-0.tsv").is_file()
    for recipe in ("mse-w8", "mse-rank_pairwise"):  # the common_structure students (distill_width, distill_ranking)
        assert (repo / "data" / "students" / f"{recipe}-medium" / f"{recipe}-medium-0.pt").is_file()
        assert (repo / "results" / "timings" / "students" / f"{recipe}-medium.json").is_file()
    config = torch.load(repo / "data/students/mse-w8-medium/mse-w8-medium-0.pt", weights_only=False)["distill_config"]
    assert config["student"]["hidden_sizes"] == [8, 8] and config["ranking"]["loss"] == "none"
    config = torch.load(repo / "data/students/mse-rank_pairwise-medium/mse-rank_pairwise-medium-0.pt",
                        weights_only=False)["distill_config"]
    assert config["ranking"]["loss"] == "pairwise"
    assert not list((repo / "data" / "resume").glob("*"))  # finished runs leave no resume files
    # the machine's float path beside collect's seconds (mop_core/float_path.py): this machine's
    assert json.loads((repo / "results/timings/collect.json").read_text())["float_path"] == float_path()
    evaluation = json.loads((repo / "results" / "eval" / "metrics.json").read_text())
    for task in ("stand", "walk"):
        for group in ("behaviour_expert", "teacher_medium_deterministic", "multitask_medium", "student_mse_medium",
                      "student_kl_medium"):
            stats = evaluation[task][group]  # one seed each: an interval over the 3 episodes
            assert stats["ci_low"] <= stats["mean"] <= stats["ci_high"] and stats["n"] == 3
            assert stats["ci_unit"] == "episode" and stats["normalised"]["ci_low"] <= stats["normalised"]["mean"]
        assert "student_q_medium_to_teacher" in evaluation[task]
        collect = json.loads((repo / "results" / "collect" / "metrics.json").read_text())
        assert evaluation["normalisation"][task]["random_return"] == collect[task]["random_return"]
    aggregate = evaluation["aggregate"]
    assert set(aggregate["iqm_normalised"]) >= {"student_mse_medium", "teacher_medium_deterministic"}
    assert set(aggregate["probability_of_improvement"]) == {
        "multitask_medium_vs_teachers", "student_mse_medium_vs_teachers", "student_q_medium_vs_teachers",
        "student_kl_medium_vs_teachers", "student_mse_medium_vs_student_q_medium",
        "student_mse_medium_vs_student_kl_medium", "student_q_medium_vs_student_kl_medium",
        "student_mse-w8_medium_vs_teachers", "student_mse-rank_pairwise_medium_vs_teachers",
        "student_mse-w8_medium_vs_student_mse_medium", "student_mse-rank_pairwise_medium_vs_student_mse_medium",
        *(f"student_mse-{v}_medium_vs_{y}" for v in ("ds", "oqs_own", "oqs_target", "single_stand", "single_walk")
          for y in ("teachers", "student_mse_medium")),
        "student_mse-mop_stand_still-medium_vs_teachers", "student_mse-oqs_own_stand_still-medium_vs_teachers",
        "student_mse-oqs_own_stand_still-medium_vs_student_mse-mop_stand_still-medium"}
    for a in aggregate["probability_of_improvement"].values():  # over runs: no interval under 3 a side
        assert 0 <= a["value"] <= 1 and (a["ci_low"] is None) == (min(a["runs_x"], a["runs_y"]) < 3)
    assert set(aggregate["paired_difference"]) == {name for name in aggregate["probability_of_improvement"]
                                                   if not name.endswith("_vs_teachers")}
    assert set(evaluation["cross_task"]["medium"]["stand"]) == {"stand", "walk", "stand_still"}  # + transfer task
    assert evaluation["cross_task"]["medium"]["walk"]["stand_still"]["n"] == 3
    for figure in ("returns.png", "student_curves.png"):
        assert (repo / "results" / "eval" / figure).read_bytes()[:4] == b"\x89PNG"
    stages = _run(["dvc", "stage", "list"], repo).stdout
    assert "train_teachers@medium-gaussian" in stages and "train_multitask@medium" in stages
    assert "distill@kl-medium" in stages and "eval" in stages
    shared = json.loads((repo / "results" / "shared_computation" / "metrics.json").read_text())
    for group in ("mse_medium", "q_medium", "kl_medium"):
        layers = shared["groups"][group]["pairs"]["stand-walk"]
        assert list(layers) == ["layer1", "layer2"]
        assert all(-1 <= row[f"average_tau_{v}"] <= 1 for row in layers.values() for v in "ab")
    assert "tau-b" in shared["note"] and "tau-a" in shared["note"]
    curve = (repo / "results" / "students" / "curves" / "mse-medium" / "mse-medium-0.tsv").read_text().splitlines()
    assert {"per_state_tau_a_layer1", "per_state_tau_b_layer2"} <= set(curve[0].split("\t"))
    _check_report(repo)
    timing = json.loads((repo / "results" / "timings" / "students" / "mse-medium.json").read_text())
    assert timing["seconds"] > 0 and timing["steps_per_second"] > 0 and "torch==" in timing["versions"]
    assert timing["runs"] == 1  # the tiny profile's one seed: a group of one
    status = _run(["dvc", "status"], repo).stdout
    assert "up to date" in status.lower()
    # the .gitignore DVC keeps next to file outputs is not data: rewriting it (as a checkout elsewhere
    # does) must not make distill/eval/report stale through the directory dependency data/teachers
    gitignore = repo / "data" / "teachers" / ".gitignore"
    original = gitignore.read_text()
    gitignore.write_text(original + "/another-teacher.pt\n")
    try:
        assert "up to date" in _run(["dvc", "status"], repo).stdout.lower()
    finally:
        gitignore.write_text(original)


# The README's DVC one-liners, run verbatim below (test_the_readme_shows_the_tested_commands keeps them in sync).
HEADLINE_SHOW = "dvc metrics show results/metrics.json"
TIMINGS_SHOW = "dvc metrics show results/timings"
HEADLINE_DIFF = "dvc metrics diff --targets results/metrics.json"
EXP_SHOW = (r"dvc exp show --drop '.*' --keep "
            r"'Experiment|distill\.(learning_rate|lr_schedule)|normalised_return|per_state_tau_a'")
# The README's recipe for several machines, run verbatim (the remote's path aside) by the cross-clone test
EXP_RUN = "dvc exp run -S distill.learning_rate=3e-4"
REMOTE_SETUP = 'dvc remote add -d shared /mnt/shared/mop-dvc && git commit -am "shared remote" && git push'
RUN_CACHE_PUSH = "dvc push --run-cache"
EXP_PUSH = "dvc exp push --run-cache origin"
RESTORE_ON_B = "git pull && dvc exp run --pull -S distill.learning_rate=3e-4"
RESTORE_STUDY_ON_B = "dvc repro --pull"
SHARED_CACHE = "dvc cache dir --local /mnt/shared/mop-cache"
# the experiments' smaller grid (the MSE distill entry's students only, no other loss or family: the suite's time)
SMALLER_GRID = ("-S", "distill.losses=[mse]",
                "-S", "state_shift.datasets=[]", "-S", "state_shift.widths=[]", "-S", "state_shift.data_percents=[]",
                "-S", "state_shift.corrections=[]", "-S", "state_shift.correction_datasets=[]",
                "-S", "common_structure.single_task=[]", "-S", "common_structure.widths=[]",
                "-S", "common_structure.ranking_losses=[]", "-S", "data_sharing.students=[]",
                "-S", "data_sharing.substitute_students=[]")


def _command(line: str, *extra: str) -> list[str]:
    return [*shlex.split(line), *extra]


def test_the_readme_shows_the_tested_commands():
    readme = (ROOT / "README.md").read_text()
    for line in (HEADLINE_SHOW, TIMINGS_SHOW, HEADLINE_DIFF, EXP_SHOW, EXP_RUN, REMOTE_SETUP, RUN_CACHE_PUSH,
                 EXP_PUSH, RESTORE_ON_B, RESTORE_STUDY_ON_B, SHARED_CACHE):
        assert line in readme, line


def markdown_blocks(text: str) -> list[tuple[str, str]]:
    """Every fenced code block of a Markdown page: (its language, its code)."""
    blocks = []
    for block in re.findall(r"^```\w*\n(?:.*\n)*?```$", text, flags=re.M):
        language, _, code = block[3:].partition("\n")
        blocks.append((language, code.removesuffix("```")))
    return blocks


def test_the_library_snippets_of_the_docs_run_on_the_tiny_studys_outputs(repo, tmp_path):
    """Every code block of docs/ecosystem.md (Python and shell), then every Python block of the README,
    run verbatim in order, in a copy of the tiny study (they write files of their own). The README's
    shell blocks are the two setup commands (.ci/run runs the tests' one; the record the study's) and
    the DVC one-liners the tests above run (test_the_readme_shows_the_tested_commands)."""
    optional = "docs/ecosystem.md's Minari and d3rlpy blocks need pip install -e '.[ecosystem]'"
    pytest.importorskip("minari", reason=optional)
    pytest.importorskip("d3rlpy", reason=optional)
    readme = markdown_blocks((ROOT / "README.md").read_text())
    assert all(lang in ("bash", "python", "") for lang, _ in readme)  # "": the DAG drawing
    runnable = markdown_blocks((ROOT / "docs" / "ecosystem.md").read_text())
    runnable += [(lang, code) for lang, code in readme if lang == "python"]
    assert [lang for lang, _ in runnable] == ["python", "python", "bash", "python", "python"]
    work = tmp_path / "study"
    shutil.copytree(repo, work, symlinks=True)
    outputs = []
    for number, (lang, code) in enumerate(runnable):
        script = tmp_path / f"block{number}.{'py' if lang == 'python' else 'sh'}"
        script.write_text(code)
        stdout = _run([sys.executable if lang == "python" else "bash", str(script)], work).stdout
        outputs.append(stdout.strip().splitlines()[-1])  # what the block prints last (d3rlpy logs before it)
    assert outputs[0].strip() == "walk torch.Size([256])"
    shape, dtype = outputs[1].split(")")[0] + ")", outputs[1].split()[1]
    assert shape == "(24,)" and dtype == "float32"
    assert "Minari datasets in data/minari" in outputs[2] and (work / "data" / "minari" / "mop").is_dir()
    episodes, score = outputs[3].split()[0], outputs[3].split()[-1]
    assert int(episodes) > 0 and -1.0 < float(score.strip("[]")) < 2.0
    assert float(outputs[4]) >= 0.0  # the d3rlpy policy's return in mop/walker-walk-v0


def test_metrics_show_holds_the_headline_numbers_and_the_timings_apart(repo):
    shown = json.loads(_run(["dvc", "metrics", "show", "--json"], repo).stdout)[""]["data"]
    assert all(path == "results/metrics.json" or path.startswith("results/timings/") for path in shown), shown
    assert len([path for path in shown if path.startswith("results/timings/")]) == 28  # one per stage entry
    headline = shown["results/metrics.json"]["data"]
    assert headline == json.loads((repo / "results" / "metrics.json").read_text())
    evaluation = json.loads((repo / "results" / "eval" / "metrics.json").read_text())
    shared = json.loads((repo / "results" / "shared_computation" / "metrics.json").read_text())
    for task in ("stand", "walk"):
        for group in ("behaviour_expert", "teacher_medium_deterministic", "multitask_medium", "student_mse_medium",
                      "student_q_medium", "student_kl_medium"):
            assert headline["normalised_return"][group][task] == round(evaluation[task][group]["normalised"]["mean"], 2)
    for group in ("mse_medium", "q_medium", "kl_medium"):
        for layer in ("layer1", "layer2"):
            row = shared["groups"][group]["pairs"]["stand-walk"][layer]
            assert headline["per_state_tau_a"][group]["stand-walk"][layer] == round(row["per_state_tau_a_mean"], 4)
    assert "seconds" not in json.dumps(headline) and len(json.dumps(headline)) < 4000  # one small file
    table = _run(_command(HEADLINE_SHOW, "--md"), repo).stdout
    rows = [line for line in table.splitlines() if line.strip()]
    assert "normalised_return.student_mse_medium.stand" in table and len(rows) == 3  # header, rule, one row
    timings = _run(_command(TIMINGS_SHOW, "--md"), repo).stdout
    assert timings.count("results/timings/") == 28 and "normalised_return" not in timings


def test_every_plot_renders_and_only_the_current_runs_are_drawn(repo):
    curves = repo / "results" / "students" / "curves"
    stale = curves / "mse-expert" / "mse-expert-0.tsv"  # what another profile's pairing would leave behind
    stale.parent.mkdir()
    shutil.copy(curves / "mse-medium" / "mse-medium-0.tsv", stale)
    try:
        shown = json.loads(_run(["dvc", "plots", "show", "--json"], repo).stdout)
        _run(["dvc", "plots", "show"], repo)  # the HTML page, written to dvc_plots/ (git-ignored)
    finally:
        shutil.rmtree(stale.parent)
    assert not shown.get("errors"), shown.get("errors")
    kinds = {path: {plot["type"] for plot in plots} for path, plots in shown["data"].items()}
    assert "results/students/curves/mse-expert/mse-expert-0.tsv" not in kinds
    for curve in ("collect/curves/stand.tsv", "teachers/curves/medium-gaussian/walk-medium-gaussian-0.tsv",
                  "multitask/curves/medium/medium-0.tsv", "students/curves/kl-medium/kl-medium-0.tsv",
                  "eval/returns.tsv",
                  "students/tau/mse-medium/mse-medium-0/per_state_tau_a_layer1.tsv",
                  "students/tau/q-medium/q-medium-0/per_state_tau_b_layer2.tsv"):
        assert kinds[f"results/{curve}"] == {"vega"}, curve
    pngs = {p.relative_to(repo).as_posix() for p in (repo / "results").rglob("*.png")}
    assert len(pngs) >= 9 and all(kinds[png] == {"image"} for png in pngs)  # every figure a stage drew


def test_no_output_is_tracked_by_git(repo):
    """Every stage output is DVC's (cached, git-ignored): a profile switch or a rerun leaves git clean
    but for dvc.lock and the .gitignore files DVC keeps."""
    status = _run(["git", "status", "--porcelain", "--untracked-files=all"], repo).stdout.splitlines()
    paths = [line[3:] for line in status]
    assert all(p == "dvc.lock" or p.endswith(".gitignore") for p in paths), paths


def test_a_forced_teacher_rerun_leaves_every_later_stage_up_to_date(repo):
    """The checkpoint, curve and metrics hold no time or version: a rerun writes the same bytes, and
    only the run's timing record changes (no stage reads it)."""
    stage, batch = "train_teachers@medium-deterministic", "medium-deterministic"
    files = [repo / "data" / "teachers" / batch / f"{task}-{batch}-0.pt" for task in ("stand", "walk")]
    files += [repo / "results" / "teachers" / kind / batch / f"{task}-{batch}-0.{ext}" for task in ("stand", "walk")
              for kind, ext in (("curves", "tsv"), ("metrics", "json"))]
    before = [f.read_bytes() for f in files]
    out = _run(["dvc", "repro", "-f", "-s", stage], repo).stdout
    assert _stages_run(out) == {stage}
    assert [f.read_bytes() for f in files] == before
    assert json.loads(_run(["dvc", "status", "--json"], repo).stdout) == {}


def _check_report(repo: Path) -> None:
    """The report has every thesis section, and every figure it links is a PNG file."""
    report = (repo / "results" / "report.md").read_text()
    for title in ("Table 4.1", "Figure 5.1", "Figure 5.3", "Figure 5.4", "Figure 5.8", "Appendix E", "IQM",
                  "Table 6.1", "Figure 6.3", "Figure 6.4", "Figure 6.5", "Figure 6.9", "Table 6.2", "Table 6.3",
                  "Gradient conflict"):
        assert title in report
    # the report opens with the verdicts (a row per registered finding, each with its verdict), then the
    # sections in the thesis's order
    from mop_core.report.findings import FINDINGS
    verdicts, body = report[:report.index("## 1. ")], report[report.index("## 1. "):]
    assert verdicts.index("## Verdicts") < verdicts.index("**Scale.**")
    assert sum(verdicts.count(f"**{v}**") for v in ("reproduced", "contradicted", "inconclusive")) == len(FINDINGS)
    recorded = json.loads((repo / "results" / "verdicts.json").read_text())
    assert set(recorded["findings"]) == set(FINDINGS) and sum(recorded["thesis_findings"].values()) > 30
    assert body.index("Table 4.1") < body.index("Figure 5.1") < body.index("Figure 5.8") < body.index(
        "Appendix E") < body.index("Table 6.1") < body.index(
        "Figure 6.5") < body.index("Table 6.3")
    assert "| 8 | mse-w8 | 1 |" in report and "| pairwise | mse-rank_pairwise | 1 |" in report
    assert "| medium | stand | DS teacher |" in report
    assert "| medium | OQS (target critic) | walk | D_stand->walk" in report
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", report)
    assert len(links) >= 7  # teachers, multitask, losses, 3 sorted-activation figures, tau curve, returns
    for link in links:
        assert (repo / "results" / link).read_bytes()[:4] == b"\x89PNG", link
    assert "Not part of this run" not in report  # the tiny study runs every stage


def _commit(repo: Path, message: str) -> None:
    _run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "add", "-A"], repo)
    _run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", message, "--allow-empty"], repo)


def _stages_run(out: str) -> set[str]:
    return {line.split("'")[1] for line in out.splitlines() if line.startswith("Running stage '")}


# Which stages a parameter change invalidates: `dvc repro --dry` lists the stages whose own params or
# files changed (it does not run them, so it cannot show the downstream stages their new outputs
# would invalidate; the distill test below shows that propagation in a real run).
def _invalidated_by(repo: Path, section: str, key: str, value) -> set[str]:
    original = (repo / "params.yaml").read_text()
    params = yaml.safe_load(original)
    node = params[section]
    *path, last = key.split(".")
    for part in path:
        node = node[part]
    node[last] = value
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    try:
        stages = _stages_run(_run(["dvc", "repro", "--dry"], repo).stdout)
        assert "params" in stages  # every params edit is checked first, whole file; the rest follows
        return stages - {"params"}
    finally:
        (repo / "params.yaml").write_text(original)


def test_each_parameter_section_invalidates_only_its_stages(repo):
    _commit(repo, "lock")
    assert _invalidated_by(repo, "collect", "td3.learning_rate", 0.002) == {"collect"}
    assert _invalidated_by(repo, "relabel", "physics_check_transitions", 20) == {"relabel"}
    teachers = _invalidated_by(repo, "train_teachers", "pbrl.learning_rate", 0.002)
    assert {"train_teachers@medium-deterministic", "train_multitask@medium", "train_relabelled_teachers@medium-ds",
            "train_relabelled_teachers@medium-oqs"} <= teachers
    assert not {"collect", "relabel", "eval"} & teachers and not any(s.startswith("distill") for s in teachers)
    assert _invalidated_by(repo, "eval", "episodes", 2) == {"eval", "report"}  # the report names the budget
    assert _invalidated_by(repo, "shared_computation", "episodes", 2) == {"shared_computation"}
    # dropping the width sweep leaves the ranking students (their entry's item and params are unchanged)
    assert _invalidated_by(repo, "common_structure", "widths", []) == {
        "student_inputs", "eval", "shared_computation", "state_shift", "report"}
    # dropping the OQS students leaves the DS ones and every teacher
    assert _invalidated_by(repo, "data_sharing", "students", ["ds"]) == {
        "student_inputs", "eval", "shared_computation", "report"}


def test_a_changed_teacher_makes_only_its_own_students_stale(repo):
    """Each distill entry depends on its student_inputs record, not on every teacher."""
    import torch

    # only the KL student learns from it
    teacher = repo / "data" / "teachers" / "medium-gaussian" / "stand-medium-gaussian-0.pt"
    original = teacher.read_bytes()
    try:
        teacher.unlink()  # DVC may have linked it to its cache: write a new file, never into the link
        payload = torch.load(io.BytesIO(original), weights_only=False)
        payload["actor"] = {k: v + 1e-3 for k, v in payload["actor"].items()}
        torch.save(payload, teacher)
        _run(["dvc", "repro", "-s", "student_inputs"], repo)
        stale = set(json.loads(_run(["dvc", "status", "--json"], repo).stdout))
        assert {s for s in stale if s.startswith("distill")} == {"distill@kl-medium"}, stale
        assert not {"distill@mse-medium", "distill@q-medium"} & stale
    finally:
        teacher.unlink()
        teacher.write_bytes(original)
        _run(["dvc", "repro", "-s", "student_inputs"], repo)
    assert not {s for s in json.loads(_run(["dvc", "status", "--json"], repo).stdout) if s.startswith("distill")}


def _experiment_headline(repo: Path, key: str, value) -> dict:
    """results/metrics.json of the experiment whose distill.<key> is ``value`` (``dvc exp show --json``)."""
    for base in json.loads(_run(["dvc", "exp", "show", "--json"], repo).stdout):
        for experiment in base.get("experiments") or []:
            for rev in experiment["revs"]:
                if rev["data"]["params"]["params.yaml"]["data"]["distill"][key] == value:
                    return rev["data"]["metrics"]["results/metrics.json"]["data"]
    raise AssertionError(f"no experiment with distill.{key} = {value!r}")


def test_queued_sweep_runs_and_shows_in_exp_show(repo):
    _run(["git", "checkout", "-q", "--", "."], repo)
    _run(["dvc", "checkout", "-q"], repo)
    # the tiny profile is a complete params file: -S can set any key (lr_schedule is constant there)
    _run(["dvc", "exp", "run", "--queue", "-S", "distill.learning_rate=0.003", "-S", "distill.lr_schedule=cosine",
          *SMALLER_GRID], repo)
    _run(["dvc", "exp", "run", "--run-all", "-j", "1"], repo)
    status = _run(["dvc", "queue", "status"], repo).stdout
    assert status.count("Success") == 1 and "Failed" not in status
    table = _run(_command(EXP_SHOW, "--md"), repo).stdout
    assert "0.003" in table and "cosine" in table and "normalised_return.student_mse_medium.stand" in table
    assert "seconds" not in table and "Created" not in table
    assert "normalised_return" in json.dumps(_experiment_headline(repo, "learning_rate", 0.003))


# the stages the cross-clone experiment (a distill parameter on the smaller grid) runs: the MSE distill entry and
# what reads students (which stages each section invalidates on the whole grid: test_each_parameter_section_...)
EXPERIMENT_STAGES = {"params", "compose", "student_inputs", "distill@mse-medium", "state_shift", "eval",
                     "shared_computation", "report"}
# (compose and student_inputs: the smaller grid empties state_shift.datasets and the families they list)


def _stages_restored(out: str) -> set[str]:
    restored = "is cached - skipping run, checking out outputs"
    return {line.split("'")[1] for line in out.splitlines() if line.endswith(restored)}


def _outputs(root: Path) -> dict[str, str]:
    """Every file of every output dvc.lock records under ``root``: path -> md5 of its bytes."""
    lock = yaml.safe_load((root / "dvc.lock").read_text())
    paths = {out["path"] for stage in lock["stages"].values() for out in stage.get("outs", [])}
    files = {}
    for path in sorted(paths):
        target = root / path
        for file in sorted(target.rglob("*")) if target.is_dir() else [target]:
            if file.is_file() and file.name != ".gitignore" and "__pycache__" not in file.parts:
                files[file.relative_to(root).as_posix()] = hashlib.md5(file.read_bytes()).hexdigest()
    return files


def test_a_workspace_experiment_is_restored_on_another_clone_through_a_shared_remote(repo, tmp_path):
    """The README's recipe, verbatim but for the remote's path and the experiment's smaller grid (the suite's
    time; B restores the whole committed study, every family, through the remote first): machine A (the
    fixture's clone) runs an experiment and pushes it, machine B (another clone) restores it from the run
    cache, executing nothing, with A's outputs. Python writes bytecode caches in both clones (see _run):
    .dvcignore keeps them out of the code's dependency hashes, which they made different in every clone."""
    _run(["git", "checkout", "-q", "HEAD", "--", "."], repo)  # HEAD: dvc autostages dvc.lock
    _run(["dvc", "checkout", "-q"], repo)
    _commit(repo, "the study")  # its dvc.lock
    for key, value in (("user.name", "t"), ("user.email", "t@t")):
        _run(["git", "config", key, value], repo)
    origin = tmp_path / "shared.git"  # the machines' Git remote
    _run(["git", "init", "-q", "--bare", str(origin)], tmp_path)
    _run(["git", "remote", "add", "origin", str(origin)], repo)
    _run(["git", "push", "-q", "-u", "origin", "HEAD"], repo)
    _run(REMOTE_SETUP.replace("/mnt/shared/mop-dvc", str(tmp_path / "remote")), repo)
    # the committed study's outputs first: `push --run-cache` sends every run record but only the
    # workspace's outputs (treeverse/dvc#10472), and the experiment replaces the students in the workspace
    _run(_command(RUN_CACHE_PUSH), repo)

    out = _run(_command(EXP_RUN, *SMALLER_GRID), repo).stdout  # a distill parameter: distill and its readers
    ran = _stages_run(out)  # compose and student_inputs: run, or restored where the queued sweep ran them already
    assert ran | _stages_restored(out) == EXPERIMENT_STAGES and EXPERIMENT_STAGES - ran <= {"compose", "student_inputs"}
    diff = json.loads(_run(_command(HEADLINE_DIFF, "--json"), repo).stdout)  # against the last commit
    changed = diff["results/metrics.json"]
    assert any(key.startswith("normalised_return.student_") for key in changed)
    assert not any(key.startswith("normalised_return.teacher_") for key in changed)  # teachers did not rerun
    machine_a = _outputs(repo)
    _run(_command(EXP_PUSH), repo)  # the experiment's commit, its outputs and its stage runs' records

    machine_b = tmp_path / "B"
    _run(["git", "clone", "-q", str(origin), str(machine_b)], tmp_path)
    out = _run(_command(RESTORE_STUDY_ON_B), machine_b).stdout  # the committed study first: nothing runs
    assert not _stages_run(out), out
    out = _run(f"{RESTORE_ON_B} {shlex.join(SMALLER_GRID)}", machine_b).stdout
    assert not _stages_run(out), out
    assert _stages_restored(out) == EXPERIMENT_STAGES
    assert _outputs(machine_b) == machine_a
    assert (machine_b / "dvc.lock").read_text() == (repo / "dvc.lock").read_text()


def test_a_clone_sharing_the_cache_directory_restores_what_another_ran(repo, tmp_path):
    """The scale-out workers' set-up: clones on one machine with one `cache.dir`. A clone at the study's
    commit restores every stage from the shared cache, and a stage one clone runs is restored in the other."""
    _run(["git", "checkout", "-q", "HEAD", "--", "."], repo)  # HEAD: dvc autostages dvc.lock
    _run(["dvc", "checkout", "-q"], repo)
    _commit(repo, "the study")  # its dvc.lock
    worker = tmp_path / "worker"
    _run(["git", "clone", "-q", str(repo), str(worker)], tmp_path)
    _run(_command(SHARED_CACHE.replace("/mnt/shared/mop-cache", str(repo / ".dvc" / "cache"))), worker)
    out = _run(["dvc", "repro"], worker).stdout
    assert not _stages_run(out), out
    assert _outputs(worker) == _outputs(repo)

    stage = "distill@mse-medium"  # the worker runs one stage of a changed study, the coordinator restores it
    for root in (worker, repo):
        params = yaml.safe_load((root / "params.yaml").read_text())
        params["distill"]["learning_rate"] = 5e-4
        (root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    assert _stages_run(_run(["dvc", "repro", "-s", stage], worker).stdout) == {stage}
    out = _run(["dvc", "repro", "-s", stage], repo).stdout
    assert not _stages_run(out) and f"Stage '{stage}' is cached - skipping run" in out, out
    student = Path("data/students/mse-medium/mse-medium-0.pt")
    assert (repo / student).read_bytes() == (worker / student).read_bytes()
    _run(["git", "checkout", "-q", "HEAD", "--", "."], repo)  # HEAD: dvc autostages dvc.lock
    _run(["dvc", "checkout", "-q"], repo)


def test_bad_parameter_fails_before_compute_and_names_the_key(repo, tmp_path):
    work = tmp_path / "bad"
    shutil.copytree(repo / "stages", work / "stages")
    params = yaml.safe_load((repo / "params.yaml").read_text())
    params["collect"]["schedule"]["medium_step"] = 10_000
    (work / "params.yaml").write_text(yaml.safe_dump(params))
    result = _run([sys.executable, "stages/collect.py"], work, check=False)
    assert result.returncode == 2
    assert "collect.schedule.medium_step: expected fewer gradient steps" in result.stderr
    assert {p.name for p in (work / "data").iterdir()} <= {"locks"}  # only the run lock, no output
    params["collect"]["schedule"]["medium_step"] = 10
    params["study"]["tasks"] = ["stand", "fly"]
    (work / "params.yaml").write_text(yaml.safe_dump(params))
    result = _run([sys.executable, "stages/collect.py"], work, check=False)
    assert "study.tasks[1]: unknown task 'fly'" in result.stderr
    params["study"]["tasks"] = ["stand"]
    params["study"]["levels"] = ["expert", "replay"]
    (work / "params.yaml").write_text(yaml.safe_dump(params))
    result = _run([sys.executable, "stages/relabel.py"], work, check=False)
    assert "study.levels[1]: expected one of expert, medium, medium_replay" in result.stderr

    params["study"]["tasks"], params["study"]["levels"] = ["stand", "walk"], ["medium"]  # a valid study again
    params["train_teachers"]["pbrl"]["ensemble_size"] = 1
    (work / "params.yaml").write_text(yaml.safe_dump(params))
    teacher = [sys.executable, "stages/train_teachers.py", "--level", "medium", "--tasks", "stand", "--seeds", "0"]
    result = _run(teacher, work, check=False)
    assert result.returncode == 2
    assert "train_teachers.pbrl.ensemble_size: expected an integer >= 2" in result.stderr
    params["train_teachers"]["pbrl"]["ensemble_size"] = 3
    (work / "params.yaml").write_text(yaml.safe_dump(params))
    result = _run(teacher, work, check=False)  # no datasets in this directory
    assert result.returncode == 2 and "missing input data/datasets/stand-medium.hdf5" in result.stderr
    assert not (work / "data" / "teachers").exists()

    params["study"]["tasks"] = ["stand", "walk"]
    params["train_teachers"]["actors"] = ["deterministic"]
    (work / "params.yaml").write_text(yaml.safe_dump(params))
    student = [sys.executable, "stages/distill.py", "--entry", "mse-medium", "--seeds", "0"]
    result = _run(student, work, check=False)
    assert result.returncode == 2
    assert "distill.losses: expected gaussian teachers for the kl loss: add gaussian to train_teachers.actors" \
        in result.stderr
    params["distill"]["losses"] = ["mse"]
    params["distill"]["student"]["hidden_sizes"] = []
    (work / "params.yaml").write_text(yaml.safe_dump(params))
    result = _run(student, work, check=False)
    assert "distill.student.hidden_sizes: expected a non-empty list" in result.stderr
    params["distill"]["student"]["hidden_sizes"] = [16]
    (work / "params.yaml").write_text(yaml.safe_dump(params))
    result = _run([*student[:3], "mse-expert+medium+medium", *student[4:]], work, check=False)
    assert "--entry: expected a distill entry of this study, one of [" in result.stderr
    assert "'mse-medium'" in result.stderr and "got 'mse-expert+medium+medium'" in result.stderr
    result = _run(student, work, check=False)
    assert "missing input data/teachers/medium-deterministic/stand-medium-deterministic-0.pt" in result.stderr
    assert not (work / "data" / "students").exists()


def _refusals(ws: Path, cases) -> list[tuple]:
    """Each case on workspace ``ws``, one after another: (name, verdict, last line, outputs unchanged)."""
    backup = snapshot(ws, ws.parent / f"{ws.name}-backup")
    records = {"student_inputs": "data/student_inputs", "state_shift": "results/state_shift/metrics.json",
               "report": "results/report.md", "compose": "results/compose/metrics.json"}
    outcomes = []
    for case in cases:
        case.breaks(ws)
        written = ws / records.get(case.stage, "results/eval/metrics.json")
        before = _tree_digest(written)
        result = run_stage_script([sys.executable, *_stage_command(case)], ws)
        outcomes.append((case.name, *classify(result, case.culprit), before == _tree_digest(written)))
        restore(ws, backup)
    return outcomes


def test_every_swapped_rebuilt_or_emptied_input_of_the_later_families_is_refused_by_name(repo, tmp_path):
    """The later families' inputs (scripts/bad_inputs.provenance_cases: composed datasets swapped or composed
    with other episodes, reference episodes and collect data of another task, a teacher of other widths, a
    student of another width, emptied records), each on a copy of the study: exit 2, one ``error:`` line
    naming the file, and nothing the stage writes changed (it refused before any compute). The cases run
    on one copy of the study per core (at most 4), one case at a time on each."""
    cases = provenance_cases()
    workers = min(4, available_cores(), len(cases))
    workspaces = [tmp_path / f"ws{i}" for i in range(workers)]
    for ws in workspaces:
        for name in ("stages", "mop_core", "profiles", "params.yaml", "dvc.yaml", "data", "results"):
            (shutil.copytree if (repo / name).is_dir() else shutil.copy)(repo / name, ws / name)
    with ThreadPoolExecutor(workers) as pool:
        parts = pool.map(_refusals, workspaces, [cases[i::workers] for i in range(workers)])
    outcomes = [outcome for part in parts for outcome in part]
    assert len(outcomes) == 18 and all(o[1] == "named" and o[3] for o in outcomes), \
        [o for o in outcomes if o[1] != "named" or not o[3]]


def _stage_command(case) -> list[str]:
    from bad_inputs import STAGE

    return [STAGE[case.stage][0], *(case.args if case.args is not None else STAGE[case.stage][1:])]


def _tree_digest(path: Path) -> str:
    """One digest of a file's or a folder's bytes (what a refused stage must leave as it was)."""
    digest = hashlib.sha256()
    for file in sorted([path] if path.is_file() else path.rglob("*") if path.is_dir() else []):
        if file.is_file():
            digest.update(file.name.encode() + file.read_bytes())
    return digest.hexdigest()


def test_a_bad_param_stops_dvc_repro_before_any_output_is_deleted(repo):
    """DVC deletes a stage's outputs before its command runs; the params stage fails first, so a typo
    anywhere costs nothing (once, this deleted distill's checkpoints and cache: false metrics)."""
    original = (repo / "params.yaml").read_text()
    outputs = [repo / "data" / "students" / "mse-medium" / "mse-medium-0.pt", repo / "results" / "students" /
               "metrics" / "mse-medium" / "mse-medium-0.json", repo / "results" / "eval" / "metrics.json",
               repo / "results" / "report.md"]
    before = {path: path.read_bytes() for path in outputs}
    params = yaml.safe_load(original)
    params["distill"]["learning_rate"] = float("inf")
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    try:
        result = _run(["dvc", "repro"], repo, check=False)
    finally:
        (repo / "params.yaml").write_text(original)
    assert result.returncode != 0
    assert "error: distill.learning_rate: expected a finite number, got inf" in result.stderr + result.stdout
    assert _stages_run(result.stdout) == {"params"}
    assert {path: path.read_bytes() for path in outputs} == before


def _without_timings(outputs: dict[str, str]) -> dict[str, str]:
    return {path: md5 for path, md5 in outputs.items() if not path.startswith("results/timings/")}


def test_the_study_through_mop_cluster_on_two_ray_nodes_equals_the_serial_run(repo, tmp_path):
    """`mop-cluster repro distill@mse-medium` on a local cluster of two Ray nodes (a head and a worker node
    started on this machine): the MSE students and every entry they read from in dvc.yaml, as `dvc dag` draws
    it, run each in its own clone sharing the DVC cache, and no other entry. student_inputs reads the whole of
    data/teachers and data/composed, so every teacher entry (the Gaussian ones too) and compose are upstream of
    any student; the other students, the multi-task baseline, eval and report are not. The first attempt at
    relabel dies mid-entry (a killed worker) and Ray retries it; the workspace's own dvc repro of the target
    then executes nothing, and every output equals the serial run's (the module's fixture), timing records
    aside. The whole tiny study through the cluster is benchmarks/bench_cluster.py's measure; sweeps
    on a cluster are tests/test_cluster.py's (a smaller pipeline: the same code paths, a tenth of the time)."""
    _run(["git", "checkout", "-q", "HEAD", "--", "."], repo)  # HEAD: dvc autostages dvc.lock
    _run(["dvc", "checkout", "-q"], repo)
    study = committed_project(ROOT, tmp_path / "study")
    port, target = "6391", "distill@mse-medium"
    env = "MOP_CLUSTER_KILL_ONCE=relabel RAY_USAGE_STATS_ENABLED=0 RAY_AUTH_MODE=disabled"  # one machine: no token
    try:
        _run(f"{env} ray start --head --port {port} --num-cpus 2 --num-gpus 0 --include-dashboard false", study)
        _run(f"{env} ray start --address 127.0.0.1:{port} --num-cpus 2 --num-gpus 0", study)
        out = _run(f"{env} mop-cluster repro --address 127.0.0.1:{port} {target}", study).stdout
        assert "the workspace's dvc repro executed 0 stage(s)" in out, out
        assert "relabel ran" in out and list((study / ".dvc" / "tmp" / "mop-cluster").glob("killed-relabel")), out
        def drawn(*targets: str) -> set[str]:  # the entries `dvc dag` draws (upstream of targets, if any)
            return set(re.findall(r'^"([^"]+)";$', _run(["dvc", "dag", "--dot", *targets], study).stdout, re.M))

        done = dict(re.findall(r"^mop-cluster: (\S+) (ran|restored) in ", out, flags=re.MULTILINE))
        read, every = drawn(target), drawn()
        assert set(done) == read < every, (sorted(done), sorted(read))  # what the target reads from, no more
        for entry in ("params", "collect", "relabel", "train_teachers@medium-deterministic",
                      "train_teachers@medium-gaussian", "compose", "student_inputs", target):  # via data/teachers
            assert done.get(entry) == "ran", out
        for entry in ("distill@kl-medium", "train_multitask@medium", "eval", "report"):  # not read by the target
            assert entry in every and entry not in done, out
        assert not _stages_run(_run(["dvc", "repro", target], study).stdout)
        assert json.loads(_run(["dvc", "status", "--json", target], study).stdout) == {}
        ours, serial = _without_timings(_outputs(study)), _without_timings(_outputs(repo))
        assert any(path.startswith("results/students/") for path in ours), sorted(ours)
        assert {path: serial.get(path) for path in ours} == ours
    finally:
        _run(["ray", "stop", "--force"], study, check=False)
