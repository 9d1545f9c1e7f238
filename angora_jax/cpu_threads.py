"""The size of XLA's CPU thread pool, which must be set before JAX starts its CPU backend: on few cores, a program
with two batched matrix factorizations side by side hung forever at 0% CPU.

jaxlib's LAPACK kernels on the CPU (Cholesky, triangular solves, ...) split a large batch into chunks, schedule them
into XLA's intra-op thread pool and wait there for them, on a thread of that same pool (`ParallelBatchMap` in
jaxlib's lapack_kernels.cc, jaxlib 0.10.2). XLA runs independent operations of a program at once, and one step of
MJX has two independent batched Cholesky factorizations (`fwd_position`'s factor of the mass matrix and the Euler
integrator's of the mass matrix plus damping; an auto-reset's forward pass adds a third). When they start together
on a pool of 2 threads (one per core on a 2-core machine), both threads wait for chunks that no free thread is left
to run. The batch that splits is about 64 matrices of the Shadow hand's 24 degrees of freedom: `analyze ablate
--episodes 64` of a ShadowHandReach run hung in about half of its runs, `--episodes 32` never; training with
`ppo.num_envs=128` on the CPU hung in its first cycle.

`size_cpu_pool`, called when this module is imported (the package imports it first, before anything of it starts
JAX, so it imports nothing of the package), gives that pool at least `MIN_THREADS` threads, more than the
factorizations that can wait at once, through `PJRT_NPROC`, which XLA reads when it makes the CPU client. A pool
thread beyond the cores costs nothing measurable (a batched Cholesky loop at a batch that does not split: 10.7-11.0
s with 4 threads on 2 cores against 10.7 s with 2). A `PJRT_NPROC` or `NPROC` already set is left as it is, and so
is a backend JAX started before the package was imported (a notebook that ran JAX first): there, set `PJRT_NPROC=4`
before starting Python.
"""

from __future__ import annotations

import os

# More threads than the batched factorizations of one program that can wait at once (two in an MJX step, three with
# an auto-reset's forward pass).
MIN_THREADS = 4


def schedulable_cores() -> int:
    """The cores this process may run on (its CPU affinity, as XLA counts them), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # no sched_getaffinity (macOS)
        return os.cpu_count() or 1


def size_cpu_pool() -> int | None:
    """Set `PJRT_NPROC` to the larger of the schedulable cores and `MIN_THREADS` unless `PJRT_NPROC` or `NPROC` is set
    (XLA reads them in that order). Returns the number set, or None when one was set already."""
    if any(os.environ.get(name) for name in ("PJRT_NPROC", "NPROC")):
        return None
    threads = max(schedulable_cores(), MIN_THREADS)
    os.environ["PJRT_NPROC"] = str(threads)
    return threads


size_cpu_pool()
