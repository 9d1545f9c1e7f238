"""The tests' quick compilation (tests/quick_compile.py) leaves no quick program behind for later tests."""

import jax
import jax.numpy as jnp
from quick_compile import quick_compilation


def program(x):
    for _ in range(8):
        x = jnp.tanh(x @ x) * 2.0 + 1.0
    return x


def test_a_program_compiled_after_quick_compilation_is_compiled_again():
    x = jnp.ones((32, 32))
    with quick_compilation():
        assert jax.config.read("jax_disable_most_optimizations")
        quick = jax.jit(program).lower(x).compile().as_text()
    default = jax.jit(program).lower(x).compile().as_text()
    assert not jax.config.read("jax_disable_most_optimizations")
    # The two compiles stand on different source lines, which an executable's metadata names: the same text is the
    # quick executable handed back by JAX's in-process caches, which key on the program and not on the setting (it
    # was, before quick_compilation cleared them).
    assert default != quick
