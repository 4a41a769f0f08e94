"""mop_core.provenance: each input file checked against what the catalogue says it is.

The end-to-end cases (every swapped, rebuilt or emptied file of scripts/bad_inputs.provenance_cases
refused by the stage a user runs next) are in tests/test_pipeline.py; these are the unit checks."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from mop_core.config import InputFileError
from mop_core.data.hdf5 import read_dataset, write_dataset
from mop_core.experiment.catalogue import build_catalogue
from mop_core.experiment.study import shift_grid, study_config
from mop_core.provenance import Provenance, composed_specs, flat
from mop_core.shift.compose import compose_config
from mop_core.storage.files import read_record
from mop_core.storage.layout import EVAL_METRICS, SHIFT_METRICS, composed_file, dataset_file


@pytest.fixture
def study_dir(tiny_collected, tmp_path, monkeypatch):
    """A study folder (cwd) holding collect's tiny stand datasets in stand's and walk's slots."""
    root, _ = tiny_collected
    monkeypatch.chdir(tmp_path)
    for level in ("expert", "medium", "medium_replay"):
        dataset_file("stand", level).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(root / "datasets" / f"stand-{level}.hdf5", dataset_file("stand", level))
    shutil.copy(root / "datasets" / "stand-medium.hdf5", dataset_file("walk", "expert"))  # stand's data, walk's slot
    return tmp_path


def test_a_dataset_of_another_task_or_level_is_refused_by_name(study_dir, tiny_params):
    provenance = Provenance.of(build_catalogue(tiny_params))
    provenance.check_datasets([dataset_file("stand", "medium"), dataset_file("stand", "expert")])
    with pytest.raises(InputFileError, match=r"^data/datasets/walk-expert.hdf5: holds task='stand', expected "
                                             r"'walk' \(collect's walk-expert dataset\)"):
        provenance.check_datasets([dataset_file("walk", "expert")])
    with pytest.raises(ValueError, match="not a dataset of this study"):
        provenance.check_datasets([Path("data/datasets/fly-medium.hdf5")])


def test_composed_specs_name_every_file_the_compose_stage_writes_with_its_counts(tiny_params):
    grid = shift_grid(tiny_params, study_config(tiny_params))
    config = compose_config(grid)
    teacher = build_catalogue(tiny_params).composing_teachers[0]
    specs = {s.path: s for s in composed_specs(teacher, config)}
    assert set(specs) == {composed_file(teacher.task, teacher.level, n) for n in
                          ("online", "online_heldout", "random99", "random99_heldout", "reference")}
    online = specs[composed_file(teacher.task, teacher.level, "online")].fields
    assert online["composition"] == "online" and online["heldout"] == 0
    assert (online["teacher_episodes"], online["rest_episodes"]) == config.counts("online")
    assert specs[composed_file(teacher.task, teacher.level, "reference")].fields["teacher_episodes"] == \
        config.reference_episodes
    assert all(s.made_from == teacher.paths.checkpoint for s in specs.values())


def test_a_composed_file_of_another_composition_or_teacher_is_refused(study_dir, tiny_params):
    """collect's dataset in a composed slot (no composition), then a file whose attributes say it is
    the online data but whose episodes another policy rolled out."""
    grid = shift_grid(tiny_params, study_config(tiny_params))
    catalogue = build_catalogue(tiny_params)
    provenance = Provenance.of(catalogue, compose_config(grid))
    teacher = catalogue.composing_teachers[0]
    online = composed_file(teacher.task, teacher.level, "online")
    online.parent.mkdir(parents=True)
    shutil.copy(dataset_file("stand", "medium"), online)
    with pytest.raises(InputFileError, match=rf"^{online}: holds composition=None, expected 'online'"):
        provenance.check_datasets([online])
    data = read_dataset(online)
    spec = provenance.datasets[online]
    write_dataset(online, data.arrays, {**data.attrs, **spec.fields, "behaviour_sha256": "f" * 64})
    provenance._actor_sha256[teacher.paths.checkpoint] = "a" * 64  # the composing teacher's actor
    with pytest.raises(InputFileError, match=rf"^{online}: rolled out by a policy of actor ffffffffffff\.\.\., "
                                             rf"expected {teacher.paths.checkpoint}'s"):
        provenance.check_datasets([online])
    write_dataset(online, data.arrays, {**data.attrs, **spec.fields, "behaviour_sha256": "a" * 64})
    provenance.check_datasets([online])


@pytest.mark.parametrize("content, message", [
    ("{}", r"record without 'pairing', 'measure', 'shift', 'students' \(emptied or edited\?\)"),
    ("[]", r"expected a JSON object \(the stage's record\), found a list"),
    ('{"pairing": "medium", "measure": {}, "shift": {}}', r"record without 'students'"),
])
def test_an_emptied_or_foreign_record_is_refused_by_name(tmp_path, monkeypatch, content, message):
    monkeypatch.chdir(tmp_path)
    SHIFT_METRICS.parent.mkdir(parents=True)
    SHIFT_METRICS.write_text(content)
    with pytest.raises(InputFileError, match=rf"^{SHIFT_METRICS}: {message}"):
        read_record(SHIFT_METRICS)


def test_a_record_with_its_keys_is_read_and_records_without_a_schema_need_only_be_objects(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    EVAL_METRICS.parent.mkdir(parents=True)
    record = {"aggregate": {}, "cross_task": {}, "eval": {"jobs": 1}, "normalisation": {}}
    EVAL_METRICS.write_text(json.dumps(record))
    assert read_record(EVAL_METRICS) == record
    other = tmp_path / "other.json"
    other.write_text("{}")
    assert read_record(other) == {}


def test_flat_names_nested_settings_by_dotted_keys():
    assert flat({"student": {"hidden_sizes": (8, 8)}, "loss": "mse"}) == {"student.hidden_sizes": [8, 8],
                                                                          "loss": "mse"}
    assert flat(None) == {}
