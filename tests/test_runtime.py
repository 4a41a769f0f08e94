"""mop_core/learning/runtime.py: seeds from what a run is, thread pinning, the device, progress bars, the worker
pool and the process settings for compute."""

from __future__ import annotations

import os
import platform
import sys
import zlib

import numpy as np
import pytest
import torch
from conftest import TEST_DEVICE

from mop_core import collect
from mop_core.config import ConfigError
from mop_core.experiment.study import study_config, study_device
from mop_core.learning import runtime
from mop_core.learning.runtime import (
    cuda_matmul,
    derive_seeds,
    parallel_map,
    progress_enabled,
    resolve_device,
    resolve_workers,
    set_cuda_matmul,
    set_threads,
)
from mop_core.storage.timings import machine_facts


def test_derive_seeds_is_a_function_of_the_key():
    seeds = derive_seeds([0, "stand", "medium"], ("agent", "sampler", "eval"))
    assert list(seeds) == ["agent", "sampler", "eval"]
    assert seeds == derive_seeds([0, "stand", "medium"], ("agent", "sampler", "eval"))
    assert all(isinstance(v, int) and 0 <= v < 2**32 for v in seeds.values())
    assert len(set(seeds.values())) == 3  # independent seeds per name
    # strings enter as their CRC-32
    assert seeds == derive_seeds([0, zlib.crc32(b"stand"), zlib.crc32(b"medium")], ("agent", "sampler", "eval"))
    # numpy's SeedSequence of the key, one spawned child per name; pinned: a change here changes every run
    children = np.random.SeedSequence([0, zlib.crc32(b"stand"), zlib.crc32(b"medium")]).spawn(3)
    assert seeds == {n: int(c.generate_state(1)[0]) for n, c in zip(("agent", "sampler", "eval"), children)}
    assert seeds == {"agent": 3036518173, "sampler": 2518971061, "eval": 3333278194}


def test_derive_seeds_does_not_depend_on_the_grid_around_a_run():
    walk = derive_seeds([0, "walk", "expert"], ("agent",))
    assert walk != derive_seeds([0, "stand", "expert"], ("agent",))
    assert walk != derive_seeds([1, "walk", "expert"], ("agent",))
    assert walk != derive_seeds([0, "walk", "medium"], ("agent",))
    assert walk != derive_seeds([0, "expert", "walk"], ("agent",))  # the order of the key matters
    # the seed of a name is its position's: listing more names leaves the first one's unchanged
    assert derive_seeds([0, "walk", "expert"], ("agent", "sampler"))["agent"] == walk["agent"]


def test_set_threads_pins_torch_and_the_blas_libraries(monkeypatch):
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)  # restored after the test
    try:
        set_threads(1)
        assert torch.get_num_threads() == 1
        set_threads(2)  # again, after the inter-op threads were fixed: no error
        assert torch.get_num_threads() == 2
        assert [os.environ[v] for v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")] == ["2"] * 3
        set_threads(1)
        assert torch.get_num_threads() == 1 and os.environ["OMP_NUM_THREADS"] == "1"
    finally:
        torch.set_num_threads(1)


def test_resolve_device(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == torch.device("cpu")
    assert resolve_device("cpu") == torch.device("cpu")
    with pytest.raises(ConfigError, match=r"^study.device: 'cuda:1' requested but CUDA is not available"):
        resolve_device("cuda:1", "study.device")
    with pytest.raises(ConfigError, match=r"^device: 'cuda' requested"):
        resolve_device("cuda")
    with pytest.raises(ConfigError, match=r"^study.device: expected 'auto', 'cpu' or 'cuda\[:N\]', got 'gpu'$"):
        resolve_device("gpu", "study.device")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_device("auto") == torch.device("cuda")
    assert resolve_device("cuda:1") == torch.device("cuda:1")
    assert resolve_device("cpu") == torch.device("cpu")


@pytest.fixture
def restore_cuda_matmul():
    flags = torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32
    yield
    torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = flags


def test_cuda_matmul_sets_both_of_torchs_tf32_flags_and_refuses_other_names(restore_cuda_matmul):
    set_cuda_matmul("tf32")
    assert torch.backends.cuda.matmul.allow_tf32 and torch.backends.cudnn.allow_tf32 and cuda_matmul() == "tf32"
    set_cuda_matmul("fp32")  # cuDNN's TF32 is on by default in torch: fp32 turns it off too
    assert not torch.backends.cuda.matmul.allow_tf32 and not torch.backends.cudnn.allow_tf32
    assert cuda_matmul() == "fp32"
    with pytest.raises(ConfigError, match=r"^study.cuda_matmul: expected one of fp32, tf32, got 'bf16'$"):
        set_cuda_matmul("bf16")
    assert cuda_matmul() == "fp32"


def test_the_study_device_sets_the_studys_cuda_matmul(tiny_params, restore_cuda_matmul):
    study = study_config({**tiny_params, "study": {**tiny_params["study"], "cuda_matmul": "tf32"}})
    assert study_device(study) == torch.device(tiny_params["study"]["device"]) and cuda_matmul() == "tf32"


def test_a_collect_worker_runs_in_the_studys_cuda_matmul(monkeypatch, restore_cuda_matmul):
    """collect's task processes are spawned: each sets study.cuda_matmul itself (run here in-process)."""
    monkeypatch.setattr(collect, "collect_task", lambda *args: cuda_matmul())
    monkeypatch.setattr(collect, "configure_compute", lambda threads: None)
    assert collect._collect_worker("stand", None, 0, None, "cpu", False, 0, 1, "tf32") == "tf32"
    assert collect._collect_worker("stand", None, 0, None, "cpu", False, 0, 1, "fp32") == "fp32"


@pytest.mark.skipif(TEST_DEVICE != "cuda" or not torch.cuda.is_available(), reason="needs MOP_TEST_DEVICE=cuda")
def test_tf32_changes_a_cuda_matmul_and_the_timing_record_says_which_ran(restore_cuda_matmul):
    """On the card: TF32 products differ from fp32 ones (so the flag reaches cuBLAS), by about TF32's
    10-bit mantissa, and a timing record names the precision its run used."""
    a, b = torch.randn(512, 512, device="cuda", generator=torch.Generator("cuda").manual_seed(0)).double().chunk(2)
    exact = a @ b.T
    set_cuda_matmul("fp32")
    full = (a.float() @ b.float().T).double()
    assert machine_facts("cuda")["cuda_matmul"] == "fp32"
    set_cuda_matmul("tf32")
    coarse = (a.float() @ b.float().T).double()
    assert machine_facts("cuda")["cuda_matmul"] == "tf32"
    full_error, coarse_error = (full - exact).abs().max().item(), (coarse - exact).abs().max().item()
    assert coarse_error > 10 * full_error and coarse_error < 1e-2 * exact.abs().max().item()


def test_progress_bars_show_when_requested_unless_switched_off(monkeypatch):
    monkeypatch.delenv("MOP_PROGRESS", raising=False)
    assert progress_enabled(True) and not progress_enabled(False)
    monkeypatch.setenv("MOP_PROGRESS", "1")
    assert progress_enabled(True)
    monkeypatch.setenv("MOP_PROGRESS", "0")
    assert not progress_enabled(True) and not progress_enabled(False)


ARGS = [(17, 5), (3, 7), (100, 9), (-8, 3), (40, 6)]


@pytest.mark.parametrize("workers", [1, 2])
def test_parallel_map_returns_results_in_order(workers):
    assert parallel_map(divmod, ARGS, workers, "test") == [divmod(*a) for a in ARGS]
    assert parallel_map(divmod, ARGS[:1], workers, "test") == [(3, 2)]


def test_parallel_map_runs_in_worker_processes_only_when_there_is_work_for_two():
    here = os.getpid()
    assert parallel_map(os.getpid, [()] * 3, 1, "test") == [here] * 3
    assert parallel_map(os.getpid, [()], 2, "test") == [here]  # one call: in this process
    pids = parallel_map(os.getpid, [()] * 4, 2, "test")
    assert len(pids) == 4 and here not in pids


def test_parallel_map_of_nothing_is_empty():
    assert parallel_map(divmod, [], 1, "test") == []


def test_parallel_map_of_nothing_is_empty_with_several_workers():
    assert parallel_map(divmod, [], 2, "test") == []



@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="mallopt is glibc's (Linux)")
def test_configure_compute_pins_the_threads_and_keeps_freed_memory(monkeypatch):
    pinned = []
    monkeypatch.setattr(runtime, "set_threads", pinned.append)
    kept = []
    monkeypatch.setattr(runtime, "keep_freed_memory", lambda: kept.append(True) or True)
    runtime.configure_compute(2)
    assert pinned == [2] and kept == [True]
    monkeypatch.undo()
    assert runtime.keep_freed_memory() is True  # glibc accepted the raised mmap threshold


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"),
                    reason="flush-to-zero is an x86 (SSE3) CPU setting")
def test_configure_compute_flushes_subnormal_floats(monkeypatch):
    monkeypatch.setattr(runtime, "set_threads", lambda threads: None)
    try:
        torch.set_flush_denormal(False)
        subnormal = torch.tensor([1e-40], dtype=torch.float32)
        assert (subnormal * 1.0).item() != 0.0  # representable as a subnormal when not flushed
        runtime.configure_compute(1)
        assert (subnormal * 1.0).item() == 0.0  # flushed: no slow subnormal arithmetic
    finally:
        torch.set_flush_denormal(False)


def test_workers_auto_is_the_cores_this_process_may_use_and_bad_values_name_their_key(monkeypatch):
    monkeypatch.setenv(runtime.THREADS_ENV, "5")  # a mop-cluster entry's CPUs
    assert resolve_workers("auto", "eval.workers") == 5 and resolve_workers(3, "eval.workers") == 3
    monkeypatch.delenv(runtime.THREADS_ENV)
    assert resolve_workers("auto", "eval.workers") == len(os.sched_getaffinity(0))
    for bad in (0, -1, 1.5, True, "all", None):
        with pytest.raises(ConfigError, match=r"^eval.workers: expected a positive integer or 'auto' \(the cores "):
            resolve_workers(bad, "eval.workers")
