"""``jaxrl_robot.parallel.jit_seeds``: one program over a leading seed axis."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxrl_robot import parallel


def test_jit_seeds_maps_over_seeds_and_on_the_cpu_compiles_without_constant_folding():
    """Each seed's row is ``fn`` of that row (by hand), ``in_axes`` passes unmapped arguments, and on the
    CPU the sum of a constant stays a ``reduce`` in the compiled program, where plain ``jit(vmap)`` folds it
    into a constant (XLA's constant folding, off for these programs on the CPU)."""
    c = np.arange(16, dtype=np.float32).reshape(4, 4)

    def fn(x):
        return x + jnp.asarray(c).sum(0)

    x = jnp.arange(8.0, dtype=jnp.float32).reshape(2, 4)
    np.testing.assert_array_equal(parallel.jit_seeds(fn)(x), [[24, 29, 34, 39], [28, 33, 38, 43]])
    scaled = parallel.jit_seeds(lambda a, s: a * s, in_axes=(0, None))(x, jnp.float32(2.0))
    np.testing.assert_array_equal(scaled, 2 * np.asarray(x))
    kept = " reduce(" in parallel.jit_seeds(fn).lower(x).compile().as_text()
    folded = " reduce(" not in jax.jit(jax.vmap(fn)).lower(x).compile().as_text()
    assert folded and kept == (jax.default_backend() == "cpu")
