"""Shared fixtures: the tiny profile as typed configs; single-threaded torch; no progress bars."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch
import yaml

os.environ.setdefault("MOP_PROGRESS", "0")
torch.set_num_threads(1)

ROOT = Path(__file__).resolve().parents[1]
TINY_PROFILE = ROOT / "profiles" / "tiny.yaml"


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
