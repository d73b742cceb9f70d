#!/usr/bin/env bash
# Issue 26's one-command proof of the GPU backend, for a session that is lent a GPU machine.
#
#   here, once:        bash benchmarks/gpu-proof.sh prepare
#   device tool run:   carry [".whl"], command: bash benchmarks/gpu-proof.sh run [size]   (timeout_s 560: it
#                      ends by itself in under 9 minutes, leaving the rest of a 15-minute lease for its start)
#
# prepare: ../shared/tools/device-wheels (hevr's dependencies as CPython 3.12 wheels in ./.whl,
# ignored by git) plus the two it does not fetch: google-crc32c and array-api-compat.
# run (on the GPU machine, whose image has CuPy, numpy, pytest, hypothesis): installs the wheels
# into /tmp/site, then, each step's output under $OUT (what comes back), all within DEADLINE
# (530 s) so the call ends before its 560 s limit; the most valuable steps first:
#   1. nvidia-smi -L                                                     -> $OUT/device.txt
#   2. the gpu-marked tests (operations, streamed and resident renders), then the kernel suites on
#      the device (HEVR_TEST_KERNELS=cuda: every operation, the key holder's kernels, renders)
#                                                                        -> $OUT/pytest.log
#   3. the bench (operations, a [size]³ 2048-bit render (default 16: 64³ took over 5 minutes on
#      an H200), throughput with its stages (plan, uploads, kernels), the kernel source's
#      experiments (HEVR_CIOS_REG), encryption)    -> $OUT/gpu.md, $OUT/gpu.json, $OUT/bench.log
#   4. benchmarks/gpu_profile_frame.py: where a resident frame's time goes, cuda and cpu
#                                                                        -> $OUT/profile.log
#   5. benchmarks/gpu_diagnose.py: compute-sanitizer on owner.cuh's failing case, then owner.cuh
#      against Python integers under every compile/launch variant, each in its own process
#                                                                        -> $OUT/diagnose.log
# Commit gpu.md / gpu.json under benchmarks/ (they name the card) and put the numbers in history.md.
set -uo pipefail
cd "$(git rev-parse --show-toplevel 2>/dev/null || echo "$(dirname "$0")/..")"
case "${1:-}" in
prepare)
  ../shared/tools/device-wheels
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    -d .whl google-crc32c array-api-compat
  ls .whl; du -sh .whl ;;
run)
  # under 9 minutes in all (DEADLINE seconds): each step gets what is left, most valuable first:
  # the verdict (tests), the bench (identity, renders, throughput split into stages, the kernel
  # source's experiments), the frame profile, then the diagnosis of owner.cuh
  : "${OUT:?run this through the device tool (it sets OUT)}"
  DEADLINE=${DEADLINE:-530}
  # step MAX CMD...: CMD under a timeout of MAX seconds or what is left before DEADLINE; skipped
  # (and said so) when under 10 s are left
  step() {
    local left=$(( DEADLINE - SECONDS )) l=$1; shift
    if (( left < 10 )); then echo "skipped at ${SECONDS}s (deadline ${DEADLINE}s): $*"; return 0; fi
    (( l > left )) && l=$left
    timeout -k 5 "$l" "$@"
  }
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
  { nvidia-smi -L; df -hT /tmp /dev/shm "$PWD"; nproc; } 2>&1 | tee "$OUT/device.txt"
  HEVR_TEST_KERNELS=cuda step 130 python3 -m pytest -q -rs -p no:cacheprovider -o addopts= -m gpu \
    tests/backends/test_cuda_device.py > "$OUT/pytest.log" 2>&1
  HEVR_TEST_KERNELS=cuda step 120 python3 -m pytest -q -rs -p no:cacheprovider -o addopts= --maxfail=20 \
    tests/backends/test_cuda_owner.py tests/backends/test_cuda_host_backend.py \
    tests/backends/test_cuda_host_renders.py >> "$OUT/pytest.log" 2>&1
  tail -3 "$OUT/pytest.log"
  step 200 python3 -c "import sys; from pathlib import Path; from hevr._bench.gpu import run_gpu_bench
run_gpu_bench(Path(sys.argv[1]), work=Path("/tmp"), render_size=int(sys.argv[2]), log_line=print)" "$OUT" "${2:-16}" \
    2>&1 | tee "$OUT/bench.log"
  step 60 python3 benchmarks/gpu_profile_frame.py 16 > "$OUT/profile.log" 2>&1; grep "^==" "$OUT/profile.log"
  # owner.cuh (wrong on an H200 on 2026-11-26): compute-sanitizer on the failing case first (it names
  # the faulting access), then the shipped build at several counts, then every compile/launch variant
  { step 75 compute-sanitizer --tool memcheck --print-limit 6 python3 benchmarks/gpu_diagnose.py \
      --variant=shipped --keys 2048 --steps decrypt --counts 64
    step 60 python3 benchmarks/gpu_diagnose.py --variant=shipped --counts 64,4096,65536
    step 150 python3 benchmarks/gpu_diagnose.py --keys 1024,2048 --counts 64 --timeout 25; } \
    > "$OUT/diagnose.log" 2>&1
  grep -E "wrong [1-9]|FAILED|timed out|ERROR SUMMARY|Invalid|at 0x" "$OUT/diagnose.log" | head -40
  echo "done in $SECONDS s" ;;
*)
  echo "usage: bash benchmarks/gpu-proof.sh prepare|run [size]" >&2; exit 2 ;;
esac
