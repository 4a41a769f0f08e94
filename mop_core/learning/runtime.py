"""Process-level settings: torch device, thread counts, seeding, progress bars, worker processes."""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import zlib
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Sequence

import numpy as np
import torch
from tqdm import tqdm

from mop_core.config import ConfigError

THREADS_ENV = "MOP_THREADS"  # what threads: auto means where it is set (a mop-cluster worker: its entry's CPUs)


def available_cores() -> int:
    """The cores this process may use: ``MOP_THREADS`` where set, else the CPU affinity's size (a container's
    or ``taskset``'s limit, which ``os.cpu_count`` ignores)."""
    value = os.environ.get(THREADS_ENV, "")
    if value:
        if not value.isdigit() or int(value) < 1:
            raise ConfigError(f"{THREADS_ENV}: expected a positive integer (the cores threads: auto uses), "
                              f"got {value!r}")
        return int(value)
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def _count_or_auto(value: Any, key: str) -> int:
    """A positive integer, or ``auto``: :func:`available_cores`."""
    if value == "auto":
        return available_cores()
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"{key}: expected a positive integer or 'auto' (the cores this process may use), "
                          f"got {value!r}")
    return value


def resolve_threads(value: Any, key: str) -> int:
    """A ``threads`` param: a positive integer, or ``auto`` (:func:`available_cores`). ``auto`` fits a run to
    its machine, at a price: thread counts change float rounding, so two machines' runs of one params file
    then differ in the last bits, which DVC's params hash does not see (an integer pins them)."""
    return _count_or_auto(value, key)


def resolve_workers(value: Any, key: str) -> int:
    """A rollout ``workers`` param (processes that each roll out whole jobs): a positive integer, or ``auto``
    (:func:`available_cores`). Unlike ``threads``, ``auto`` costs nothing here: every job draws its own
    episode seeds and runs in one single-threaded process, so the results do not depend on how many
    processes share the jobs (tested for eval and shared computation); a 64-core machine rolls out on 64."""
    return _count_or_auto(value, key)


def resolve_device(name: str, key: str = "device") -> torch.device:
    """``auto`` picks CUDA when present, else the CPU; ``cpu``/``cuda``/``cuda:N`` are taken as given."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cpu" or name.startswith("cuda"):
        if name.startswith("cuda") and not torch.cuda.is_available():
            raise ConfigError(f"{key}: {name!r} requested but CUDA is not available; use 'auto' or 'cpu'")
        return torch.device(name)
    raise ConfigError(f"{key}: expected 'auto', 'cpu' or 'cuda[:N]', got {name!r}")


CUDA_MATMULS = ("fp32", "tf32")  # study.cuda_matmul: how CUDA multiplies float32 matrices


def set_cuda_matmul(precision: str, key: str = "study.cuda_matmul") -> None:
    """CUDA float32 matrix products (and cuDNN convolutions) in full ``fp32`` or in ``tf32`` (10-bit mantissa
    inputs, fp32 accumulation) for the rest of this process; the CPU is unaffected. Both flags are set, as
    torch leaves cuDNN's TF32 on by default. TF32 bought 1.6x on an H200's PBRL groups (benchmarks/README.md,
    gpu 2026-12-04-tf32) and changes every GPU number in its last bits at least: benchmarks/tf32_check.py
    tells whether a study's numbers move beyond their run-to-run intervals."""
    if precision not in CUDA_MATMULS:
        raise ConfigError(f"{key}: expected one of {', '.join(CUDA_MATMULS)}, got {precision!r}")
    torch.backends.cuda.matmul.allow_tf32 = precision == "tf32"
    torch.backends.cudnn.allow_tf32 = precision == "tf32"


def cuda_matmul() -> str:
    """This process's CUDA float32 matmul precision (:func:`set_cuda_matmul`): ``fp32`` or ``tf32``."""
    return "tf32" if torch.backends.cuda.matmul.allow_tf32 else "fp32"


def set_threads(threads: int) -> None:
    """Pin torch (and OpenMP/MKL of child libraries) to ``threads`` threads in this process.

    Two processes with two OpenMP threads each on two cores run many times slower than two
    single-threaded processes, so parallel workers call this with 1 before any torch work.
    """
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = str(threads)
    torch.set_num_threads(threads)
    try:
        torch.set_num_interop_threads(threads)
    except RuntimeError:  # can only be set once, before any inter-op parallel work started
        pass


M_MMAP_THRESHOLD = -3  # glibc mallopt parameter (malloc.h)
MMAP_THRESHOLD = 1 << 30  # bytes: every buffer below this comes from the heap and is reused after free


def keep_freed_memory() -> bool:
    """Have glibc's malloc serve every buffer under 1 GiB from its heap, reusing freed memory,
    instead of mapping each large buffer afresh (returns whether the setting took).

    By default glibc maps every allocation above a threshold (128 KiB, raised adaptively) with
    ``mmap`` and unmaps it on ``free``: each new activation or gradient buffer of a training step
    (1-7 MB here) then starts as untouched pages, and the first write to every 4 KiB page is a
    page fault. Measured on 2 CPU cores when it was introduced: the thesis-size PBRL update ~22% faster
    and the thesis-size student step ~13% faster with the threshold raised; the last committed run of
    benchmarks/bench_pbrl.py (benchmarks/README.md, pbrl) measured the update at 0.84x instead, on a
    loaded machine: to be measured again on free cores before the setting is trusted either way. The
    price is that the process keeps its peak heap until it exits. Does
    nothing (returns False) where the C library is not glibc.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD))
    except (OSError, AttributeError):  # another C library (musl) or no mallopt
        return False


_STEP_THREADS = [1]  # threads a VectorWalkerEnv (mop_core.walker.envs) steps its members with


def set_step_threads(threads: int) -> None:
    """Step the members of every ``mop_core.walker.envs.VectorWalkerEnv`` in ``threads`` threads (each a share
    of the walkers; results do not depend on it). :func:`configure_compute` sets it to the process's
    torch threads: a stage given 2 cores uses both for its rollouts too."""
    if threads < 1:
        raise ValueError(f"threads: expected a positive integer, got {threads!r}")
    _STEP_THREADS[0] = threads


def step_threads() -> int:
    return _STEP_THREADS[0]


def configure_compute(threads: int) -> None:
    """The process settings every compute stage, worker and benchmark starts with: ``threads``
    torch threads (:func:`set_threads`), as many threads stepping batched walkers
    (:func:`set_step_threads`), freed memory kept for reuse (:func:`keep_freed_memory`),
    and subnormal floats flushed to zero (``torch.set_flush_denormal``: x86 FTZ/DAZ).

    Subnormals (|x| < 1.2e-38 in float32) take a slow microcode path on x86 CPUs, tens of times a
    normal operation's cost. They appear as training saturates: a trained ranking-regularised
    student's ``sigmoid`` tails and Adam's second moments of near-zero gradients. Measured in the
    ranking study: the pairwise-ranking group's step went from ~20 ms at the start to ~70 ms late
    in training, ApproxNDCG's doubled. Flushing them changes values only below float32's normal
    range; runs stay deterministic."""
    set_threads(threads)
    set_step_threads(threads)
    keep_freed_memory()
    torch.set_flush_denormal(True)  # False where the CPU has no FTZ/DAZ: nothing changes there


class TrainingDivergedError(RuntimeError):
    """A loss or weight became NaN or infinite; the message names the run, the step and the value."""


class CriterionNotMetError(RuntimeError):
    """A run that must reach a level did not within its cap (collect's expert criterion); the message
    names the run, the criterion, the cap and its best return. ``curve`` holds the run's learning-curve
    rows (empty when the run got no further than its check), for whoever reports the failure."""

    def __init__(self, message: str, curve: list[dict] | None = None) -> None:
        super().__init__(message)
        self.curve = list(curve or [])


def die_with_parent(sig: int = signal.SIGTERM) -> None:
    """Have the kernel send ``sig`` to this process when its parent dies (Linux ``PR_SET_PDEATHSIG``).

    Stage scripts call it at start (killing ``dvc repro`` then stops the stage it ran) and worker
    pools use it as their initializer (killing a stage stops its workers, which would otherwise go
    on writing the files a rerun writes). Elsewhere than Linux it does nothing."""
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(1, int(sig), 0, 0, 0) != 0:  # 1 = PR_SET_PDEATHSIG
        return
    if os.getppid() == 1:  # the parent died before prctl: we were already adopted by init
        os.kill(os.getpid(), sig)


def progress_enabled(requested: bool) -> bool:
    """Progress bars show when requested, unless ``MOP_PROGRESS=0`` is set (CI, tests)."""
    return requested and os.environ.get("MOP_PROGRESS", "1") != "0"


def derive_seeds(key: Sequence[int | str], names: Sequence[str]) -> dict[str, int]:
    """One independent seed per name, a function of ``key`` only (e.g. [study seed, task, level]).

    Strings enter as their CRC-32, so a run's seeds depend on what it is, not on its position in a
    grid: adding a task or a level leaves every other run's seeds unchanged.
    """
    entropy = [zlib.crc32(part.encode()) if isinstance(part, str) else int(part) for part in key]
    children = np.random.SeedSequence(entropy).spawn(len(names))
    return {name: int(child.generate_state(1)[0]) for name, child in zip(names, children)}


def _in_worker(call: tuple) -> Any:
    fn, args = call
    configure_compute(1)
    return fn(*args)


def parallel_map(fn: Callable, args: Sequence[tuple], workers: int, desc: str, progress: bool = False) -> list:
    """``[fn(*a) for a in args]`` in order, over ``workers`` single-threaded processes (in this
    process when ``workers`` or the number of calls is 1); a tqdm bar counts finished calls.
    ``fn`` must be a module-level function (it is pickled)."""
    if not args:
        return []
    bar = tqdm(total=len(args), desc=desc, unit="job", disable=not progress)
    results = []
    if workers == 1 or len(args) == 1:
        for a in args:
            results.append(fn(*a))
            bar.update(1)
    else:
        with ProcessPoolExecutor(max_workers=min(workers, len(args), os.cpu_count() or 1),
                                 initializer=die_with_parent) as pool:
            for result in pool.map(_in_worker, [(fn, a) for a in args]):
                results.append(result)
                bar.update(1)
    bar.close()
    return results


