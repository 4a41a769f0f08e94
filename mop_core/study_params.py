"""The whole params file, checked before any stage computes anything (the ``params`` stage).

:func:`check_params` builds every section's typed config (rejecting unknown keys) and checks them
against each other: unknown sections, repeated grid entries, cross-section references (teacher
seeds, actors, levels) and sizes against the data the study will produce (a batch larger than its
dataset). It imports every learner's config, so only the params stage (which reruns in seconds)
depends on all of the library; the other stages read just their own sections.
"""

from __future__ import annotations

from typing import Any, Mapping

from mop_core.catalogue import LOSS_ACTORS, shift_variants, structure_variants
from mop_core.collect import CollectConfig, collect_configs
from mop_core.compose import compose_config
from mop_core.config import keys_under, require
from mop_core.distill.distiller import distill_config
from mop_core.distill.variants import variant_config
from mop_core.evaluation import EvalConfig
from mop_core.relabel import RelabelConfig
from mop_core.shared_computation import shared_computation_config
from mop_core.shift_study import measure_config
from mop_core.study import (
    SECTIONS,
    StudyConfig,
    check_sections,
    distill_grid,
    multitask_grid,
    pairing_levels,
    section,
    sharing_grid,
    shift_grid,
    study_config,
    teacher_grid,
    typed_section,
)
from mop_core.teachers import teacher_config


def dataset_transitions(config: CollectConfig, level: str) -> int | None:
    """How many transitions the collect stage writes for ``level`` (None: known only after collect,
    i.e. medium_replay when the medium snapshot is chosen by a target return)."""
    if level == "expert":
        return config.datasets.expert_episodes * config.episode_length
    if level == "medium":
        return config.datasets.medium_episodes * config.episode_length
    if config.schedule.medium_target_return is None:  # medium_replay: everything seen up to the snapshot
        return config.schedule.warmup_steps + config.schedule.medium_step
    return None


def check_batch_sizes(params: Mapping[str, Any], study: StudyConfig, collect: CollectConfig) -> None:
    """Batches no larger than the data the study will produce (a typo, not an experiment)."""
    sizes = {level: dataset_transitions(collect, level) for level in study.levels}
    for actor in teacher_grid(params).actors:
        pbrl = teacher_config(params, study, actor).pbrl
        for level, transitions in sizes.items():
            require(transitions is None or pbrl.batch_size <= transitions, "train_teachers.pbrl.batch_size",
                    f"at most the {transitions} transitions of each {level} dataset", pbrl.batch_size)
    grid = distill_grid(params, study, LOSS_ACTORS)
    for loss in grid.losses:
        config = distill_config(params, loss)
        for pairing in grid.pairings:
            for level in set(pairing_levels(pairing, study, "distill.pairings")):
                states = config.num_states if config.state_source == "online" else sizes[level]
                if config.state_source == "offline" and config.num_states and states is not None:
                    states = min(states, config.num_states)
                require(states is None or config.batch_size <= states, "distill.batch_size",
                        f"at most the {states} states per task the {level} students learn from", config.batch_size)


def check_shift(params: Mapping[str, Any], study: StudyConfig, collect: CollectConfig) -> None:
    """The state_shift section: its grid, composed data and measure settings, its students' configs,
    and the distill batch against the states they learn from (a composed dataset, a dataset share)."""
    grid = shift_grid(params, study)
    compose = compose_config(grid)
    measure_config(grid)
    config = distill_config(params, "mse")
    with keys_under("distill"):
        for variant in shift_variants(params)[1]:
            variant_config(config, variant)
    if grid.datasets:
        states = compose.episodes * study.episode_length
        require(config.batch_size <= states, "distill.batch_size", f"at most the {states} states of a composed "
                "dataset (state_shift.episodes x study.episode_length)", config.batch_size)
    for percent in grid.data_percents:
        for level in set(pairing_levels(grid.pairing, study, "state_shift.pairing")):
            transitions = dataset_transitions(collect, level)
            if transitions is not None:
                episodes = transitions // study.episode_length
                states = max(1, round(percent / 100 * episodes)) * study.episode_length
                require(config.batch_size <= states, "distill.batch_size", f"at most the {states} states of "
                        f"{percent}% of the {level} dataset's episodes (state_shift.data_percents)", config.batch_size)


def check_params(params: Mapping[str, Any], where: str = "params.yaml") -> None:
    """Build every section's typed config and check them against each other; raise ConfigError."""
    check_sections(params, where)
    for name in SECTIONS:
        section(params, name)
    study = study_config(params)
    _, collect = collect_configs(params, study)
    with keys_under("collect.schedule"):
        for task in study.tasks:  # a per-task target return names every study task
            collect.schedule.medium_target(task)
    typed_section(params, "relabel", RelabelConfig)
    for actor in teacher_grid(params).actors:
        teacher_config(params, study, actor)
    multitask_grid(params, study)
    for loss in distill_grid(params, study, LOSS_ACTORS).losses:
        distill_config(params, loss)
    variants = structure_variants(params)[1]
    with keys_under("distill"):  # a variant's settings (ranking.states against batch_size) under distill.*
        for variant in variants:
            variant_config(distill_config(params, "mse"), variant)
    sharing_grid(params, study)
    check_batch_sizes(params, study, collect)
    check_shift(params, study, collect)
    evaluation = typed_section(params, "eval", EvalConfig)
    for i, task in enumerate(evaluation.transfer_tasks):
        require(task not in study.tasks, f"eval.transfer_tasks[{i}]", "a task outside study.tasks (the study's "
                "own tasks are evaluated already)", task)
    shared_computation_config(params)
