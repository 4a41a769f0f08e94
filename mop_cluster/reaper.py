"""Run a command as the leader of its own process group, and kill the whole group when the process that
started it dies.

    python -m mop_cluster.reaper PARENT_PID dvc repro distill@mse-medium

A worker runs an entry's ``dvc repro`` through this. When the coordinator stops (Ctrl-C, a failing entry)
it shuts Ray down, and Ray kills its worker processes with SIGKILL: no handler of theirs runs, and
``dvc repro`` with the stage's command (and the stage's own processes) would live on as orphans. Linux's
parent-death signal (``prctl(PR_SET_PDEATHSIG)``) tells this process instead, which kills its process
group (dvc, the stage, the stage's rollout workers: none of them starts a session of its own). Nothing
is cancelled through Ray (Ray 2.60 aborted when tasks were cancelled after a failure, on loaded cores).
"""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def _kill_group(signum=None, frame=None) -> None:
    os.killpg(0, signal.SIGKILL)  # the group: the command, its children and this process


def main(argv: list[str]) -> int:
    parent, command = int(argv[0]), argv[1:]
    if os.getpgid(0) != os.getpid():  # started with start_new_session=True, it is a group of its own already
        os.setpgid(0, 0)
    signal.signal(signal.SIGTERM, _kill_group)
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG)")
    if os.getppid() != parent:  # the parent died before the signal was set
        _kill_group()
    return subprocess.Popen(command).wait()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
