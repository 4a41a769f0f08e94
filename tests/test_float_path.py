"""The float-path fingerprint (mop_core/float_path.py) names the computation whose rounding moved."""

import json
import os
import subprocess
import sys

import pytest
import torch

from mop_core.float_path import differs, float_path

VECTOR_CPU = torch.backends.cpu.get_cpu_capability() in ("AVX2", "AVX512") and torch.backends.mkl.is_available()


@pytest.mark.skipif(not VECTOR_CPU, reason="the switches move ATen's x86 vector kernels and MKL's paths")
def test_each_kernel_switch_moves_only_the_hashes_of_what_it_computes():
    """ATen's portable kernels (ATEN_CPU_CAPABILITY=default) round the updates and the actions otherwise;
    MKL's reproducible small-matrix path (MKL_CBWR=AVX2) only the actions; neither touches the physics.
    The fingerprint repeats itself, and measuring it leaves the caller's threads, environment and
    random state as they were."""
    switches = {"ATEN_CPU_CAPABILITY": "default", "MKL_CBWR": "AVX2"}
    runs = {name: subprocess.Popen([sys.executable, "-m", "mop_core.float_path"],
                                   env=os.environ | {name: value}, stdout=subprocess.PIPE, text=True)
            for name, value in switches.items()}
    threads, environment, rng = torch.get_num_threads(), dict(os.environ), torch.get_rng_state()
    ours = float_path()
    assert ours == float_path() and set(ours) == {"torch_updates", "torch_acting", "mujoco"}
    assert all(len(digest) == 12 and int(digest, 16) >= 0 for digest in ours.values())
    assert torch.get_num_threads() == threads and dict(os.environ) == environment
    assert torch.equal(torch.get_rng_state(), rng)
    theirs = {name: json.loads(run.communicate()[0]) for name, run in runs.items()}
    assert differs(ours, theirs["ATEN_CPU_CAPABILITY"]) == ["torch_acting", "torch_updates"], (ours, theirs)
    assert differs(ours, theirs["MKL_CBWR"]) == ["torch_acting"], (ours, theirs)


def test_differs_lists_only_entries_both_fingerprints_hold():
    assert differs({"torch": "a", "mujoco": "b"}, {"torch": "a", "mujoco": "c"}) == ["mujoco"]
    assert differs({"torch": "a", "mujoco": "b"}, {"torch": "x"}) == ["torch"]
    assert differs({"torch": "a"}, None) == [] and differs({"torch": "a"}, {}) == []
