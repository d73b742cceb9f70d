"""Kernel micro-benchmark (hevr/_bench/kernel_micro.py): python benchmarks/kernel.py [--bits B] [--quick]."""

from hevr._bench.kernel_micro import main

if __name__ == "__main__":
    raise SystemExit(main())
