"""Shared fixtures: the tiny profile as typed configs; single-threaded torch; no progress bars."""

from __future__ import annotations

import ast
import importlib.util
import os
import sys
from pathlib import Path

import pytest
import torch
import yaml

os.environ.setdefault("MOP_PROGRESS", "0")
torch.set_num_threads(1)

ROOT = Path(__file__).resolve().parents[1]
TINY_PROFILE = ROOT / "profiles" / "tiny.yaml"
# The device the learner tests and the tiny dvc repro run on: cpu here and in CI; benchmarks/gpu_check.sh
# runs the suite with MOP_TEST_DEVICE=cuda on a GPU machine (the CUDA path end to end).
TEST_DEVICE = os.environ.get("MOP_TEST_DEVICE", "cpu")


@pytest.fixture(scope="session")
def device() -> torch.device:
    return torch.device(TEST_DEVICE)


@pytest.fixture(scope="session")
def tiny_params() -> dict:
    return yaml.safe_load(TINY_PROFILE.read_text())


@pytest.fixture(scope="session")
def tiny_collect_config(tiny_params):
    from mop_core.collect import CollectConfig
    from mop_core.config import from_mapping

    raw = {k: v for k, v in tiny_params["collect"].items() if k != "parallel"}
    return from_mapping(CollectConfig, raw | {"episode_length": tiny_params["study"]["episode_length"]}, "collect")


def collect_paths(root: Path, task: str):
    from mop_core.collect import LEVELS, CollectPaths

    return CollectPaths(
        checkpoints={lv: root / "behaviour" / task / f"{lv}.pt" for lv in ("medium", "expert")},
        datasets={lv: root / "datasets" / f"{task}-{lv}.hdf5" for lv in LEVELS},
        dataset_metrics={lv: root / "metrics" / f"{task}-{lv}.json" for lv in LEVELS},
        curve=root / "curves" / f"{task}.tsv",
    )


@pytest.fixture(scope="session")
def tiny_collected(tmp_path_factory, tiny_collect_config):
    """The tiny collect step of 'stand' run once: (root dir, summary)."""
    from mop_core.collect import collect_task

    root = tmp_path_factory.mktemp("collect")
    summary = collect_task("stand", tiny_collect_config, 0, collect_paths(root, "stand"))
    return root, summary


@pytest.fixture(scope="session")
def tiny_teachers(tiny_collected, tmp_path_factory):
    """Tiny teachers for two tasks from the tiny 'stand' data: stand on D_{stand->stand} (medium), walk
    on D_{stand->walk} (expert); deterministic and Gaussian. ``{(task, actor): checkpoint}`` and the
    dataset of each task."""
    from mop_core.agents.pbrl import PBRLConfig
    from mop_core.learning.schedule import TrainSchedule
    from mop_core.learning.training import RunPaths
    from mop_core.relabel import RelabelConfig, relabel_dataset
    from mop_core.teachers import DataSource, TeacherConfig, train_teacher

    root, _ = tiny_collected
    out = tmp_path_factory.mktemp("teachers")
    datasets = {"stand": root / "datasets" / "stand-medium.hdf5", "walk": root / "datasets" / "stand-expert.hdf5"}
    schedule = TrainSchedule(steps=20, eval_every=20, eval_episodes=1, final_eval_episodes=2, checkpoint_every=20,
                             rollout_envs=2)
    checkpoints = {}
    for task, dataset in datasets.items():
        relabel = out / f"{task}-relabel.hdf5"
        relabel_dataset(dataset, relabel, ["stand", "walk"], RelabelConfig(physics_check_transitions=0))
        for actor in ("deterministic", "gaussian"):
            config = TeacherConfig(PBRLConfig(actor=actor, hidden_sizes=(16, 16), ensemble_size=3, batch_size=16,
                                              ood_actions=1, learning_rate=1e-3), schedule, episode_length=50)
            run = out / f"{task}-{actor}"
            paths = RunPaths(run / "teacher.pt", run / "metrics.json", run / "curve.tsv", run / "resume.pt")
            train_teacher(task, DataSource(dataset, relabel, task), config, 0, 0, paths)
            checkpoints[(task, actor)] = paths.checkpoint
    return checkpoints, datasets


def params_stage():
    """stages/check_params.py as a module: its ``main`` is the params stage of dvc.yaml."""
    if str(ROOT / "stages") not in sys.path:
        sys.path.insert(0, str(ROOT / "stages"))
    spec = importlib.util.spec_from_file_location("check_params_stage", ROOT / "stages" / "check_params.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def runtime_imports(tree: ast.AST) -> list[ast.AST]:
    """Every import node of ``tree`` but those under ``if TYPE_CHECKING:`` (annotations only: no behaviour)."""
    out, todo = [], [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            todo += node.orelse
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            out.append(node)
        todo += ast.iter_child_nodes(node)
    return out
