"""What ships and what DVC watches: the wheel holds every module of mop_core, and every stage lists
every mop_core module it imports (directly or through other modules) as a dependency in dvc.yaml,
so changing that code reruns the stage."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import yaml
from conftest import ROOT, runtime_imports

LIBRARY = ROOT / "mop_core"


def without_behaviour(path: Path) -> bool:
    """A package ``__init__.py`` that holds only a docstring and constants: nothing to rerun a stage for."""
    body = ast.parse(path.read_text()).body
    return path.name == "__init__.py" and all(
        isinstance(node, (ast.Expr, ast.Assign)) and not any(isinstance(n, ast.Call) for n in ast.walk(node))
        for node in body)


def library_modules() -> list[str]:
    return sorted(".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
                  for p in LIBRARY.rglob("*.py"))


def test_the_wheel_holds_and_imports_every_module(tmp_path):
    source = tmp_path / "source"  # a copy: setuptools builds in the source tree
    shutil.copytree(LIBRARY, source / "mop_core", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", source)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(tmp_path / "dist"), str(source)], check=True, capture_output=True, text=True)
    (wheel,) = (tmp_path / "dist").glob("mop_core-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for module in library_modules():
        path = module.replace(".", "/")
        assert f"{path}.py" in names or f"{path}/__init__.py" in names, f"{module} is not in {wheel.name}"
    unpacked = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(unpacked)
    script = ("import importlib, sys\n"
              f"for name in {library_modules()!r}:\n"
              "    module = importlib.import_module(name)\n"
              f"    assert module.__file__.startswith({str(unpacked)!r}), (name, module.__file__)\n")
    env = os.environ | {"PYTHONPATH": str(unpacked)}  # ahead of the editable install of the checkout
    result = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def module_file(name: str) -> Path | None:
    """The file of a module of this repository (mop_core.x.y or a stage helper), else None."""
    parts = name.split(".")
    for candidate in (ROOT.joinpath(*parts).with_suffix(".py"), ROOT.joinpath(*parts, "__init__.py"),
                      ROOT / "stages" / f"{name}.py"):
        if candidate.is_file():
            return candidate
    return None


def imported_files(script: Path) -> set[str]:
    """Every repository file ``script`` imports, transitively (function-level imports included), and
    the ``__init__.py`` of every package on the way."""
    seen: set[Path] = set()
    todo = [script]
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for node in runtime_imports(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
            for name in names:
                parts = name.split(".")
                for k in range(1, len(parts) + 1):  # the packages on the way, then the module itself
                    found = module_file(".".join(parts[:k]))
                    if found is not None:
                        todo.append(found)
    return {p.relative_to(ROOT).as_posix() for p in seen}


def test_every_stage_depends_on_the_code_it_imports():
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    missing = {}
    for name, stage in stages.items():
        script = ROOT / stage["cmd"].split()[1]
        deps = [d for d in stage["deps"] if "${" not in d]
        needed = {f for f in imported_files(script) if not without_behaviour(ROOT / f)}
        uncovered = sorted(f for f in needed if not any(f == d or f.startswith(d.rstrip("/") + "/") for d in deps))
        if uncovered:
            missing[name] = uncovered
    assert not missing, f"dvc.yaml stages miss code dependencies: {missing}"


def test_every_stage_that_picks_the_device_lists_the_params_it_picks_by():
    """A stage whose script calls study_device trains on study.device in study.cuda_matmul: dvc.yaml must
    list both (or the whole study section), or a changed precision would not rerun it (collect once did not)."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    picking = {name for name, stage in stages.items()
               if "study_device(" in (ROOT / stage["cmd"].split()[1]).read_text()}
    assert {"collect", "train_teachers", "train_multitask", "distill"} <= picking
    unlisted = {name: keys for name in picking
                if (keys := {"study.device", "study.cuda_matmul"} - set(stages[name]["params"]))
                and "study" not in stages[name]["params"]}
    assert not unlisted, f"dvc.yaml stages miss the device params they read: {unlisted}"


def test_the_import_walk_finds_lazy_and_transitive_imports():
    files = imported_files(ROOT / "stages" / "eval.py")
    assert "mop_core/collect.py" in files  # through mop_core.policies (the behaviour checkpoint's kind)
    assert "mop_core/agents/td3.py" in files  # through mop_core.policies
    assert "stages/common.py" in files and "mop_core/data/hdf5.py" in files


def test_docstring_only_package_files_are_the_only_exemption():
    assert without_behaviour(LIBRARY / "__init__.py") and without_behaviour(LIBRARY / "agents" / "__init__.py")
    assert not without_behaviour(LIBRARY / "data" / "__init__.py")  # re-exports: imports run code
    assert not without_behaviour(LIBRARY / "learning" / "nn.py")
