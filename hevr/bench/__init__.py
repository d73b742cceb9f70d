"""Benchmarks behind ``hevr bench``: the paper's Tables 1-3, limits, python-paillier, scaling.

Modules: ``settings`` (quick / default / paper), ``paper`` (the published figures),
``measure`` (timers, machine, workers), ``cases`` (one function per kind of cell),
``crypto_micro`` and ``kernel_micro`` (one-core micro-benchmarks), ``runner`` (resumable
orchestration, raw JSON), ``report`` (the markdown: head, scaling, pipeline, the sections put
together) with ``report_goals`` (the earlier issues' goals), ``report_tables`` (the paper's Tables
1-3), ``report_limits`` (floors, primitives, python-paillier) and ``report_cells`` (how one cell
reads), ``plot`` (the figure).

The GPU proof: ``gpu`` (``hevr bench --gpu``, its steps in order) with ``gpu_operations`` (each
operation against cpu, and their rates), ``gpu_renders`` (a phantom's frames on the backend and on
cpu) and ``gpu_report`` (``gpu.md``); ``gpu_goals`` (issue 40's goal table, step by step on a GPU
machine) with ``gpu_goals_table`` (``goals.md``), ``gpu_packed`` (its packed step: a packed store's
frames on the backend and on cpu, issue 46) and ``gpu_common`` (what those steps share: rows,
digests, the key, a LocalCluster).
"""
