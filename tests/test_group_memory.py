"""Group sizing from measured device memory: waves of as many runs as fit, the GPU share a scheduler
gives, clear errors where nothing fits; the footprint probe measured on a GPU."""

from __future__ import annotations

import pytest
import torch

from mop_core.learning.group_memory import (
    GPU_SHARE_ENV,
    HEADROOM,
    GroupFootprint,
    device_room,
    gpu_share,
    measure_footprint,
    split_waves,
    wave_sizes,
)

GIB = 2**30


def test_a_group_the_room_holds_is_one_wave():
    footprint = GroupFootprint(fixed=GIB, per_run=GIB)
    assert wave_sizes(9, footprint, room=20 * GIB) == [9]
    assert wave_sizes(9, None, room=None) == [9]  # a CPU: no room limit
    assert wave_sizes(9, footprint, room=None) == [9]


def test_a_group_too_large_trains_in_near_equal_waves_that_each_fit():
    footprint = GroupFootprint(fixed=GIB, per_run=2 * GIB)
    room = 10 * GIB  # 85% of it, less the fixed part, holds 3 runs
    sizes = wave_sizes(9, footprint, room)
    assert sizes == [3, 3, 3]
    assert all(footprint.bytes(size) <= room * HEADROOM for size in sizes)
    assert wave_sizes(7, footprint, room) == [3, 2, 2]  # as even as the runs allow, larger first
    assert wave_sizes(7, None, None, max_group=4) == [4, 3]
    assert wave_sizes(4, footprint, 100 * GIB, max_group=1) == [1, 1, 1, 1]


def test_no_room_for_one_run_names_the_need_before_any_compute():
    with pytest.raises(MemoryError, match=r"a teacher of medium needs 3\.00 GiB.*2\.00 GiB per run"):
        wave_sizes(2, GroupFootprint(fixed=GIB, per_run=2 * GIB), 2 * GIB, "a teacher of medium")
    with pytest.raises(ValueError, match="max_group"):
        wave_sizes(2, None, None, max_group=0)


def test_waves_cut_the_runs_in_order():
    assert split_waves(list("abcdefg"), [3, 2, 2]) == [list("abc"), list("de"), list("fg")]
    with pytest.raises(ValueError, match="covering 3"):
        split_waves([1, 2, 3], [2])


def test_the_gpu_share_is_read_and_checked(monkeypatch):
    monkeypatch.delenv(GPU_SHARE_ENV, raising=False)
    assert gpu_share() == 1.0
    monkeypatch.setenv(GPU_SHARE_ENV, "0.25")
    assert gpu_share() == 0.25
    for bad in ("0", "1.5", "a quarter"):
        monkeypatch.setenv(GPU_SHARE_ENV, bad)
        with pytest.raises(ValueError, match=f"{GPU_SHARE_ENV}: expected the share of one GPU"):
            gpu_share()


def test_off_cuda_there_is_no_room_limit_and_nothing_to_measure():
    assert device_room("cpu") is None
    assert measure_footprint(lambda runs: pytest.fail("no probe off CUDA"), "cpu") is None


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_pbrl_groups_footprint_grows_with_its_runs_and_a_share_caps_the_room(monkeypatch):
    from mop_core.agents.pbrl import PBRLConfig
    from mop_core.agents.pbrl_group import probe_group, stack_batches
    from mop_core.data.buffer import Batch

    config = PBRLConfig(hidden_sizes=(256, 256), batch_size=256, ensemble_size=5, ood_actions=3)
    device = torch.device("cuda")

    def batch(runs: int) -> Batch:
        g = torch.Generator(device).manual_seed(runs)
        one = Batch(torch.randn(256, 24, device=device, generator=g),
                    torch.rand(256, 6, device=device, generator=g) * 2 - 1, torch.rand(256, device=device, generator=g),
                    torch.randn(256, 24, device=device, generator=g), torch.zeros(256, device=device))
        return stack_batches([one] * runs)

    footprint = measure_footprint(probe_group(config, 24, 6, batch, device), device)
    assert footprint.per_run > 0
    monkeypatch.setenv(GPU_SHARE_ENV, "0.01")
    assert device_room(device) <= 0.01 * torch.cuda.mem_get_info(device)[1]
