"""mop_core/experiment/catalogue.py and mop_core/experiment/runs.py: every run of the tiny study, in the stages'
order, what each
student learns from, which policies the eval stage rolls out where, and what each group is compared with."""

from __future__ import annotations

import copy
import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import h5py
import pytest

from mop_core.config import ConfigError, InputFileError
from mop_core.experiment.catalogue import (
    Job,
    Reference,
    build_catalogue,
    check_student_inputs,
    make_student,
    student_inputs,
)
from mop_core.experiment.runs import (
    BehaviourRun,
    MultitaskRun,
    StudentRun,
    TeacherRun,
    cross_group,
    is_cross_group,
    no_sharing_group,
    representation_group,
)
from mop_core.experiment.variants import VARIANTS, Ranking, Sharing, SingleTask, Variant, register_variant
from mop_core.learning.runtime import derive_seeds

TASKS = ("stand", "walk")


@pytest.fixture(scope="module")
def catalogue(tiny_params):
    return build_catalogue(tiny_params)


@pytest.fixture
def plain_catalogue(tiny_params):
    """The tiny study without its data-sharing runs and single-task students (tested on their own below)."""
    return build_catalogue(_with(tiny_params, data_sharing={"levels": []}, common_structure={"single_task": []}))


def _with(params: dict, **sections) -> dict:
    """A copy of ``params`` with ``section={key: value}`` entries replaced."""
    params = copy.deepcopy(params)
    for name, values in sections.items():
        params[name].update(values)
    return params


def test_the_tiny_study_has_these_runs_in_this_order(catalogue):
    assert catalogue.tasks == TASKS and catalogue.levels == ("medium",) and catalogue.study_seed == 0
    assert catalogue.behaviour == (BehaviourRun("stand", "medium"), BehaviourRun("stand", "expert"),
                                   BehaviourRun("walk", "medium"), BehaviourRun("walk", "expert"))
    assert [t.name for t in catalogue.teachers] == ["stand-medium-deterministic-0", "stand-medium-gaussian-0",
                                                    "walk-medium-deterministic-0", "walk-medium-gaussian-0"]
    assert catalogue.multitask == (MultitaskRun("medium", 0, TASKS),)
    assert [s.name for s in catalogue.students] == ["mse-medium-0", "q-medium-0", "kl-medium-0", "mse-w8-medium-0",
                                                    "mse-rank_pairwise-medium-0", "mse-single_stand-medium-0",
                                                    "mse-single_walk-medium-0", "mse-ds-medium-0",
                                                    "mse-oqs_own-medium-0", "mse-oqs_target-medium-0",
                                                    "mse-mop-stand_still-medium-0", "mse-oqs_own-stand_still-medium-0"]
    assert [t.name for t in catalogue.relabelled_teachers] == [
        "stand-from-stand+walk-medium-deterministic-0", "walk-from-stand+walk-medium-deterministic-0",
        "stand-from-walk-medium-deterministic-0", "walk-from-stand-medium-deterministic-0",
        # the substitute's set {stand_still, walk} on stand's and walk's data: walk's teachers are reused
        "stand_still-from-stand-medium-deterministic-0", "stand_still-from-stand+walk-medium-deterministic-0",
        "stand_still-from-walk-medium-deterministic-0"]
    assert [s.name for s in catalogue.mop_students()] == ["mse-medium-0", "q-medium-0", "kl-medium-0"]
    assert catalogue.teacher_seed == 0 and catalogue.teacher_actors == ("deterministic", "gaussian")


def test_run_names_groups_and_files(catalogue):
    behaviour = catalogue.behaviour[1]
    assert behaviour.group == "behaviour_expert" and behaviour.checkpoint == Path("data/behaviour/stand/expert.pt")
    teacher = catalogue.teachers[1]
    assert teacher.group == "teacher_medium_gaussian"
    assert teacher.paths.checkpoint == Path("data/teachers/medium-gaussian/stand-medium-gaussian-0.pt")
    assert teacher.paths.timing == Path("results/timings/teachers/medium-gaussian.json")  # the group's
    assert teacher.paths.metrics == Path("results/teachers/metrics/medium-gaussian/stand-medium-gaussian-0.json")
    assert teacher.paths.curve == Path("results/teachers/curves/medium-gaussian/stand-medium-gaussian-0.tsv")
    assert teacher.paths.resume == Path("data/resume/teachers-medium-gaussian.pt")
    assert teacher.datasets == (Path("data/datasets/stand-medium.hdf5"),)
    assert teacher.relabels == (Path("data/relabelled/stand-medium.hdf5"),)
    multitask = catalogue.multitask[0]
    assert multitask.name == "medium-0" and multitask.group == "multitask_medium"
    assert multitask.paths.checkpoint == Path("data/multitask/medium/medium-0.pt") and multitask.entry == "medium"
    assert multitask.paths.resume == Path("data/resume/multitask-medium.pt")  # the entry's group's
    assert multitask.paths.timing == Path("results/timings/multitask/medium.json")
    assert multitask.reference_group() == "teacher_medium_deterministic"
    student = catalogue.students[2]
    assert student.group == "student_kl_medium" and representation_group("kl", "medium") == "kl_medium"
    assert student.paths.checkpoint == Path("data/students/kl-medium/kl-medium-0.pt") and student.entry == "kl-medium"
    assert student.paths.resume == Path("data/resume/students-kl-medium.pt")  # the group's, shared by its seeds
    assert student.tasks == TASKS and student.levels == ("medium", "medium") and student.teacher_seed == 0
    variant = catalogue.students[4]  # a common-structure variant: the plain MSE student's teachers, its own files
    assert variant.variant == Ranking("pairwise") and variant.recipe == "mse-rank_pairwise"
    assert variant.group == "student_mse-rank_pairwise_medium"
    assert variant.representation_group == "mse-rank_pairwise_medium"
    assert variant.paths.checkpoint == Path("data/students/mse-rank_pairwise-medium/mse-rank_pairwise-medium-0.pt")
    assert variant.teachers == catalogue.students[0].teachers
    assert student.datasets == (Path("data/datasets/stand-medium.hdf5"), Path("data/datasets/walk-medium.hdf5"))
    assert cross_group("expert", "walk") == "cross_expert_walk"
    assert is_cross_group("cross_medium_stand") and not is_cross_group("teacher_medium_deterministic")


def test_kl_students_learn_from_gaussian_teachers_mse_and_q_from_deterministic_ones(catalogue):
    for student in catalogue.students:
        if student.variant == Sharing("ds") or student.substitute:  # data sharing: the teachers on U_j D_{j->i}
            continue
        actor = "gaussian" if student.loss == "kl" else "deterministic"
        tasks = TASKS if not student.single_task else (student.variant.task,)
        assert student.teachers == tuple(TeacherRun(task, "medium", actor, 0) for task in tasks)
        assert set(student.teachers) <= set(catalogue.teachers)  # every teacher a student needs is trained


def test_eval_jobs_cover_every_policy_and_the_cross_task_teachers(plain_catalogue):
    def teacher(task, actor):
        return Path(f"data/teachers/medium-{actor}/{task}-medium-{actor}-0.pt")

    expected = []
    for task, other in (("stand", "walk"), ("walk", "stand")):
        expected += [Job("behaviour_medium", 0, Path(f"data/behaviour/{task}/medium.pt"), task),
                     Job("behaviour_expert", 0, Path(f"data/behaviour/{task}/expert.pt"), task),
                     Job("teacher_medium_deterministic", 0, teacher(task, "deterministic"), task),
                     Job("teacher_medium_gaussian", 0, teacher(task, "gaussian"), task),
                     Job(f"cross_medium_{task}", 0, teacher(task, "deterministic"), other)]
    expected += [Job("multitask_medium", 0, Path("data/multitask/medium/medium-0.pt"), task, task) for task in TASKS]
    for loss in ("mse", "q", "kl"):
        checkpoint = Path(f"data/students/{loss}-medium/{loss}-medium-0.pt")
        expected += [Job(f"student_{loss}_medium", 0, checkpoint, task, task) for task in TASKS]
    for recipe in ("mse-w8", "mse-rank_pairwise"):
        checkpoint = Path(f"data/students/{recipe}-medium/{recipe}-medium-0.pt")
        expected += [Job(f"student_{recipe}_medium", 0, checkpoint, task, task) for task in TASKS]
    for student in plain_catalogue.shift_students:  # the state-shift students: every return is the eval stage's
        expected += [Job(student.group, student.seed, student.paths.checkpoint, task, task) for task in TASKS]
    assert plain_catalogue.eval_jobs() == expected
    assert plain_catalogue.cross_task_teachers() == [TeacherRun("stand", "medium", "deterministic", 0),
                                               TeacherRun("walk", "medium", "deterministic", 0)]


def test_only_gaussian_students_sample_when_asked(catalogue):
    sampled = catalogue.eval_jobs(sample_gaussian_students=True)
    plain = catalogue.eval_jobs()
    assert len(sampled) == len(plain)
    kl = catalogue.students[2]
    for job, same in zip(sampled, plain):
        if job.group == "student_kl_medium":
            seed = derive_seeds([0, "eval", "sample", "kl-medium-0", job.eval_task], ("sample",))["sample"]
            assert job.sample_seed == seed == catalogue.sample_seed(kl, job.eval_task)
            assert job == Job(same.group, same.train_seed, same.checkpoint, same.eval_task, same.task_id, seed)
        else:
            assert job == same and job.sample_seed is None
    assert catalogue.sample_seed(kl, "stand") != catalogue.sample_seed(kl, "walk")


def test_references_and_student_comparisons(plain_catalogue):
    deterministic = {task: Reference("teacher_medium_deterministic", 0) for task in TASKS}
    assert plain_catalogue.references() == {
        "multitask_medium": {task: Reference("teacher_medium_deterministic") for task in TASKS},  # every seed's mean
        "student_mse_medium": deterministic,
        "student_q_medium": deterministic,
        "student_kl_medium": {task: Reference("teacher_medium_gaussian", 0) for task in TASKS},
        "student_mse-w8_medium": deterministic,
        "student_mse-rank_pairwise_medium": deterministic,
    }
    assert plain_catalogue.student_comparisons() == [("student_mse_medium", "student_q_medium"),
                                               ("student_mse_medium", "student_kl_medium"),
                                               ("student_q_medium", "student_kl_medium"),
                                               ("student_mse-w8_medium", "student_mse_medium"),
                                               ("student_mse-rank_pairwise_medium", "student_mse_medium")]


def test_a_mixed_pairing_maps_its_levels_per_task(tiny_params):
    params = _with(tiny_params, study={"levels": ["expert", "medium"]},
                   distill={"pairings": ["expert+medium", "medium"], "seeds": [0, 1], "losses": ["mse", "kl"]},
                   data_sharing={"levels": []})
    catalogue = build_catalogue(params)
    assert [t.name for t in catalogue.teachers[:4]] == ["stand-expert-deterministic-0", "stand-expert-gaussian-0",
                                                        "stand-medium-deterministic-0", "stand-medium-gaussian-0"]
    assert len(catalogue.teachers) == 8
    assert [s.name for s in catalogue.mop_students()] == [
        "mse-expert+medium-0", "mse-expert+medium-1", "mse-medium-0", "mse-medium-1", "kl-expert+medium-0",
        "kl-expert+medium-1", "kl-medium-0", "kl-medium-1"]
    assert [s.name for s in catalogue.variant_students()] == [  # common_structure.pairing: medium
        "mse-w8-medium-0", "mse-w8-medium-1", "mse-rank_pairwise-medium-0", "mse-rank_pairwise-medium-1",
        "mse-single_stand-medium-0", "mse-single_stand-medium-1", "mse-single_walk-medium-0",
        "mse-single_walk-medium-1"]
    mixed = catalogue.students[0]
    assert mixed.teachers == (TeacherRun("stand", "expert", "deterministic", 0),
                              TeacherRun("walk", "medium", "deterministic", 0))
    assert mixed.levels == ("expert", "medium") and mixed.group == "student_mse_expert+medium"
    assert mixed.datasets == (Path("data/datasets/stand-expert.hdf5"), Path("data/datasets/walk-medium.hdf5"))
    assert catalogue.students[4].teachers == (TeacherRun("stand", "expert", "gaussian", 0),
                                              TeacherRun("walk", "medium", "gaussian", 0))
    references = catalogue.references()
    assert references["student_mse_expert+medium"] == {"stand": Reference("teacher_expert_deterministic", 0),
                                                       "walk": Reference("teacher_medium_deterministic", 0)}
    assert references["student_kl_expert+medium"] == {"stand": Reference("teacher_expert_gaussian", 0),
                                                      "walk": Reference("teacher_medium_gaussian", 0)}
    # head to head only within a pairing
    assert catalogue.student_comparisons() == [("student_mse_expert+medium", "student_kl_expert+medium"),
                                               ("student_mse_medium", "student_kl_medium"),
                                               ("student_mse-w8_medium", "student_mse_medium"),
                                               ("student_mse-rank_pairwise_medium", "student_mse_medium"),
                                               ("student_mse-single_stand_medium", "student_mse_medium"),
                                               ("student_mse-single_walk_medium", "student_mse_medium")]
    groups = catalogue.student_groups()
    assert list(groups) == ["student_mse_expert+medium", "student_mse_medium", "student_kl_expert+medium",
                            "student_kl_medium", "student_mse-w8_medium", "student_mse-rank_pairwise_medium",
                            "student_mse-single_stand_medium", "student_mse-single_walk_medium"]
    assert [s.seed for s in groups["student_mse_expert+medium"]] == [0, 1]
    cross = [j for j in catalogue.eval_jobs() if is_cross_group(j.group)]
    assert [(j.group, j.eval_task) for j in cross] == [("cross_expert_stand", "walk"), ("cross_medium_stand", "walk"),
                                                       ("cross_expert_walk", "stand"), ("cross_medium_walk", "stand")]


def test_the_teacher_seed_students_learn_from(tiny_params):
    params = _with(tiny_params, train_teachers={"seeds": [0, 1]}, distill={"teacher_seed": 1})
    catalogue = build_catalogue(params)
    assert [t.seed for t in catalogue.teachers] == [0, 1] * 4
    assert all(t.seed == 1 for s in catalogue.students for t in s.teachers)
    assert catalogue.references()["student_mse_medium"]["walk"] == Reference("teacher_medium_deterministic", 1)
    cross = [j for j in catalogue.eval_jobs() if is_cross_group(j.group)]
    assert [j.checkpoint.name for j in cross] == ["stand-medium-deterministic-1.pt", "walk-medium-deterministic-1.pt"]
    assert all(j.train_seed == 1 for j in cross)


def test_data_sharing_runs_their_teachers_files_and_eval_jobs(catalogue):
    """DS: task i's teacher on U_j D_{j->i}; OQS: task i's teachers on D_{j->i}, j != i, and MOP's for j = i."""
    ds, _, oqs_stand, _ = catalogue.relabelled_teachers[:4]  # the study's tasks' (the substitute's set follows)
    assert ds.data_tasks == ("stand", "walk") and ds.sharing == "ds" and ds.group == "teacher_ds_medium_deterministic"
    assert ds.datasets == (Path("data/datasets/stand-medium.hdf5"), Path("data/datasets/walk-medium.hdf5"))
    assert ds.relabels == (Path("data/relabelled/stand-medium.hdf5"), Path("data/relabelled/walk-medium.hdf5"))
    assert ds.paths.checkpoint == Path("data/teachers/ds-medium-deterministic/"
                                       "stand-from-stand+walk-medium-deterministic-0.pt")
    assert oqs_stand.sharing == "oqs" and oqs_stand.group == "teacher_from_walk_medium_deterministic"
    assert oqs_stand.datasets == (Path("data/datasets/walk-medium.hdf5"),)
    assert oqs_stand.entry == "oqs-medium-deterministic"
    assert set(catalogue.relabelled_teacher_entries()) == {"ds-medium-deterministic", "oqs-medium-deterministic"}
    plain = catalogue.teachers[0]
    assert plain.sharing == "" and plain.datasets == (Path("data/datasets/stand-medium.hdf5"),)  # MOP's: unchanged
    students = {s.variant.name: s for s in catalogue.sharing_students()}
    assert set(students) == {"ds", "oqs_own", "oqs_target"}
    assert students["ds"].teachers == catalogue.relabelled_teachers[:2] and not students["ds"].candidates
    own = students["oqs_own"]
    assert [t.name for t in own.teachers] == ["stand-medium-deterministic-0", "walk-medium-deterministic-0"]
    assert [[t.name for t in c] for c in own.candidates] == [
        ["stand-medium-deterministic-0", "stand-from-walk-medium-deterministic-0"],
        ["walk-from-stand-medium-deterministic-0", "walk-medium-deterministic-0"]]
    assert len(own.all_teachers) == 4 and own.state_datasets == own.datasets == ds.datasets
    assert own.group == "student_mse-oqs_own_medium" and own.entry == "mse-oqs_own-medium"
    jobs = [(j.group, j.eval_task) for j in catalogue.eval_jobs() if "_ds_" in j.group or "_from_" in j.group]
    assert jobs == [("teacher_ds_medium_deterministic", "stand"), ("teacher_from_walk_medium_deterministic", "stand"),
                    ("teacher_ds_medium_deterministic", "walk"), ("teacher_from_stand_medium_deterministic", "walk"),
                    ("teacher_from_stand_medium_deterministic", "stand_still"),  # the substitute's own teacher
                    ("teacher_ds_medium_deterministic", "stand_still"),
                    ("teacher_from_walk_medium_deterministic", "stand_still")]
    assert ("student_mse-oqs_target_medium", "student_mse_medium") in catalogue.student_comparisons()
    assert catalogue.references()["student_mse-ds_medium"]["walk"].group == "teacher_ds_medium_deterministic"


def test_a_substitute_runs_mop_ds_and_oqs_on_its_task_set_from_its_base_tasks_data(catalogue):
    """data_sharing.substitutes [stand_still]: the set {stand_still, walk} where stand_still learns from
    stand's datasets relabelled (D_{stand->stand_still}); walk's teachers are the study set's."""
    own, ds, from_walk = catalogue.relabelled_teachers[4:]
    assert (own.task, own.data_tasks, own.entry) == ("stand_still", ("stand",), "oqs-medium-deterministic")
    assert own.datasets == (Path("data/datasets/stand-medium.hdf5"),)
    assert own.relabels == (Path("data/relabelled/stand-medium.hdf5"),)  # its stand_still column
    assert (ds.data_tasks, ds.entry) == (("stand", "walk"), "ds-medium-deterministic")
    assert (from_walk.data_tasks, from_walk.group) == (("walk",), "teacher_from_walk_medium_deterministic")
    mop, oqs = catalogue.substitute_students()
    assert (mop.name, mop.entry, mop.group) == ("mse-mop-stand_still-medium-0", "mse-mop-stand_still-medium",
                                                "student_mse-mop_stand_still-medium")
    assert mop.tasks == ("stand_still", "walk") and mop.data_tasks == ("stand", "walk")
    assert mop.teachers == (own, TeacherRun("walk", "medium", "deterministic", 0)) and not mop.pooled_states
    assert mop.datasets == (Path("data/datasets/stand-medium.hdf5"), Path("data/datasets/walk-medium.hdf5"))
    assert [[t.name for t in c] for c in oqs.candidates] == [
        ["stand_still-from-stand-medium-deterministic-0", "stand_still-from-walk-medium-deterministic-0"],
        ["walk-from-stand-medium-deterministic-0", "walk-medium-deterministic-0"]]
    assert oqs.state_datasets == mop.datasets and oqs.representation_group == "mse-oqs_own_stand_still-medium"
    assert catalogue.eval_tasks == ("stand", "walk", "stand_still")
    assert catalogue.references()["student_mse-mop_stand_still-medium"] == {
        "stand_still": Reference("teacher_from_stand_medium_deterministic", 0),
        "walk": Reference("teacher_medium_deterministic", 0)}
    assert ("student_mse-oqs_own_stand_still-medium", "student_mse-mop_stand_still-medium") in \
        catalogue.student_comparisons()
    assert mop not in catalogue.mop_students()
    assert oqs not in catalogue.variant_students() + catalogue.sharing_students()


@pytest.mark.parametrize("sharing, error", [
    ({"substitutes": ["walk"]}, r"data_sharing.substitutes\[0\]: expected a task outside study.tasks"),
    ({"substitutes": ["run"]}, r"data_sharing.substitutes\[0\]: expected a task outside study.tasks whose base"),
    ({"substitutes": ["sit"]}, r"data_sharing.substitutes\[0\]: unknown task 'sit'"),
    ({"teachers": ["ds"], "students": ["ds"], "substitute_students": ["ds"]},
     r"data_sharing.substitutes: expected oqs in teachers"),
    ({"substitute_students": ["mse"]}, r"data_sharing.substitute_students\[0\]: expected one of mop, ds"),
])
def test_substitute_errors_name_the_parameter(tiny_params, sharing, error):
    with pytest.raises(ConfigError, match=error):
        build_catalogue(_with(tiny_params, data_sharing=sharing))


def test_no_data_sharing_runs_when_the_section_is_empty(tiny_params):
    catalogue = build_catalogue(_with(tiny_params, data_sharing={"levels": []}))
    assert catalogue.relabelled_teachers == () and catalogue.sharing_students() == []


def test_transfer_tasks_add_cross_task_jobs_only(tiny_params):
    catalogue = build_catalogue(tiny_params)
    plain = catalogue.eval_jobs()
    jobs = catalogue.eval_jobs(transfer_tasks=("stand_still",))
    added = [j for j in jobs if j not in plain]
    assert [(j.group, j.eval_task) for j in added] == [("cross_medium_stand", "stand_still"),
                                                      ("cross_medium_walk", "stand_still")]
    assert [j.checkpoint.name for j in added] == ["stand-medium-deterministic-0.pt", "walk-medium-deterministic-0.pt"]


def test_no_cross_task_jobs_without_deterministic_teachers(tiny_params):
    params = _with(tiny_params, train_teachers={"actors": ["gaussian"]}, distill={"losses": ["kl"]},
                   common_structure={"widths": [], "ranking_losses": [], "single_task": []},
                   data_sharing={"levels": []}, state_shift={"datasets": [], "widths": [], "data_percents": [],
                                             "corrections": [], "correction_datasets": []})
    catalogue = build_catalogue(params)
    assert catalogue.cross_task_teachers() == []
    assert not [j for j in catalogue.eval_jobs() if is_cross_group(j.group)]
    assert catalogue.student_comparisons() == []  # one loss: nothing to compare


def test_state_shift_needs_deterministic_teachers_and_a_distill_pairing(tiny_params):
    with pytest.raises(ConfigError, match="state_shift: expected deterministic teachers"):
        build_catalogue(_with(tiny_params, train_teachers={"actors": ["gaussian"]}, distill={"losses": ["kl"]},
                              common_structure={"widths": [], "ranking_losses": [], "single_task": []},
                              data_sharing={"levels": []}))
    with pytest.raises(ConfigError, match=r"state_shift.pairing: expected one of distill.pairings \['medium'\]"):
        build_catalogue(_with(tiny_params, study={"levels": ["medium", "expert"]}, state_shift={"pairing": "expert"}))


def test_common_structure_variants_need_deterministic_teachers_and_a_distill_pairing(tiny_params):
    with pytest.raises(ConfigError, match="common_structure: expected deterministic teachers"):
        build_catalogue(_with(tiny_params, train_teachers={"actors": ["gaussian"]}, distill={"losses": ["kl"]}))
    with pytest.raises(ConfigError, match="common_structure.pairing: expected one of distill.pairings"):
        build_catalogue(_with(tiny_params, study={"levels": ["expert", "medium"]},
                              common_structure={"pairing": "expert"}))
    with pytest.raises(ConfigError, match=r"common_structure.ranking_losses\[0\]: expected one of pairwise"):
        build_catalogue(_with(tiny_params, common_structure={"ranking_losses": ["ndcg"]}))
    with pytest.raises(ConfigError, match="common_structure.widths: expected a list of positive integers"):
        build_catalogue(_with(tiny_params, common_structure={"widths": [0]}))
    none = build_catalogue(_with(tiny_params, common_structure={"widths": [], "ranking_losses": [], "single_task": []},
                                 data_sharing={"levels": []}))
    assert none.variant_students() == [] and len(none.students) == 3


def test_single_task_students_learn_from_their_task_alone_and_form_the_no_sharing_pairs(catalogue):
    stand, walk = [run for run in catalogue.students if run.single_task]
    assert stand == StudentRun("mse", "medium", 0, (TeacherRun("stand", "medium", "deterministic", 0),),
                               SingleTask("stand"))
    assert (stand.tasks, walk.tasks) == (("stand",), ("walk",))
    assert (walk.entry, walk.group, walk.representation_group) == (
        "mse-single_walk-medium", "student_mse-single_walk_medium", "mse-single_walk_medium")
    assert walk.datasets == (Path("data/datasets/walk-medium.hdf5"),)
    assert catalogue.single_task_students() == {"medium": {0: [stand, walk]}}
    jobs = [(j.group, j.eval_task, j.task_id) for j in catalogue.eval_jobs()
            if j.group.startswith("student_mse-single")]
    assert jobs == [("student_mse-single_stand_medium", "stand", "stand"),
                    ("student_mse-single_walk_medium", "walk", "walk")]
    assert catalogue.references()["student_mse-single_walk_medium"] == {
        "walk": Reference("teacher_medium_deterministic", 0)}
    assert ("student_mse-single_walk_medium", "student_mse_medium") in catalogue.student_comparisons()
    assert no_sharing_group("medium") == "mse-single_medium"


@pytest.mark.parametrize("single, error", [
    (["stand"], r"common_structure.single_task: expected \[\] or two or more study tasks"),
    (["stand", "run"], r"common_structure.single_task\[1\]: expected one of study.tasks"),
    (["walk", "walk"], r"common_structure.single_task"),
])
def test_single_task_errors_name_the_parameter(tiny_params, single, error):
    with pytest.raises(ConfigError, match=error):
        build_catalogue(_with(tiny_params, common_structure={"single_task": single}))


def test_make_student():
    student = make_student("q", "expert+medium", 3, TASKS, ("expert", "medium"), 2)
    assert student == StudentRun("q", "expert+medium", 3, (TeacherRun("stand", "expert", "deterministic", 2),
                                                           TeacherRun("walk", "medium", "deterministic", 2)))
    assert student.name == "q-expert+medium-3" and student.teacher_seed == 2


def catalogue_seeds(catalogue) -> list[int]:
    return sorted({run.seed for run in catalogue.students})


def test_student_inputs_record_the_teachers_and_datasets_by_content(catalogue, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the run paths are relative to the repository root
    batch = catalogue.student_entries()["mse-medium"]
    student = batch[0]
    assert [run.name for run in batch] == [f"mse-medium-{seed}" for seed in catalogue_seeds(catalogue)]
    for i, (teacher, dataset) in enumerate(zip(student.teachers, student.datasets)):
        teacher.paths.checkpoint.parent.mkdir(parents=True, exist_ok=True)
        teacher.paths.checkpoint.write_bytes(b"teacher %d" % i)
        dataset.parent.mkdir(parents=True, exist_ok=True)
        with h5py.File(dataset, "w") as h5:
            h5.attrs["content_sha256"] = f"content-{teacher.task}"
    record = student_inputs(batch)
    assert record == {
        "students": [run.name for run in batch], "tasks": ["stand", "walk"],
        "teachers": [{"path": "data/teachers/medium-deterministic/stand-medium-deterministic-0.pt",
                      "sha256": hashlib.sha256(b"teacher 0").hexdigest()},
                     {"path": "data/teachers/medium-deterministic/walk-medium-deterministic-0.pt",
                      "sha256": hashlib.sha256(b"teacher 1").hexdigest()}],
        "datasets": [{"path": "data/datasets/stand-medium.hdf5", "content_sha256": "content-stand"},
                     {"path": "data/datasets/walk-medium.hdf5", "content_sha256": "content-walk"}]}
    where = Path("data/student_inputs/mse-medium.json")
    check_student_inputs(batch, record, where)
    student.teachers[1].paths.checkpoint.write_bytes(b"retrained")
    with pytest.raises(InputFileError) as err:
        check_student_inputs(batch, record, where)
    message = str(err.value)  # names the file that changed and the record
    assert message.startswith("data/teachers/medium-deterministic/walk-medium-deterministic-0.pt: ")
    assert str(where) in message
    student.teachers[1].paths.checkpoint.write_bytes(b"teacher 1")
    check_student_inputs(batch, record, where)
    with h5py.File(student.datasets[0], "a") as h5:
        h5.attrs["content_sha256"] = "recollected"
    with pytest.raises(InputFileError, match=r"^data/datasets/stand-medium.hdf5: "):
        check_student_inputs(batch, record, where)


def test_a_registered_family_gets_its_students_from_its_grid_without_a_catalogue_change(tiny_params):
    """The catalogue asks the registry: a family declares its section and keys, and its students, entries
    and distill stage follow (the dry run of adding a family: variants.py, its grid's key, dvc.yaml)."""
    @register_variant
    @dataclass(frozen=True)
    class Halved(Variant):  # every hidden layer half of ``width`` (reuses common_structure.widths)
        width: int
        family: ClassVar[str] = "halved_for_test"
        stage: ClassVar[str] = "distill_halved"
        section: ClassVar[str] = "common_structure"
        keys: ClassVar[tuple[str, ...]] = ("widths",)

        @property
        def name(self) -> str:
            return f"half{self.width}"

    try:
        params = copy.deepcopy(tiny_params)
        widths = params["common_structure"]["widths"]
        catalogue = build_catalogue(params)
    finally:
        del VARIANTS["halved_for_test"]
    halved = [run for run in catalogue.students if isinstance(run.variant, Halved)]
    assert [run.variant.width for run in halved] == [w for w in widths for _ in params["distill"]["seeds"]]
    pairing = params["common_structure"]["pairing"]
    assert set(catalogue.distill_stages()["distill_halved"]) == {f"mse-half{w}-{pairing}" for w in widths}
    assert set(build_catalogue(params).students) < set(catalogue.students)  # unregistered: gone again


def test_a_multitask_entry_holds_every_seed_of_its_level_and_refuses_others_by_flag(tiny_params):
    from mop_core.config import ConfigError
    from mop_core.multitask import multitask_runs

    params = _with(tiny_params, train_multitask={"seeds": [0, 2, 1]})
    assert [(r.level, r.seed) for r in multitask_runs(params, "medium")] == [("medium", 0), ("medium", 2),
                                                                             ("medium", 1)]
    assert [r.seed for r in multitask_runs(params, "medium", [1])] == [1]
    with pytest.raises(ConfigError, match="--seeds"):
        multitask_runs(params, "medium", [5])
    with pytest.raises(ConfigError, match="--level"):
        multitask_runs(params, "expert")
