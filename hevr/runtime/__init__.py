"""Running hevr's jobs in a process: the Dask scheduler, progress, cancellation, the per-process
accounting of task time, the C allocator's settings and the caches of recent keys' tables.

=================================  ===========================================================
:mod:`hevr.runtime.scheduler`      task lists on the given or active Dask client
:mod:`hevr.runtime.progress`       one progress display: a widget, a bar or log lines
:mod:`hevr.runtime.cancel`         stopping an interrupted job's tasks in this process
:mod:`hevr.runtime.stats`          where render tasks spend their time
:mod:`hevr.runtime.malloc`         keeping a frame's temporary arrays out of ``mmap``
:mod:`hevr.runtime.recent`         per-process caches of the most recent keys' derived tables
=================================  ===========================================================
"""
