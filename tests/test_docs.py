"""The front door and the map: README.md stays short, opens with the two commands (the second is the
one .ci/run runs), and docs/layout.md names every module of mop_core/ and every stage script. The
modules are read from the files at test time, so an added or moved module fails here until the map
follows it. (The README's DVC one-liners and code blocks run in tests/test_pipeline.py.)"""

from __future__ import annotations

import re

from conftest import ROOT

README = ROOT / "README.md"
LAYOUT = ROOT / "docs" / "layout.md"
README_MAX_BYTES = 14_000
FENCED = re.compile(r"^```\w*\n(?:.*\n)*?```$", re.M)
# a path named in layout.md: from the repository root, not part of a longer path
NAMED_PATH = re.compile(r"(?<![\w./-])((?:mop_core|stages)/(?:[\w-]+/)*(?:[\w-]+\.py)?)(?![\w/-])")


def test_the_readme_is_short():
    size = len(README.read_bytes())
    assert size <= README_MAX_BYTES, f"README.md is {size} bytes (at most {README_MAX_BYTES}): move detail into docs/"


def test_the_readme_opens_with_the_study_command_and_the_test_command_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text()
    test_command = next(line for line in ci.splitlines() if line.startswith("python3.11 -m venv"))
    first, second = FENCED.findall(README.read_text())[:2]
    assert first.rstrip("`\n").endswith("pip install -e . && dvc repro"), first
    assert second.rstrip("`\n").endswith(test_command), (second, test_command)


def layout_names() -> set[str]:
    """Every module as docs/layout.md names it: its path from the repository root; a package's
    __init__.py by its folder (mop_core/distill/)."""
    files = sorted((ROOT / "mop_core").rglob("*.py")) + sorted((ROOT / "stages").rglob("*.py"))
    return {path.parent.relative_to(ROOT).as_posix() + "/" if path.name == "__init__.py"
            else path.relative_to(ROOT).as_posix() for path in files}


def test_the_layout_names_every_module_and_stage_script():
    named = set(NAMED_PATH.findall(LAYOUT.read_text()))
    missing = sorted(layout_names() - named)
    assert not missing, f"docs/layout.md does not name {missing}: add a line each (the module's docstring says what)"


def test_every_module_the_layout_names_exists():
    named = set(NAMED_PATH.findall(LAYOUT.read_text()))
    gone = sorted(name for name in named
                  if not ((ROOT / name).is_dir() if name.endswith("/") else (ROOT / name).is_file()))
    assert not gone, f"docs/layout.md names {gone}, which do not exist: moved or removed?"


def test_every_stage_script_is_thin():
    """A stage script parses its arguments, asks the catalogue and the library, and writes: <= 60 lines
    (stages/common.py, what every stage shares, aside)."""
    long = {p.name: n for p in sorted((ROOT / "stages").glob("*.py")) if p.name != "common.py"
            and (n := len(p.read_text().splitlines())) > 60}
    assert not long, f"stage scripts over 60 lines: {long}"


def test_the_pipeline_definition_is_short():
    """dvc.yaml stays <= 600 lines: the distill stages share one params list and list their code deps
    as folders, so a new student family adds one short stage, not 50 lines of copies."""
    n = len((ROOT / "dvc.yaml").read_text().splitlines())
    assert n <= 600, f"dvc.yaml has {n} lines (at most 600)"
