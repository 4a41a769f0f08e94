"""Speed of the state-shift measures (mop_core/shift/measures.py), measured in one run here.

Prints, for two sets of ``--states`` 24-float states (the walker's observation size; the target:
20k x 20k in under a minute on 2 cores, all measures together):
- seconds of the kNN KL estimate (k = 1) and of its split-half null;
- seconds of the classifier two-sample test (train + held-out AUC) and of the density ratio on the
  second set;
- their sum against the 60 s target, as a ratio.

Run: ``python benchmarks/bench_shift.py [--states 20000] [--threads 2]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from mop_core.learning.runtime import configure_compute
from mop_core.shift.measures import classifier_test, knn_kl, split_half_null

TARGET_SECONDS = 60.0


def timed(fn) -> tuple[float, object]:
    start = time.perf_counter()
    value = fn()
    return time.perf_counter() - start, value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--states", type=int, default=20000)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    configure_compute(args.threads)
    rng = np.random.default_rng(0)
    x = rng.standard_normal((args.states, 24)).astype(np.float32)
    y = rng.standard_normal((args.states, 24)).astype(np.float32)
    y[:, 0] += 0.7  # a shift of KL 0.245
    knn_seconds, estimate = timed(lambda: knn_kl(x, y))
    null_seconds, null = timed(lambda: split_half_null(x, knn_kl))
    clf_seconds, result = timed(lambda: classifier_test(x, y))
    ratio_seconds, _ = timed(lambda: result.density_ratio(y))
    total = knn_seconds + null_seconds + clf_seconds + ratio_seconds
    print(f"{args.states} x {args.states} states, 24 floats, {args.threads} threads: kNN KL {knn_seconds:.1f} s "
          f"(estimate {estimate:.3f}, true 0.245), split-half null {null_seconds:.1f} s ({null:.3f}); classifier "
          f"{clf_seconds:.1f} s (held-out AUC {result.auc:.3f}), density ratio {ratio_seconds:.2f} s; total "
          f"{total:.1f} s = {total / TARGET_SECONDS:.2f}x the {TARGET_SECONDS:.0f} s target")


if __name__ == "__main__":
    main()
