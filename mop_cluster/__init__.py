"""mop-cluster: the study's independent DVC stage entries run concurrently as Ray tasks.

DVC runs one stage at a time (treeverse/dvc#755). The pattern DVC's own blog describes: a coordinator
finds the stale stage entries; workers, each in a clone at HEAD sharing the DVC cache directory, run
``dvc repro <entry>`` in DAG order; every finished entry lands in the run cache; the coordinator's final
``dvc repro`` restores each from the run cache ("is cached - skipping run") and writes dvc.lock once.

This package is a tool over the DVC pipeline, beside the study's library: it reads dvc.yaml and the
threads each stage declares in params.yaml, never the study's code (``mop_core`` never reads params.yaml).
"""
