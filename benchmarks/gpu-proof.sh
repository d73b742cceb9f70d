#!/usr/bin/env bash
# Issue 26's one-command proof of the GPU backend, for a session that is lent a GPU machine.
#
#   here, once:        bash benchmarks/gpu-proof.sh prepare
#   device tool run:   carry [".whl"], command: bash benchmarks/gpu-proof.sh run   (timeout_s 480: it ends
#                      by itself in under 7 minutes, leaving the rest of a 15-minute lease for its start)
#
# prepare: ../shared/tools/device-wheels (hevr's dependencies as CPython 3.12 wheels in ./.whl,
# ignored by git) plus the two it does not fetch: google-crc32c and array-api-compat.
# run (on the GPU machine, whose image has CuPy, numpy, pytest, hypothesis): installs the wheels
# into /tmp/site, then, each step's output under $OUT (what comes back):
#   1. nvidia-smi -L                                   -> $OUT/device.txt
#   2. hevr bench --gpu (operations, a 64³ 2048-bit render, throughput; ~3-5 min)
#                                                      -> $OUT/gpu.md, $OUT/gpu.json, $OUT/bench.log
#   3. the gpu-marked tests first, then the kernel suites on the device (HEVR_TEST_KERNELS=cuda: every
#      operation, the key holder's kernels, whole renders)  -> $OUT/pytest.log (written as it goes)
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
  : "${OUT:?run this through the device tool (it sets OUT)}"
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
  nvidia-smi -L 2>&1 | tee "$OUT/device.txt"
  timeout 300 python3 -m hevr bench --gpu --out "$OUT" --work /tmp 2>&1 | tee "$OUT/bench.log"
  HEVR_TEST_KERNELS=cuda timeout 120 python3 -m pytest -q -rs -p no:cacheprovider -o addopts= -m gpu \
    tests/backends/test_cuda_device.py > "$OUT/pytest.log" 2>&1
  HEVR_TEST_KERNELS=cuda timeout 150 python3 -m pytest -q -rs -p no:cacheprovider -o addopts= --maxfail=20 \
    tests/backends/test_cuda_owner.py tests/backends/test_cuda_host_backend.py \
    tests/backends/test_cuda_host_renders.py >> "$OUT/pytest.log" 2>&1
  tail -30 "$OUT/pytest.log" ;;
diagnose)
  # a shorter run for a failure found by `run`: gpu_diagnose.py's checks against Python integers, then the
  # bench with a ${2:-24}³ render (its cases timed one by one)
  : "${OUT:?run this through the device tool (it sets OUT)}"
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
  nvidia-smi -L 2>&1 | tee "$OUT/device.txt"
  timeout 130 python3 benchmarks/gpu_diagnose.py 2>&1 | tee "$OUT/diagnose.log"
  timeout 240 python3 -c "import sys; from pathlib import Path; from hevr._bench.gpu import run_gpu_bench
run_gpu_bench(Path(sys.argv[1]), work=Path('/tmp'), render_size=int(sys.argv[2]), log_line=print)" "$OUT" "${2:-24}" \
    2>&1 | tee "$OUT/bench.log" ;;
*)
  echo "usage: bash benchmarks/gpu-proof.sh prepare|run|diagnose [size]" >&2; exit 2 ;;
esac
