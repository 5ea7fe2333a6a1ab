"""``jaxrl_robot.parallel.jit_seeds``: one program over a leading seed axis."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxrl_robot import parallel


def test_jit_seeds_maps_over_seeds_and_on_the_cpu_compiles_without_constant_folding(monkeypatch):
    """Each seed's row is ``fn`` of that row (by hand), and ``in_axes`` passes unmapped arguments. On the
    CPU the sum of a constant stays a ``reduce`` in the compiled program, where plain ``jit(vmap)`` folds
    it into a constant (XLA's constant folding is off for these programs on the CPU), and the passes
    ``XLA_FLAGS`` turns off stay off: a 1×3 by 3×1 product stays a ``dot`` where ``algsimp`` is off
    (``envs_mjx`` turns it off on the CPU) and becomes element-wise arithmetic where it runs."""
    c = np.arange(16, dtype=np.float32).reshape(4, 4)

    def fn(x):
        return x + jnp.asarray(c).sum(0)

    x = jnp.arange(8.0, dtype=jnp.float32).reshape(2, 4)
    np.testing.assert_array_equal(parallel.jit_seeds(fn)(x), [[24, 29, 34, 39], [28, 33, 38, 43]])
    scaled = parallel.jit_seeds(lambda a, s: a * s, in_axes=(0, None))(x, jnp.float32(2.0))
    np.testing.assert_array_equal(scaled, 2 * np.asarray(x))
    cpu = jax.default_backend() == "cpu"
    kept = " reduce(" in parallel.jit_seeds(fn).lower(x).compile().as_text()
    folded = " reduce(" not in jax.jit(jax.vmap(fn)).lower(x).compile().as_text()
    assert folded and kept == cpu

    def product(a):
        return (a @ a.T).reshape(())

    a = jnp.ones((2, 1, 3), jnp.float32)
    for flags, dot in (("--xla_disable_hlo_passes=algsimp", True), ("", False)):
        monkeypatch.setenv("XLA_FLAGS", flags)
        assert parallel.disabled_passes() == (["algsimp"] if flags else [])
        if cpu:
            assert (" dot(" in parallel.jit_seeds(product).lower(a).compile().as_text()) == dot, flags
    monkeypatch.setenv("XLA_FLAGS", "--xla_foo=1 --xla_disable_hlo_passes=algsimp,cse --xla_disable_hlo_passes=cse")
    assert parallel.disabled_passes() == ["algsimp", "cse"]
