#!/usr/bin/env bash
# Issues 26 and 40: the proof of the GPU backend and its goal table, for a session lent a GPU machine.
#
#   here, once:        bash benchmarks/gpu-proof.sh prepare
#   device tool, call 1: carry [".whl"], command: bash benchmarks/gpu-proof.sh run     timeout_s 360
#   device tool, call 2: carry [".whl"], command: bash benchmarks/gpu-proof.sh goals   timeout_s 430
#   (or, alone: bash benchmarks/gpu-proof.sh packed  timeout_s 180: issue 46's packed frames only)
#                      (OWNER_KERNELS=1 bash ... goals once owner.cuh passes there: the stores then
#                      encrypt in its kernels, the "100^3 encryption <= 3 s" row; PREV=FILE: call 1's
#                      goals.jsonl copied into the working tree, so goals.md holds the throughput too)
#
# The two calls and their starts fit one 15-minute lease, with minutes between them to fix what call 1
# showed; each ends by itself (DEADLINE 330 s / 400 s) before its timeout_s, each step gets what is
# left, the most valuable first (issue 40: the owner fix, the throughput, the GPU frames, the cpu
# curve), and every figure is written under $OUT as it is measured.
#
# prepare: ../shared/tools/device-wheels (hevr's dependencies as CPython 3.12 wheels in ./.whl,
# ignored by git) plus the two it does not fetch: google-crc32c and array-api-compat.
# run (on the GPU machine, whose image has CuPy, numpy, pytest, hypothesis): installs the wheels
# into /tmp/site, then
#   1. nvidia-smi                                                        -> $OUT/device.txt
#   2. owner.cuh: compute-sanitizer on its failing case (2048-bit CRT decryption), the kernels'
#      registers / local memory / the stack limit as the driver reports them, the same with a 16 KiB
#      stack, then tests/backends/test_cuda_owner.py with the kernels on   -> diagnose.log, pytest.log
#   3. throughput at 2048-bit keys, end to end and kernels only          -> goals.jsonl / goals.md
#   4. the gpu-marked tests, the kernel source's experiment (HEVR_CIOS_REG) -> pytest.log, experiments.json
#      and the operation suite on the device (HEVR_TEST_KERNELS=cuda)    -> pytest.log
#   5. every compile/launch variant of owner.cuh in its own process      -> diagnose.log
# goals: hevr/bench/gpu_goals.py's steps, each its own process: the 100^3 scalar and 50^3 4-dim
# stores (2048-bit key), the backend's resident 150^2 frames (X-ray nearest, trilinear, TF trilinear
# end to end), issue 46's packed frames (a 128^3 packed store at 2048 bits, two views x nearest and
# bilinear, on the backend and on cpu, identical ciphertexts asserted; hevr/bench/gpu_packed.py: about a
# minute), the cpu curve on 1, 2, 4, 8, 16 workers; then where a frame's time goes
# (benchmarks/gpu_profile_frame.py)                                     -> goals.jsonl, goals.md, profile.log
# packed: the packed step alone (DEADLINE 150 s), for a lease that has already run the other two.
# Commit what comes back under benchmarks/ (results-gpu-<card>-<date>.*, naming the card) and put the
# goal table in history.md.
set -uo pipefail
cd "$(git rev-parse --show-toplevel 2>/dev/null || echo "$(dirname "$0")/..")"
case "${1:-}" in
prepare)
  ../shared/tools/device-wheels
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    -d .whl google-crc32c array-api-compat
  ls .whl; du -sh .whl ;;
run|goals|packed)
  # run (call 1, under 6 minutes: DEADLINE 330 s): the key holder's kernels first (compute-sanitizer
  # names owner.cuh's faulting access, the kernel attributes, then the owner suite with them on), the
  # gpu-marked tests (the backend's verdict), the throughput (products/s, pairs/s: end to end and
  # kernels only, HEVR_CIOS_REG beside the default), then the compile/launch variants of owner.cuh.
  # goals (call 2, under 7 minutes: DEADLINE 400 s): issue 40's goal table (hevr/bench/gpu_goals.py):
  # the 100^3 and 50^3 (4-dim) stores, the GPU's resident frames, the cpu curve on 1-16 workers.
  # Leaves room in a 15-minute lease for both calls and their starts; each step gets what is left.
  : "${OUT:?run this through the device tool (it sets OUT)}"
  case "$1" in run) DEADLINE=${DEADLINE:-330} ;; goals) DEADLINE=${DEADLINE:-400} ;; *) DEADLINE=${DEADLINE:-150} ;; esac
  # step MAX CMD...: CMD under a timeout of MAX seconds or what is left before DEADLINE; skipped
  # (and said so) when under 10 s are left
  step() {
    local left=$(( DEADLINE - SECONDS )) l=$1; shift
    if (( left < 10 )); then echo "skipped at ${SECONDS}s (deadline ${DEADLINE}s): $*"; return 0; fi
    (( l > left )) && l=$left
    timeout -k 5 "$l" "$@"
  }
  # GOALS_ARGS: more arguments for gpu_goals (a rehearsal here: GOALS_ARGS="--backend cuda-host --size 12
  # --tf-size 8 --image 12 --bits 256 --workers 1,2 --packed-size 12 --packed-image 12" with
  # PYTHON=.venv/bin/python and NO_WHEELS=1)
  if [ -z "${NO_WHEELS:-}" ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
  fi
  PY=${PYTHON:-python3}
  export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 HEVR_KNOWN_STORES=${HEVR_KNOWN_STORES:-/tmp/hevr-known/known-stores.json}
  # the key holder's record refuses a folder others may write (/tmp is 1777): a private one
  mkdir -p -m 700 "$(dirname "$HEVR_KNOWN_STORES")"
  WORK=${WORK:-/tmp/hevr-goals}
  G="$PY -m hevr.bench.gpu_goals --out $OUT --work $WORK ${GOALS_ARGS:-}"
  if [ "$1" = run ]; then
    { nvidia-smi -L; nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv; nproc; } 2>&1 \
      | tee "$OUT/device.txt"
    # 2. owner.cuh (wrong on an H200 on 2026-11-26): the faulting access, then the suite with the kernels on
    { step 70 compute-sanitizer --tool memcheck --print-limit 6 $PY benchmarks/gpu_diagnose.py \
        --variant=shipped --keys 2048 --steps decrypt --counts 64
      step 40 compute-sanitizer --tool initcheck --print-limit 6 $PY benchmarks/gpu_diagnose.py \
        --variant=shipped --keys 2048 --steps decrypt --counts 64
      step 30 $PY benchmarks/gpu_diagnose.py --variant=stack16k --keys 2048 --steps decrypt,owner --counts 64,65536; } \
      > "$OUT/diagnose.log" 2>&1
    HEVR_TEST_KERNELS=cuda step 70 $PY -m pytest -q -rs -p no:cacheprovider -o addopts= --maxfail=20 \
      tests/backends/test_cuda_owner.py > "$OUT/pytest.log" 2>&1
    # 3. the throughput: end to end and kernels only (its caps above leave it time whatever came before)
    step 60 $G throughput > "$OUT/goals.log" 2>&1
    # 4. the backend's verdict: operations, streamed and resident renders, the render kernels on the device;
    #    then the source's experiment (HEVR_CIOS_REG) and the operation suite on the device
    HEVR_TEST_KERNELS=cuda step 80 $PY -m pytest -q -rs -p no:cacheprovider -o addopts= -m gpu \
      tests/backends/test_cuda_device.py tests/backends/test_packed_backends.py >> "$OUT/pytest.log" 2>&1
    step 40 $PY -c "import json, sys; from hevr.backends import get_backend; from hevr.bench.gpu_operations import experiments
print(json.dumps(experiments(get_backend('cuda'), False)))" > "$OUT/experiments.json" 2>>"$OUT/goals.log"
    HEVR_TEST_KERNELS=cuda step 60 $PY -m pytest -q -rs -p no:cacheprovider -o addopts= --maxfail=20 \
      tests/backends/test_cuda_host_backend.py >> "$OUT/pytest.log" 2>&1
    grep -E "passed|failed|error" "$OUT/pytest.log" | tail -3
    # 5. every compile/launch variant of owner.cuh, each in its own process, with what is left
    step 150 $PY benchmarks/gpu_diagnose.py --keys 1024,2048 --counts 64 --timeout 25 >> "$OUT/diagnose.log" 2>&1
    grep -E "wrong [1-9]|FAILED|timed out|ERROR SUMMARY|Invalid|at 0x|stack limit|kernel k_" "$OUT/diagnose.log" | head -40
  elif [ "$1" = packed ]; then
    step 140 $G packed --repeats 1 > "$OUT/goals.log" 2>&1
  else
    # call 1's rows (its goals.jsonl copied into the working tree, named by PREV) head the table
    if [ -n "${PREV:-}" ] && [ -f "$PREV" ]; then cp "$PREV" "$OUT/goals.jsonl"; fi
    # --owner-kernels once owner.cuh passes on the device (the stores then encrypt in its kernels)
    step 130 $G stores ${OWNER_KERNELS:+--owner-kernels} > "$OUT/goals.log" 2>&1
    step 110 $G frames >> "$OUT/goals.log" 2>&1
    step 100 $G packed --repeats 1 >> "$OUT/goals.log" 2>&1   # issue 46: packed frames, backend vs cpu
    step 150 $G curve --repeats 2 >> "$OUT/goals.log" 2>&1
    step 60 $PY benchmarks/gpu_profile_frame.py ${PROFILE_ARGS:-24 cuda} > "$OUT/profile.log" 2>&1; grep "^==" "$OUT/profile.log"
  fi
  $G table > /dev/null 2>&1; cat "$OUT/goals.md" 2>/dev/null
  echo "done in $SECONDS s" ;;
*)
  echo "usage: bash benchmarks/gpu-proof.sh prepare|run|goals|packed" >&2; exit 2 ;;
esac
