"""Compiling for tests that run a program for a few dozen steps, where compiling is nearly all of the test's time.

XLA's CPU backend at optimisation level 0 compiles the same program (the same HLO, every op kept) with less
optimised machine code: measured on 2 CPU cores, Humanoid's batched MJX step compiles in 47 s instead of 72 s and its
reset in 14 s instead of 21 s, while 32 steps take 4.5 s instead of 0.9 s. Programs that run long (training) keep
the default."""

import os
from collections.abc import Iterator
from contextlib import contextmanager

import jax

QUICK = {"xla_backend_optimization_level": 0}


@contextmanager
def quick_compilation() -> Iterator[None]:
    """Within: JAX compiles every program with XLA's CPU backend at optimisation level 0 and LLVM's expensive passes
    off (`jax_disable_most_optimizations`). The setting is part of the persistent compilation cache's key but not of
    JAX's in-process caches, which would hand the quick programs to any later compile of the same program in this
    process (a later test's training loop, or a test comparing runs bit for bit). So those caches are cleared on
    leaving, unless it was already on when entered (a test's quick compiles within its file's): then it stays on."""
    already = jax.config.values["jax_disable_most_optimizations"]
    jax.config.update("jax_disable_most_optimizations", True)
    try:
        yield
    finally:
        if not already:
            jax.config.update("jax_disable_most_optimizations", False)
            jax.clear_caches()


def compile_quickly(function, *example_args):
    """`function` jitted and compiled for arguments shaped as `example_args`, with the settings above."""
    return jax.jit(function).lower(*example_args).compile(compiler_options=QUICK)


# The same for a subprocess that trains a few cycles (its environment): JAX then compiles every program with XLA's
# CPU backend at optimisation level 0 and LLVM's expensive passes off. Measured on 2 CPU cores: tests/warp_parallel.py
# (Warp reach, 3 cycles on 1 and on 2 devices, and a resume) in 41 s of CPU time instead of 61.
QUICK_SUBPROCESS = {"JAX_DISABLE_MOST_OPTIMIZATIONS": "1"}

# Quicker still, for a subprocess given no XLA_FLAGS of its own: XLA's CPU backend also without its newer fusion
# emitters (--xla_cpu_use_fusion_emitters=false: fused loops emitted element by element, as before those emitters),
# which compile the same HLO in less time. Measured on 2 CPU cores, interleaved: `angora-jax train` of the curriculum
# test's tiny MyoHandPose run in 17-22 s of CPU time instead of 25-29, examples/muscle_hand.ipynb in 78 s instead of
# 98-109. The flag is added to the session's XLA_FLAGS (tests/conftest.py sets them before any test file imports this
# one). QUICK_SUBPROCESS's other users, some of which set XLA_FLAGS of their own, have not been measured with it.
QUICK_SUBPROCESS_NO_FUSION_EMITTERS = QUICK_SUBPROCESS | {
    "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_use_fusion_emitters=false".strip()}
