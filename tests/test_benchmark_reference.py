"""benchmarks/reference.py: the thesis's code is measured only at its pinned commit, never vendored."""

from __future__ import annotations

import sys

import pytest
from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
from reference import PINNED_FILES, REFERENCE_COMMIT, ReferenceError, reference_dir, verify  # noqa: E402


def test_a_missing_checkout_is_refused_with_how_to_get_it(tmp_path):
    with pytest.raises(ReferenceError, match=f"is not a directory; git clone .* checkout {REFERENCE_COMMIT}"):
        verify(tmp_path / "nowhere")


def test_a_checkout_of_another_commit_is_refused_naming_the_file(tmp_path):
    for name in PINNED_FILES:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("# not the pinned file\n")
    with pytest.raises(ReferenceError, match=r"utils\.py differs from commit 8269599f820e"):
        verify(tmp_path)
    (tmp_path / "utils.py").unlink()
    with pytest.raises(ReferenceError, match=r"utils\.py is missing"):
        verify(tmp_path)


def test_the_checkout_comes_from_the_flag_else_the_environment(monkeypatch, tmp_path):
    monkeypatch.delenv("MOP_REFERENCE", raising=False)
    assert reference_dir(None) is None
    monkeypatch.setenv("MOP_REFERENCE", str(tmp_path))
    assert reference_dir(None) == tmp_path.resolve()
    assert reference_dir(str(tmp_path / "x")) == (tmp_path / "x").resolve()
