#!/usr/bin/env bash
# The GPU check of the thesis profile, as one prepared run (issue 16, part 4), in under 10 minutes:
#   1. updates/s of TD3, PBRL and student groups (R = 1, 8 and the profile's entry sizes) at the thesis
#      profile's sizes, captured and eager, and a teacher group's measured memory (benchmarks/bench_rates.py),
#      and the thesis profile's estimated cost from them (mop_core.plan);
#   2. a shortened thesis-profile `dvc repro`: every schedule at 0.1%, one level, two learning-curve points per
#      run (mop_core.plan --scale --one-level --max-evaluations), its per-stage times next to the plan's
#      estimate for that same shortened profile;
#   3. the test suite with every learner test and the tiny profile's `dvc repro` on CUDA (MOP_TEST_DEVICE);
#   4. (only when MOP_GPU_CHECK_PARTS names tf32) benchmarks/tf32_check.py: part 2's shortened profile (or
#      MOP_GPU_CHECK_TF32_PROFILE) run in fp32 and in TF32, compared by verdicts and intervals: tf32.log. A smoke
#      test of TF32 on the card: one teacher seed at 0.1% of the schedules leaves most findings without an
#      interval, and two such repros need more than the 400 s default (one took over 200 s on the H200); the
#      check that decides is the evidence profile's (docs/design.md).
# Results land in $OUT (or ./gpu_check_out): gpu.txt, rates.json, rates.log, plan.md, repro.log, short_plan.md,
# short_timings.md, tests.log.
#
# On a machine without a package registry (the GPU machines lent here), build the site bundle first, here:
#   python benchmarks/gpu_bundle.py --out .gpu/site.tar.xz      # ~30 MiB: dm_control, mujoco, dvc, ...
# and send .gpu along; the script unpacks it when it is there. Tried on CPU first with
#   MOP_GPU_CHECK_DEVICE=cpu MOP_GPU_CHECK_TESTS=tests/test_distill.py MOP_GPU_CHECK_RATES_ARGS=--quick \
#   MOP_GPU_CHECK_SCALE=0.0001 bash benchmarks/gpu_check.sh
# Time limits per part: MOP_GPU_CHECK_LIMITS="rates repro tests tf32" seconds (default "100 200 260 400": with the
# unpacking, under the 600 s a device command may run). The parts run, in this order: MOP_GPU_CHECK_PARTS
# (default "rates repro tests"; e.g. "tests rates" checks the captured
# updates against eager first, then times them). MOP_GPU_CHECK_PROFILE: part 1's profile (default
# profiles/thesis.yaml; profiles/evidence.yaml prices the evidence record on the card). Measured on an
# H200 (2026-11-27): rates 34 s; the shortened repro ran collect, teachers and the baseline in ~90 s, its rollouts
# (~1-1.6k control steps/s on that machine) dominate the rest; the suite on CUDA took more than 290 s (the
# tiny dvc repro tests), the rest of it 50 s with 12 workers. At most 8 files come back from the machine: keep
# the outputs below to 8.
set -uo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
OUT=${OUT:-$ROOT/gpu_check_out}
DEVICE=${MOP_GPU_CHECK_DEVICE:-cuda}
TESTS=${MOP_GPU_CHECK_TESTS:-tests}
read -r LIMIT_RATES LIMIT_REPRO LIMIT_TESTS LIMIT_TF32 <<< "${MOP_GPU_CHECK_LIMITS:-100 200 260 400}"
SCALE=${MOP_GPU_CHECK_SCALE:-0.001}
PARTS=${MOP_GPU_CHECK_PARTS:-rates repro tests}
PROFILE=${MOP_GPU_CHECK_PROFILE:-profiles/thesis.yaml}  # the profile part 1 measures at and plans
mkdir -p "$OUT"
started=$(date +%s)
stamp() { echo "[gpu_check +$(( $(date +%s) - started ))s] $*"; }

# ---- environment: the carried site bundle, `python` and `dvc` on PATH ----------------------------------
if [ -f .gpu/site.tar.xz ]; then
  mkdir -p /tmp/mop_site && tar -xJf .gpu/site.tar.xz -C /tmp/mop_site
  export PYTHONPATH=/tmp/mop_site:$ROOT${PYTHONPATH:+:$PYTHONPATH}
else
  export PYTHONPATH=$ROOT${PYTHONPATH:+:$PYTHONPATH}
fi
PY=$(command -v python3)
# mop_core's own metadata (timing records name its version): an editable install, offline, no dependencies
"$PY" -m pip install -q --no-deps --no-build-isolation --no-index -e . > /tmp/mop_install.log 2>&1 \
  || { echo "pip install -e . failed:"; cat /tmp/mop_install.log; } >> "$OUT/gpu.txt"
mkdir -p /tmp/mop_bin
command -v python >/dev/null || ln -sf "$PY" /tmp/mop_bin/python
command -v dvc >/dev/null || printf '#!/bin/sh\nexec %s -m dvc "$@"\n' "$PY" > /tmp/mop_bin/dvc
chmod +x /tmp/mop_bin/* 2>/dev/null
export PATH=/tmp/mop_bin:$PATH MOP_PROGRESS=0 PYTHONUNBUFFERED=1
git config --global user.name >/dev/null || git config --global user.name gpu-check
git config --global user.email >/dev/null || git config --global user.email gpu-check@localhost
(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>&1 || echo "no nvidia-smi") >> "$OUT/gpu.txt"
"$PY" -c "import torch, mujoco, dm_control, dvc; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())" \
  2>&1 | tee -a "$OUT/gpu.txt"
stamp "environment ready"

# ---- 1. rates at the thesis sizes and the thesis profile's estimated cost ------------------------------
part_rates() {
  stamp "rates at $PROFILE's sizes"
  (cd benchmarks && timeout "$LIMIT_RATES" "$PY" bench_rates.py --profile "../$PROFILE" --device "$DEVICE" \
    ${MOP_GPU_CHECK_RATES_ARGS:-} --out "$OUT/rates.json" > "$OUT/rates.log" 2>&1) || echo "rates failed: see rates.log"
  if [ -f "$OUT/rates.json" ]; then
    "$PY" -m mop_core.plan "$PROFILE" --rates "$OUT/rates.json" | tee "$OUT/plan.md"
  fi
}

# ---- 2. a shortened thesis-profile dvc repro ----------------------------------------------------------
part_repro() {
  stamp "shortened thesis profile (scale $SCALE, one level): dvc repro"
  SHORT=/tmp/mop_short
  rm -rf "$SHORT" && mkdir -p "$SHORT"
  "$PY" -c "import sys; sys.path.insert(0, 'scripts'); from bad_inputs import copy_project; from pathlib import Path; \
  copy_project(Path('.'), Path('$SHORT'))"
  "$PY" -m mop_core.plan profiles/thesis.yaml --scale "$SCALE" --one-level --max-evaluations 2 --out "$SHORT/params.yaml"
  sed -i "s/^  device: .*/  device: $DEVICE/" "$SHORT/params.yaml"
  if [ -f "$OUT/rates.json" ]; then
    "$PY" -m mop_core.plan "$SHORT/params.yaml" --rates "$OUT/rates.json" > "$OUT/short_plan.md"
  fi
  (cd "$SHORT" && git init -q && git add -A && git commit -qm short && \
    timeout "$LIMIT_REPRO" dvc repro > "$OUT/repro.log" 2>&1; echo "dvc repro exit $?" >> "$OUT/repro.log")
  tail -n 5 "$OUT/repro.log"
  (cd "$SHORT" && "$PY" -m mop_core.timings > "$OUT/short_timings.md" 2>&1)
  cat "$OUT/short_timings.md"
}

# ---- 3. the test suite on the device (last: the part most likely to run long) -------------------------
part_tests() {
  workers=$(( $(nproc) > 8 ? 8 : $(nproc) ))
  parallel=""
  "$PY" -c "import xdist" 2>/dev/null && parallel="-n $workers --dist loadfile"  # pytest-xdist, where installed
  stamp "tests ($TESTS) on $DEVICE ${parallel:-in one process}"
  MOP_TEST_DEVICE=$DEVICE timeout "$LIMIT_TESTS" "$PY" -m pytest -q -p no:cacheprovider $parallel $TESTS \
    > "$OUT/tests.log" 2>&1
  echo "tests exit $?" >> "$OUT/tests.log"
  tail -n 15 "$OUT/tests.log"
}

# ---- 4. TF32 against fp32 (only when named in MOP_GPU_CHECK_PARTS; its log is one more file) ------------
part_tf32() {
  TF32_PROFILE=${MOP_GPU_CHECK_TF32_PROFILE:-/tmp/mop_tf32_profile.yaml}  # default: part 2's shortened profile
  [ -n "${MOP_GPU_CHECK_TF32_PROFILE:-}" ] || "$PY" -m mop_core.plan profiles/thesis.yaml --scale "$SCALE" \
    --one-level --max-evaluations 2 --out "$TF32_PROFILE"
  stamp "TF32 against fp32: benchmarks/tf32_check.py run on $TF32_PROFILE"
  rm -rf /tmp/mop_tf32
  timeout "${LIMIT_TF32:-400}" "$PY" benchmarks/tf32_check.py run --profile "$TF32_PROFILE" --out /tmp/mop_tf32 \
    --device "$DEVICE" > "$OUT/tf32.log" 2>&1
  echo "tf32_check exit $?" >> "$OUT/tf32.log"
  tail -n 12 "$OUT/tf32.log"
}

for part in $PARTS; do "part_$part"; done

stamp "done"
