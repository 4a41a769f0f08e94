"""The float-path fingerprint (mop_core/float_path.py) names the library path whose rounding moved."""

import json
import os
import subprocess
import sys

import torch

from mop_core.float_path import differs, float_path


def test_each_kernel_switch_moves_only_the_hashes_of_what_it_computes():
    """ATen's portable kernels (ATEN_CPU_CAPABILITY=default) round the updates and the actions otherwise;
    MKL's reproducible small-matrix path (MKL_CBWR=AVX2) only the actions; neither touches the physics.
    The same process repeats its own fingerprint."""
    switches = {"ATEN_CPU_CAPABILITY": "default", "MKL_CBWR": "AVX2"}
    runs = {name: subprocess.Popen([sys.executable, "-m", "mop_core.float_path"],
                                   env=os.environ | {name: value}, stdout=subprocess.PIPE, text=True)
            for name, value in switches.items()}
    torch.set_num_threads(2)
    ours = float_path()
    assert torch.get_num_threads() == 2 and ours == float_path() and all(len(digest) == 12 for digest in ours.values())
    theirs = {name: json.loads(run.communicate()[0]) for name, run in runs.items()}
    assert differs(ours, theirs["ATEN_CPU_CAPABILITY"]) == ["torch_acting", "torch_updates"], (ours, theirs)
    assert differs(ours, theirs["MKL_CBWR"]) == ["torch_acting"], (ours, theirs)


def test_differs_lists_only_entries_both_fingerprints_hold():
    assert differs({"torch": "a", "mujoco": "b"}, {"torch": "a", "mujoco": "c"}) == ["mujoco"]
    assert differs({"torch": "a", "mujoco": "b"}, {"torch": "x"}) == ["torch"]
    assert differs({"torch": "a"}, None) == [] and differs({"torch": "a"}, {}) == []
