"""The whole params file, checked before any stage computes anything (the ``params`` stage).

:func:`check_params` builds every section's typed config (rejecting unknown keys) and checks them
against each other: unknown sections and keys, repeated grid entries, cross-section references
(teacher seeds, actors, levels), sizes against the data the study will produce (a batch larger than
its dataset) and settings that would have no effect in the given study (DAgger rounds that never
run within the distillation steps, a variant that trains plain MOP's students again, two composed
datasets of the same episodes). It imports every learner's config, so only the params stage (which
reruns in seconds) depends on all of the library; the other stages read just their own sections.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping

from mop_core.agents.pbrl import PBRLConfig
from mop_core.collect import CollectConfig, collect_configs
from mop_core.config import ConfigError, keys_under, require
from mop_core.distill.config import DistillConfig, distill_config
from mop_core.experiment.catalogue import LOSS_ACTORS, shift_variants, structure_variants
from mop_core.experiment.study import (
    DISTILL_GRID_KEYS,
    SECTIONS,
    EvalConfig,
    StudyConfig,
    check_sections,
    distill_grid,
    multitask_grid,
    pairing_levels,
    section,
    sharing_grid,
    shift_grid,
    structure_grid,
    study_config,
    teacher_grid,
    typed_section,
)
from mop_core.relabel import RelabelConfig
from mop_core.shared_computation import SharedComputationConfig, shared_computation_config
from mop_core.shift.compose import ComposeConfig, compose_config
from mop_core.shift.study import measure_config
from mop_core.teachers import teacher_config
from mop_core.walker.tasks import get_task


def _fields(config_type: type) -> frozenset[str]:
    return frozenset(f.name for f in dataclasses.fields(config_type))


# The sections whose keys differ from their typed config's fields: section -> (its keys in a params file,
# fields a params file does not set because the section's own check refuses them with a message of its own:
# train_teachers.pbrl.actor, distill.loss, distill.correction).
SECTION_KEYS = {
    "collect": (_fields(CollectConfig) - {"episode_length"} | {"parallel"}, frozenset()),
    "train_teachers.pbrl": (_fields(PBRLConfig) - {"actor"}, frozenset({"actor"})),
    "distill": (_fields(DistillConfig) - {"loss", "correction", "data_fraction"} | set(DISTILL_GRID_KEYS),
                frozenset({"loss", "correction"})),
    "shared_computation": (_fields(SharedComputationConfig) | {"threads"}, frozenset()),
}
# config fields that another key sets: a params file that sets them here would be overridden or ignored
SET_ELSEWHERE = {
    "collect.episode_length": "study.episode_length (the collect stage's episodes are the study's)",
    "distill.data_fraction": "state_shift.data_percents (the students on a share of each dataset)",
}


def check_section_keys(params: Mapping[str, Any]) -> None:
    """Every key of the sections in SECTION_KEYS is one of theirs, with the list of the section's own
    keys in the error (not its typed config's fields, some of which the params file does not set)."""
    for where, (known, refused_later) in SECTION_KEYS.items():
        node: Any = params
        for part in where.split("."):
            node = node.get(part) if isinstance(node, Mapping) else None
        if not isinstance(node, Mapping):
            continue  # the section's typed config names what it expected
        for key in sorted(node, key=str):
            if f"{where}.{key}" in SET_ELSEWHERE:
                raise ConfigError(f"{where}.{key}: not a parameter of this section; set "
                                  f"{SET_ELSEWHERE[f'{where}.{key}']} instead")
            if key not in known and key not in refused_later:
                raise ConfigError(f"{where}.{key}: unknown parameter; known: {', '.join(sorted(known))}")


def check_target_returns(collect: CollectConfig) -> None:
    """A per-task medium target return or expert criterion names registered tasks (a misspelt one would be
    ignored)."""
    for key in ("medium_target_return", "expert_return"):
        targets = getattr(collect.schedule, key)
        if isinstance(targets, dict):
            for task in targets:
                get_task(task, f"collect.schedule.{key}.{task}")


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
        pbrl = teacher_config(params, study, actor, study.levels[0]).pbrl  # one PBRL setting for every level
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
    check_compositions(compose)
    for name, raw in grid.compositions.items():  # compose_config typed every entry
        require(not (isinstance(raw, Mapping) and "rest" in raw and compose.compositions[name].teacher_share == 1),
                f"state_shift.compositions.{name}.rest", "no rest with teacher_share 1 (the teacher acts in every "
                "episode: no episode acts by the rest)", raw.get("rest") if isinstance(raw, Mapping) else None)
    measure_config(grid)
    config = distill_config(params, "mse")
    if "dagger" in grid.corrections:  # round k starts at update k * steps // (rounds + 1): distinct only below
        steps = distill_grid(params, study, LOSS_ACTORS).schedule.steps
        require(config.dagger.rounds < steps, "distill.dagger.rounds", f"at most distill.schedule.steps - 1 = "
                f"{steps - 1} (the DAgger students' {steps} steps are cut into rounds + 1 phases of at least one "
                "step; more rounds could never run)", config.dagger.rounds)
    with keys_under("distill"):
        for variant in shift_variants(params)[1]:
            variant.apply(config)
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


def check_compositions(compose: ComposeConfig) -> None:
    """The composed datasets are different compositions (two names of one composition are the same
    episodes twice: each pool's first episodes are shared), and noisy-teacher episodes come with noise
    (at noise_std 0 they are the teacher's own)."""
    seen: dict[tuple, str] = {}
    for i, name in enumerate(compose.datasets):
        composition = compose.compositions[name]
        same = (composition.teacher_share, composition.rest if composition.teacher_share < 1 else "")
        require(same not in seen, f"state_shift.datasets[{i}]", f"a composition other than that of "
                f"{seen.get(same)!r} (both are teacher_share {same[0]}{f', rest {same[1]}' if same[1] else ''}: "
                "the same data twice)", name)
        seen[same] = name
        noisy = composition.rest == "noise" and any(others for _, others in (compose.counts(name),
                                                                            compose.counts(name, heldout=True)))
        require(not noisy or compose.noise_std > 0, "state_shift.noise_std", f"a positive number while "
                f"state_shift.datasets has {name!r}, whose noisy-teacher episodes are the teacher's own at 0",
                compose.noise_std)


def check_structure(params: Mapping[str, Any], study: StudyConfig) -> None:
    """A common_structure variant differs from the plain MSE students it is compared with: a width
    other than theirs, a ranking loss that is on (distill.ranking's weights) and not theirs."""
    grid = structure_grid(params, study)
    config = distill_config(params, "mse")
    sizes = config.student.hidden_sizes
    if len(set(sizes)) == 1:
        for i, width in enumerate(grid.widths):
            require(width != sizes[0], f"common_structure.widths[{i}]", f"a width other than distill.student."
                    f"hidden_sizes' {sizes[0]} (the plain MSE students are that wide: the same students twice)",
                    width)
    if grid.ranking_losses:
        ranking = config.ranking
        require(ranking.weight > 0, "distill.ranking.weight", "a positive number while common_structure."
                "ranking_losses is set (at 0 its ranking students are the plain MSE students)", ranking.weight)
        require(any(w > 0 for w in ranking.weights_for(len(sizes))), "distill.ranking.layer_weights",
                "a positive weight for some layer while common_structure.ranking_losses is set (all 0: its "
                "ranking students are the plain MSE students)", list(ranking.layer_weights))
        for i, loss in enumerate(grid.ranking_losses):
            require(loss != ranking.loss, f"common_structure.ranking_losses[{i}]", f"a loss other than "
                    f"distill.ranking.loss (the plain MSE students learn with {loss} already: the same students "
                    "twice)", loss)


def check_params(params: Mapping[str, Any], where: str = "params.yaml") -> None:
    """Build every section's typed config and check them against each other; raise ConfigError."""
    check_sections(params, where)
    for name in SECTIONS:
        section(params, name)
    check_section_keys(params)
    study = study_config(params)
    _, collect = collect_configs(params, study)
    check_target_returns(collect)
    for task in study.tasks:  # a criterion for every study task, named before any compute
        collect.schedule.expert_criterion(task)
    with keys_under("collect.schedule"):
        for task in study.tasks:  # a per-task target return names every study task
            collect.schedule.medium_target(task)
    typed_section(params, "relabel", RelabelConfig)
    for actor in teacher_grid(params).actors:
        for level in study.levels:  # a schedule for every study level (steps may be one per level)
            teacher_config(params, study, actor, level)
    multitask_grid(params, study)
    for loss in distill_grid(params, study, LOSS_ACTORS).losses:
        distill_config(params, loss)
    variants = structure_variants(params)[1]
    with keys_under("distill"):  # a variant's settings (ranking.states against batch_size) under distill.*
        for variant in variants:
            variant.apply(distill_config(params, "mse"))
    check_structure(params, study)
    sharing_grid(params, study)
    check_batch_sizes(params, study, collect)
    check_shift(params, study, collect)
    evaluation = typed_section(params, "eval", EvalConfig)
    for i, task in enumerate(evaluation.transfer_tasks):
        require(task not in study.tasks, f"eval.transfer_tasks[{i}]", "a task outside study.tasks (the study's "
                "own tasks are evaluated already)", task)
    require(not evaluation.transfer_tasks or "deterministic" in teacher_grid(params).actors, "eval.transfer_tasks",
            "[] unless train_teachers.actors includes deterministic (only the deterministic teachers are evaluated "
            "on the transfer tasks)", list(evaluation.transfer_tasks))
    shared_computation_config(params)
