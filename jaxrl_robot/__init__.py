"""jaxrl-robot: JAX-accelerated, vectorised deep reinforcement learning for robot control.

Pure-functional agents (``make_train(config, env) -> train(key)``), returns and losses,
replay buffers and evaluation helpers, designed to be imported into other JAX code.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
