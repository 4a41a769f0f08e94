"""mop_core: the library behind the MOP pipeline (Multi-task Offline Policy distillation).

Wings by concern: ``walker`` (tasks, batched MuJoCo, rollouts), ``data`` (HDF5 datasets, buffers),
``storage`` (file layout, atomic writes, checkpoints, timings), ``learning`` (networks, the training
loop, process settings), ``agents`` (TD3, PBRL, the multi-task baseline), ``distill`` (students and
their training), ``experiment`` (the params grid, run kinds, student variants, the catalogue),
``shift`` (thesis 5.2-5.3), ``representations`` (activation similarity, thesis 6.2) and ``report``
(the report and its verdicts); the stage-level modules (collect, relabel, teachers, evaluation, the
params check, shared computation, ...) sit at the top. Each wing imports only wings below it (tested).
Stage scripts in ``stages/`` read ``params.yaml`` and ask the catalogue; nothing in this package
reads ``params.yaml``: it receives the parsed mapping.
"""

__version__ = "0.1.0"
