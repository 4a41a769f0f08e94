"""The whole params file as typed configs, checked together before any stage computes anything.

The ``params`` stage of dvc.yaml (stages/check_params.py) runs :func:`check_params`: it is upstream
of every other stage, so a bad value anywhere stops ``dvc repro`` in a few seconds, with one line
naming the key, before DVC deletes any stage's outputs. Each stage script also builds its own
sections' typed configs (rejecting unknown keys) when run by hand; every script rejects unknown
sections (common.load_params).

Checks beyond each section's own types: unknown sections, repeated grid entries, cross-section
references (teacher seeds, actors, levels) and sizes against the data the study will produce (a
batch larger than its dataset).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from collect import collect_configs
from common import PARAMS, SECTIONS, check_sections, load_params, section, study_config
from distill_config import distill_config, distill_grid, pairing_levels
from eval import eval_config
from relabel import relabel_config
from shared_computation import shared_computation_config
from teacher_config import multitask_grid, teacher_config, teacher_grid

from mop_core.collect import CollectConfig
from mop_core.config import require


def dataset_transitions(config: CollectConfig, level: str) -> int | None:
    """How many transitions the collect stage writes for ``level`` (None: known only after collect,
    i.e. medium_replay when the medium snapshot is chosen by a target return)."""
    episode_length = config.episode_length
    if level == "expert":
        return config.datasets.expert_episodes * episode_length
    if level == "medium":
        return config.datasets.medium_episodes * episode_length
    if config.schedule.medium_target_return is None:  # medium_replay: everything seen up to the snapshot
        return config.schedule.warmup_steps + config.schedule.medium_step
    return None


def check_params(params: dict[str, Any]) -> None:
    """Build every section's typed config and check them against each other; raise ConfigError."""
    check_sections(params)
    for name in SECTIONS:
        section(params, name)
    study = study_config(params)
    _, collect = collect_configs(params, study)
    relabel_config(params)
    teachers = teacher_grid(params)
    sizes = {level: dataset_transitions(collect, level) for level in study.levels}
    for actor in teachers.actors:
        pbrl = teacher_config(params, study, actor).pbrl
        for level, transitions in sizes.items():
            require(transitions is None or pbrl.batch_size <= transitions, "train_teachers.pbrl.batch_size",
                    f"at most the {transitions} transitions of each {level} dataset", pbrl.batch_size)
    multitask_grid(params, study)
    grid = distill_grid(params, study)
    for loss in grid.losses:
        config = distill_config(params, loss)
        for pairing in grid.pairings:
            for level in set(pairing_levels(pairing, study, "distill.pairings")):
                states = config.num_states if config.state_source == "online" else sizes[level]
                if config.state_source == "offline" and config.num_states and states is not None:
                    states = min(states, config.num_states)
                require(states is None or config.batch_size <= states, "distill.batch_size",
                        f"at most the {states} states per task the {level} students learn from", config.batch_size)
    eval_config(params)
    shared_computation_config(params)


def load_study_params(path: Path = PARAMS) -> dict[str, Any]:
    """params.yaml, after :func:`check_params` passed on all of it."""
    params = load_params(path)
    check_params(params)
    return params
