"""Each profile is a complete params file: `cp profiles/<name>.yaml params.yaml` gives a study whose
every key is written down (no silent library defaults), and it passes the params stage's checks."""

from __future__ import annotations

import shutil

import pytest
import yaml
from conftest import ROOT, params_stage

PROFILES = sorted((ROOT / "profiles").glob("*.yaml"))


VALUES = {"collect.schedule.medium_target_return", "collect.schedule.expert_return",  # mappings of tasks,
          "train_teachers.schedule.steps"}  # of levels (or a number): values, not sections


def key_paths(mapping: dict, prefix: str = "") -> set[str]:
    """Every key of a nested mapping as a dotted path (``train_teachers.pbrl.critic_tau``)."""
    paths = set()
    for key, value in mapping.items():
        path = f"{prefix}{key}"
        paths.add(path)
        if isinstance(value, dict) and path not in VALUES:
            paths |= key_paths(value, path + ".")
    return paths


def test_the_profiles_are_found():
    assert {p.name for p in PROFILES} >= {"tiny.yaml", "thesis.yaml"}


@pytest.mark.parametrize("profile", PROFILES, ids=lambda p: p.name)
def test_a_profile_has_exactly_the_keys_of_params_yaml(profile):
    expected = key_paths(yaml.safe_load((ROOT / "params.yaml").read_text()))
    found = key_paths(yaml.safe_load(profile.read_text()))
    missing, extra = sorted(expected - found), sorted(found - expected)
    assert not missing and not extra, f"profiles/{profile.name}: missing {missing}, not in params.yaml {extra}"





@pytest.mark.parametrize("profile", PROFILES, ids=lambda p: p.name)
def test_a_profile_passes_the_params_stage(profile, tmp_path, monkeypatch):
    # the stage reads ./params.yaml and writes ./data/params_checked.txt: run it, in this process, in
    # a scratch directory holding the profile as params.yaml; a bad value raises an error naming its key
    shutil.copy(profile, tmp_path / "params.yaml")
    monkeypatch.chdir(tmp_path)
    params_stage().main()
    assert (tmp_path / "data" / "params_checked.txt").is_file()
