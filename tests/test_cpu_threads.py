"""XLA's CPU thread pool, sized when angora_jax is imported (angora_jax/cpu_threads.py): jaxlib's batched LAPACK
kernels wait inside that pool for chunks they scheduled into it, so two of them side by side (as in every MJX step)
on a pool of 2 threads hung forever at 0% CPU (`analyze ablate --episodes 64` of a ShadowHandReach run)."""

import os
import subprocess
import sys

import pytest

from angora_jax import cpu_threads

# Three independent batched Cholesky factorizations in a loop, as in an MJX step (fwd_position's and the Euler
# integrator's, and an auto-reset's forward pass), in a process held to 2 cores. A batch of 128 matrices of 24 x 24
# (the Shadow hand's degrees of freedom) is split into chunks on the pool; with the pool left at 2 threads
# (PJRT_NPROC=2) the program hung in 12 of 12 runs, and finished in about 3 s in 5 of 5 with the package's pool.
SIDE_BY_SIDE = """
import os, sys
os.sched_setaffinity(0, {cores})  # before XLA counts the cores
import angora_jax
import jax
import jax.numpy as jnp

n, batch = 24, 128
x = jax.random.normal(jax.random.key(0), (batch, n, n))

def body(carry):
    i, m = carry
    factors = [jnp.linalg.cholesky(p @ jnp.swapaxes(p, -1, -2) + n * jnp.eye(n))
               for p in (jnp.tanh(m) + m, jnp.sin(m) + m, jnp.cos(m) + m)]
    return i + 1, m + 1e-9 * sum(factors)

run = jax.jit(lambda m: jax.lax.while_loop(lambda c: c[0] < 1000, body, (0, m))[1])
print(os.environ.get("PJRT_NPROC"), bool(jnp.isfinite(run(x)).all()))
"""


@pytest.mark.skipif(
    not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
    reason="needs two cores to hold the process to",
)
def test_batched_factorizations_side_by_side_finish_on_two_cores():
    cores = set(sorted(os.sched_getaffinity(0))[:2])
    environment = {k: v for k, v in os.environ.items() if k not in ("PJRT_NPROC", "NPROC")}
    environment["JAX_PLATFORMS"] = "cpu"
    try:
        done = subprocess.run(
            [sys.executable, "-c", SIDE_BY_SIDE.format(cores=cores)],
            capture_output=True,
            text=True,
            env=environment,
            timeout=90,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(
            "batched Cholesky factorizations side by side hung on 2 cores: XLA's CPU thread pool was left "
            "at 2 threads, which both waited inside jaxlib's LAPACK kernels (see angora_jax/cpu_threads.py)"
        )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == [str(cpu_threads.MIN_THREADS), "True"]


def test_a_thread_count_set_by_the_user_is_kept(monkeypatch):
    monkeypatch.setenv("NPROC", "2")
    monkeypatch.delenv("PJRT_NPROC", raising=False)
    assert cpu_threads.size_cpu_pool() is None
    assert "PJRT_NPROC" not in os.environ
    monkeypatch.delenv("NPROC")
    monkeypatch.setattr(cpu_threads, "schedulable_cores", lambda: 16)
    assert cpu_threads.size_cpu_pool() == 16 and os.environ["PJRT_NPROC"] == "16"  # many cores: XLA's own count
