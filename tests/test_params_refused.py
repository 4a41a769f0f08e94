"""Parameters that mean nothing are refused by the params stage (mop_core/study_params.py), before any
compute, with one line naming the key and what was expected: a section or key no stage reads, a
pairing spelled as an alias of another, and settings that would have no effect in the given study.
Each case below passed the params stage before (or failed later, naming missing files)."""

from __future__ import annotations

import copy
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import ROOT, params_stage

from mop_core.config import ConfigError
from mop_core.experiment.study import StudyConfig, pairing_levels
from mop_core.study_params import check_params

DELETE = object()


def _set(params: dict, *pairs) -> dict:
    """A copy of ``params`` with each (dotted key, value) pair set (DELETE removes the key)."""
    params = copy.deepcopy(params)
    for key, value in pairs:
        *path, last = key.split(".")
        node = params
        for part in path:
            node = node.setdefault(part, {})
        if value is DELETE:
            del node[last]
        else:
            node[last] = value
    return params


def _refused(params: dict, message: str) -> None:
    with pytest.raises(ConfigError, match="^" + re.escape(message)):
        check_params(params)





# ---- a: every section and key is one a stage reads; dvc reruns the check on any change of the file -----
def test_the_params_stage_depends_on_the_whole_params_file():
    stage = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]["params"]
    assert stage["cmd"] == "python stages/check_params.py"
    assert stage["params"] == [{"params.yaml": None}]  # no keys listed: DVC tracks every key of the file


def _key_paths(mapping: dict, prefix: str = "") -> list[str]:
    """Every mapping of the profile by dotted path (where a misspelt key can be added)."""
    out = []
    for key, value in mapping.items():
        if isinstance(value, dict):
            out.append(prefix + key)
            out += _key_paths(value, f"{prefix}{key}.")
    return out


TINY = yaml.safe_load((ROOT / "profiles" / "tiny.yaml").read_text())


@pytest.mark.parametrize("where", ["", *_key_paths(TINY)])
def test_an_unknown_key_is_refused_in_every_section(tiny_params, where):
    key = f"{where}.colour" if where else "colour"
    if where == "state_shift.compositions":  # its keys are dataset names: an entry must be a composition
        _refused(_set(tiny_params, (key, 1)), f"{key}: expected a mapping {{teacher_share")
    elif where in ("collect.schedule.medium_target_return", "collect.schedule.expert_return"):  # keys are tasks
        pytest.skip("a mapping of tasks")
    else:
        _refused(_set(tiny_params, (key, 1)), f"{key}: unknown " + ("section in params.yaml" if not where
                                                                       else "parameter; known: "))


@pytest.mark.parametrize("key,known", [
    ("distill.pairing", "pairings"),  # the grid keys are listed, not the config's fields it sets itself
    ("collect.paralel", "parallel"),
    ("shared_computation.thread", "threads"),
])
def test_an_unknown_key_lists_the_keys_of_its_section(tiny_params, key, known):
    with pytest.raises(ConfigError, match="^" + re.escape(f"{key}: unknown parameter; known: ")) as err:
        check_params(_set(tiny_params, (key, 1)))
    listed = str(err.value).split("known: ")[1].split(", ")
    assert known in listed
    assert not {"loss", "correction", "data_fraction", "episode_length", "actor"} & set(listed)


def test_misspelt_sections_beside_the_right_ones_are_refused(tiny_params):
    _refused(_set(tiny_params, ("distil", {"seeds": [0]})), "distil: unknown section in params.yaml; known: study")
    _refused(_set(tiny_params, ("common_structur", {})), "common_structur: unknown section in params.yaml")


# ---- b: a pairing is spelled one way ------------------------------------------------------------------
@pytest.mark.parametrize("key,value", [
    ("distill.pairings", ["medium+medium"]),
    ("common_structure.pairing", "medium+medium"),
    ("state_shift.pairing", "medium+medium"),
])
def test_a_pairing_spelled_as_an_alias_is_refused(tiny_params, key, value):
    _refused(_set(tiny_params, (key, value)), f"{key.split('[')[0]}: expected 'medium' (a pairing of one level "
                                              "for every study task is spelled as that level")


def test_an_alias_beside_its_pairing_is_refused_as_a_repeat(tiny_params):
    _refused(_set(tiny_params, ("distill.pairings", ["medium", "medium+medium"])),
             "distill.pairings: expected distinct pairings ('medium' and 'medium+medium' both pair the tasks")


def test_mixed_pairings_keep_their_spelling():
    study = StudyConfig(tasks=("stand", "walk"), levels=("expert", "medium"))
    assert pairing_levels("expert+medium", study) == ("expert", "medium")
    assert pairing_levels("expert", study) == ("expert", "expert")
    with pytest.raises(ConfigError, match=r"^distill.pairings: expected 'expert' \(a pairing of one level"):
        pairing_levels("expert+expert", study)
    assert pairing_levels("medium", StudyConfig(tasks=("stand",), levels=("medium",))) == ("medium",)


# ---- c: settings with no effect, or silently ignored -------------------------------------------------
NO_EFFECT = [
    # the tiny DAgger students train 20 steps: round k starts at update k * 20 // (rounds + 1)
    ([("distill.dagger.rounds", 20)], "distill.dagger.rounds: expected at most distill.schedule.steps - 1 = 19"),
    ([("distill.dagger.rounds", 3), ("distill.schedule.steps", 3), ("distill.schedule.eval_every", 1),
      ("distill.schedule.checkpoint_every", 1)], "distill.dagger.rounds: expected at most distill.schedule.steps - 1"),
    ([("eval.transfer_tasks", ["walk"])], "eval.transfer_tasks[0]: expected a task outside study.tasks"),
    ([("train_teachers.actors", ["gaussian"]), ("distill.losses", ["kl"]), ("common_structure.widths", []),
      ("common_structure.ranking_losses", []), ("common_structure.single_task", []), ("data_sharing.levels", []),
      ("state_shift.datasets", []), ("state_shift.widths", []), ("state_shift.data_percents", []),
      ("state_shift.corrections", []), ("state_shift.correction_datasets", [])],
     "eval.transfer_tasks: expected [] unless train_teachers.actors includes deterministic"),
    # the tiny students are 16 wide: a width-16 variant trains the plain MSE students again
    ([("common_structure.widths", [8, 16])], "common_structure.widths[1]: expected a width other than "
                                            "distill.student.hidden_sizes' 16"),
    ([("distill.ranking.weight", 0.0)], "distill.ranking.weight: expected a positive number while "
                                        "common_structure.ranking_losses is set"),
    ([("distill.ranking.layer_weights", [0.0, 0.0])], "distill.ranking.layer_weights: expected a positive weight"),
    ([("distill.ranking.loss", "pairwise")], "common_structure.ranking_losses[0]: expected a loss other than "
                                             "distill.ranking.loss"),
    # online is 2 teacher episodes of 2; a noise composition of teacher_share 1 is the same data
    ([("state_shift.compositions.noise.teacher_share", 1.0), ("state_shift.datasets", ["online", "noise"]),
      ("state_shift.correction_datasets", ["online"])],
     "state_shift.datasets[1]: expected a composition other than that of 'online'"),
    ([("state_shift.noise_std", 0.0), ("state_shift.datasets", ["online", "noise"]),
      ("state_shift.correction_datasets", ["noise"])],
     "state_shift.noise_std: expected a positive number while state_shift.datasets has 'noise'"),
    ([("state_shift.compositions.online.rest", "random")],
     "state_shift.compositions.online.rest: expected no rest with teacher_share 1"),
    ([("collect.episode_length", 25)], "collect.episode_length: not a parameter of this section; set "
                                       "study.episode_length"),
    ([("distill.data_fraction", 0.5)], "distill.data_fraction: not a parameter of this section; set "
                                       "state_shift.data_percents"),
    ([("collect.schedule.medium_target_return", {"stand": 400.0, "walk": 600.0, "wlak": 600.0})],
     "collect.schedule.medium_target_return.wlak: unknown task 'wlak'"),
]


@pytest.mark.parametrize("pairs,message", NO_EFFECT, ids=[m.split(":")[0] for _, m in NO_EFFECT])
def test_settings_with_no_effect_are_refused(tiny_params, pairs, message):
    _refused(_set(tiny_params, *pairs), message)


ACCEPTED = [
    [("distill.dagger.rounds", 19)],  # the last round starts at update 19 of 20
    [("state_shift.noise_std", 0.0)],  # no tiny dataset has noisy-teacher episodes
    [("common_structure.widths", [8, 32])],
    [("distill.student.hidden_sizes", [16, 8]), ("common_structure.widths", [16])],  # not a uniform width
    [("distill.ranking.weight", 0.0), ("common_structure.ranking_losses", [])],  # no ranking students
    [("state_shift.corrections", ["reweight"]), ("distill.dagger.rounds", 100)],  # no DAgger students
    [("eval.transfer_tasks", [])],
    [("collect.schedule.medium_target_return", {"stand": 400.0, "walk": 600.0, "run": 300.0})],
]


@pytest.mark.parametrize("pairs", ACCEPTED, ids=[str(p[0][0]) for p in ACCEPTED])
def test_settings_next_to_the_limits_pass(tiny_params, pairs):
    check_params(_set(tiny_params, *pairs))


STAGE_CASES = NO_EFFECT[:3] + NO_EFFECT[-4:]


@pytest.mark.parametrize("pairs,message", STAGE_CASES, ids=[m.split(":")[0] for _, m in STAGE_CASES])
def test_the_params_stage_refuses_before_writing_anything(tiny_params, tmp_path, monkeypatch, pairs, message):
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(_set(tiny_params, *pairs), sort_keys=False))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match="^" + re.escape(message)):
        params_stage().main()
    assert not (tmp_path / "data").exists()


@pytest.mark.parametrize("profile", sorted((ROOT / "profiles").glob("*.yaml")) + [ROOT / "params.yaml"],
                         ids=lambda p: p.name)
def test_every_valid_profile_still_passes(profile):
    check_params(yaml.safe_load(profile.read_text()))


# ---- a, end to end: dvc reruns the params stage when a section appears --------------------------------
@pytest.mark.slow
def test_dvc_repro_reruns_the_check_when_a_misspelt_section_appears(tmp_path):
    sys.path.insert(0, str(ROOT / "scripts"))
    from bad_inputs import copy_project

    copy_project(ROOT, tmp_path)  # code, DAG, profiles; the tiny profile as params.yaml
    env = os.environ | {"MOP_PROGRESS": "0", "PYTHONPATH": str(tmp_path),
                        "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(args, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)

    for cmd in (["git", "init", "-q"], ["git", "add", "-A"],
                ["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "tiny"]):
        assert run(*cmd).returncode == 0
    first = run("dvc", "repro", "params")  # the params stage alone (seconds): nothing else computes
    assert first.returncode == 0, first.stderr
    params = tmp_path / "params.yaml"
    params.write_text(params.read_text() + "distil:\n  seeds: [0, 1]\n")
    status = run("dvc", "status", "params")
    assert "distil" in status.stdout, status.stdout
    again = run("dvc", "repro", "params")
    assert again.returncode != 0
    assert "error: distil: unknown section in params.yaml" in again.stderr, again.stderr


THREAD_KEYS = ("train_teachers.threads", "distill.threads", "shared_computation.threads", "state_shift.measure.threads")


@pytest.mark.parametrize("key", THREAD_KEYS)
def test_threads_auto_is_the_cores_this_process_may_use_and_a_bad_value_is_named(tiny_params, key, monkeypatch):
    from mop_core.experiment.study import positive_threads

    check_params(_set(tiny_params, (key, "auto")))  # accepted wherever a thread count is
    monkeypatch.setenv("MOP_THREADS", "3")  # a mop-cluster worker's CPUs
    assert positive_threads("auto", key) == 3
    monkeypatch.delenv("MOP_THREADS")
    assert positive_threads("auto", key) == len(os.sched_getaffinity(0))
    _refused(_set(tiny_params, (key, "all")), f"{key}: expected a positive integer or 'auto'")


def test_teacher_steps_per_level_must_name_every_study_level(tiny_params):
    _refused(_set(tiny_params, ("train_teachers.schedule.steps", {"expert": 40})),
             "train_teachers.schedule.steps: expected a number of steps for level 'medium' (every study level)")
    check_params(_set(tiny_params, ("train_teachers.schedule.steps", {"medium": 40, "expert": 80})))
