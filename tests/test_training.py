"""The training loop's machinery: run fingerprints, resume files, non-finite checks, the end of a run,
and train_loop on a toy learner (an interrupted run resumed equals an uninterrupted one)."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
import torch

from mop_core.learning.resume import RESUME_KIND, non_finite_tensor, run_fingerprint, try_resume
from mop_core.learning.runtime import TrainingDivergedError
from mop_core.learning.schedule import TrainSchedule
from mop_core.learning.training import finish_run, train_loop
from mop_core.storage.artifacts import read_curve, save_checkpoint
from mop_core.storage.layout import RunPaths


def paths(root) -> RunPaths:
    return RunPaths(root / "run.pt", root / "metrics.json", root / "curve.tsv", root / "resume" / "run.pt")


class Toy:
    """A learner whose weight follows a seeded random walk: its state is the weight and the step count."""

    def __init__(self, sampler: torch.Generator):
        self.weight, self.sampler = torch.zeros(3), sampler

    def update(self) -> dict:
        self.weight = self.weight + torch.randn(3, generator=self.sampler)
        return {"loss": float(self.weight.pow(2).sum())}

    def state_dict(self) -> dict:
        return {"weight": self.weight.clone()}

    def load_state_dict(self, state: dict) -> None:
        self.weight = state["weight"].clone()


def run_toy(root, schedule: TrainSchedule, stop_at: int | None = None):
    sampler = torch.Generator().manual_seed(0)
    toy = Toy(sampler)

    def update() -> dict:
        if stop_at is not None and toy.updates_done == stop_at:
            raise KeyboardInterrupt
        toy.updates_done += 1
        return toy.update()

    toy.updates_done = 0
    curve, _, resumed_from = train_loop(toy, update, lambda seeds: {"return_mean": float(toy.weight.sum())},
                                        schedule, {"eval": 0}, sampler, paths(root).resume, "toy", "toy", False)
    return toy, curve, resumed_from


def test_the_fingerprint_depends_on_content_not_key_order():
    assert run_fingerprint({"a": 1, "b": [2, 3]}) == run_fingerprint({"b": [2, 3], "a": 1})
    assert run_fingerprint({"a": 1}) != run_fingerprint({"a": 2})


def test_a_resume_file_is_used_only_by_the_run_it_belongs_to(tmp_path, capsys):
    path = tmp_path / "resume.pt"
    assert try_resume(path, "abc") is None  # none yet: a fresh start
    save_checkpoint(path, {"kind": RESUME_KIND, "fingerprint": "abc", "step": 5})
    assert try_resume(path, "abc")["step"] == 5
    assert try_resume(path, "other") is None and "another configuration" in capsys.readouterr().out
    save_checkpoint(path, {"kind": "pbrl_teacher"})
    assert try_resume(path, "abc") is None and "ignoring resume file" in capsys.readouterr().out


def test_non_finite_tensor_names_the_nested_key():
    state = {"actor": {"w": torch.ones(2)}, "optimizers": [{"m": torch.tensor([0.0, float("nan")])}],
             "steps": torch.tensor([3])}
    assert non_finite_tensor(state) == "optimizers.0.m"
    assert non_finite_tensor({"w": torch.ones(2), "n": torch.tensor([1, 2])}) is None


def test_finish_run_writes_every_file_and_drops_the_resume_file_last(tmp_path):
    p = paths(tmp_path)
    p.resume.parent.mkdir()
    p.resume.write_bytes(b"resume")
    p = replace(p, timing=tmp_path / "timings" / "run.json")
    metrics = finish_run(p, {"kind": "toy", "w": torch.ones(1)}, [{"step": 1, "return_mean": 2.0}], {"r": 2.0},
                         seconds=4.0, steps=8, resumed_from=2, device="cpu")
    assert metrics == {"r": 2.0} and not p.resume.exists()
    checkpoint = torch.load(p.checkpoint, weights_only=False)
    assert checkpoint == {"kind": "toy", "w": torch.ones(1)}  # what the learner computed, nothing else
    assert json.loads(p.metrics.read_text()) == {"r": 2.0}
    assert read_curve(p.curve) == [{"step": "1", "return_mean": "2.0"}]
    timing = json.loads(p.timing.read_text())  # times and machine facts: only here
    assert timing["seconds"] == 4.0 and timing["steps_per_second"] == 2.0 and timing["resumed_from_step"] == 2
    assert "torch==" in timing["versions"] and timing["device"] == "cpu"


def test_a_rerun_writes_the_same_checkpoint_curve_and_metrics_bytes(tmp_path):
    """A forced rerun must not make later stages stale: only the timing record may differ."""
    schedule = TrainSchedule(steps=6, eval_every=3, eval_episodes=1, checkpoint_every=3)
    outputs = []
    for name, seconds in (("a", 1.0), ("b", 2.5)):  # the second run took longer
        agent, curve, _ = run_toy(tmp_path / name, schedule)
        p = replace(paths(tmp_path / name), timing=tmp_path / name / "timing.json")
        finish_run(p, {"kind": "toy", "w": agent.weight.detach().clone()}, curve, {"w": float(agent.weight[0])},
                   seconds=seconds, steps=6, resumed_from=0, device="cpu")
        outputs.append([f.read_bytes() for f in (p.checkpoint, p.curve, p.metrics)])
    assert outputs[0] == outputs[1]


def test_an_interrupted_run_resumes_to_the_uninterrupted_curve_and_weights(tmp_path):
    schedule = TrainSchedule(steps=12, eval_every=4, eval_episodes=1, checkpoint_every=3)
    whole, whole_curve, resumed = run_toy(tmp_path / "a", schedule)
    assert resumed == 0 and [row["step"] for row in whole_curve] == [4, 8, 12]
    with pytest.raises(KeyboardInterrupt):
        run_toy(tmp_path / "b", schedule, stop_at=7)  # after the resume file of step 6
    again, curve, resumed = run_toy(tmp_path / "b", schedule)
    assert resumed == 6
    assert torch.equal(again.weight, whole.weight)
    assert curve == whole_curve  # no wall-clock column: a resumed curve is the same record


def test_a_non_finite_loss_stops_the_run_naming_it(tmp_path):
    schedule = TrainSchedule(steps=4, eval_every=4, eval_episodes=1, checkpoint_every=4)
    toy = Toy(torch.Generator().manual_seed(0))
    with pytest.raises(TrainingDivergedError, match="toy run: loss = nan at step 1"):
        train_loop(toy, lambda: {"loss": float("nan")}, lambda seeds: {"return_mean": 0.0}, schedule, {"eval": 0},
                   toy.sampler, paths(tmp_path).resume, "toy", "toy run", False)
