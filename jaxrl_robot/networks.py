"""Actor and critic networks (flax.linen) and diagonal-Gaussian policy helpers.

Networks are plain ``flax.linen`` modules: ``variables = net.init(key, obs)`` and
``net.apply(variables, obs)``, pure functions of their parameters.

* :class:`MLP` — fully connected trunk (ReLU by default; :data:`ACTIVATIONS` names the choices).
* :class:`Critic` — ``V(s)``: MLP with a linear scalar output (no batch-norm; the thesis keeps
  the critic's output linear, §4.1.3).
* :class:`GaussianActor` — the mean action ``μ(s) = tanh(...)`` in ``[-1, 1]`` (the
  environment multiplies by its scale vector C) and the log standard deviation, either a
  fixed hyper-parameter vector σ (the thesis, Table 5.2: σ = [0.8, 0.8, 0.1]) or a learned
  state-independent log-std initialised at ``log σ``, or (``state_std``) a state-dependent
  ``σ(s) = softplus(·) + min_std`` from a second linear head, starting at σ; ``squash=False``
  leaves the mean linear, for a policy whose sample an env wrapper squashes. With
  ``batch_norm=True`` the input and every hidden pre-activation are batch-normalised (thesis
  Fig. 4.2–4.3): batch statistics while training, moving averages for acting and evaluation
  (thesis §4.1.3).
* :class:`BatchRenorm` — the actor's default batch-norm layer: batch renormalisation (Ioffe,
  2017). Plain batch-norm trains the policy that normalises each mini-batch by its own
  statistics, but acts and is evaluated with the moving averages; with a few lanes a mini-batch
  holds only a few goals, so the two policies differ and the trained one is never the one that
  acts. Batch renormalisation keeps the batch statistics in the gradient while its outputs in
  training equal the moving-average ones (up to the r/d clipping), so training, acting and
  evaluation use one policy.

Use :func:`apply_actor` to call an actor with or without batch-norm in either mode, and the
``gaussian_*`` functions for log-probabilities, entropy and KL divergence. Optional
observation normalisation keeps a :class:`~jaxrl_robot.types.RunningStats`
(:func:`init_running_stats`, :func:`update_running_stats`, :func:`normalize`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxrl_robot.types import RunningStats

__all__ = [
    "ACTIVATIONS",
    "BN_MODES",
    "MLP",
    "BatchRenorm",
    "Critic",
    "GaussianActor",
    "apply_actor",
    "gaussian_entropy",
    "gaussian_kl",
    "gaussian_log_prob",
    "gaussian_sample",
    "init_running_stats",
    "normalize",
    "tanh_gaussian_entropy",
    "tanh_log_det_jacobian",
    "update_running_stats",
]

_LOG_2PI = float(np.float32(math.log(2.0 * math.pi)))
"""log(2π) rounded to float32, as a Python float (weakly typed; no JAX computation at import)."""

BN_MODES = ("renorm", "batch")

ACTIVATIONS = {"relu": nn.relu, "swish": nn.swish, "tanh": nn.tanh, "elu": nn.elu}
"""The hidden layers' activation functions by name (brax's PPO networks use ``swish``)."""


def activation_fn(name: str):
    """The function :data:`ACTIVATIONS` names (``ValueError`` listing the choices otherwise)."""
    if name not in ACTIVATIONS:
        raise ValueError(f"activation={name!r} is not one of {', '.join(map(repr, ACTIVATIONS))}")
    return ACTIVATIONS[name]


def _dense(features: int, scale: float, use_bias: bool = True) -> nn.Dense:
    return nn.Dense(features, use_bias=use_bias, kernel_init=nn.initializers.orthogonal(scale))


class MLP(nn.Module):
    """MLP ``[..., D] -> [..., hidden[-1]]`` (orthogonal init, gain √2; ``activation`` of :data:`ACTIVATIONS`)."""

    hidden: Sequence[int] = (200, 200)
    activation: str = "relu"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        act = activation_fn(self.activation)
        for width in self.hidden:
            x = act(_dense(width, jnp.sqrt(2.0))(x))
        return x


class Critic(nn.Module):
    """State-value network ``V(s)``: ``[..., obs] -> [...]``."""

    hidden: Sequence[int] = (200, 200)
    activation: str = "relu"

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = MLP(self.hidden, self.activation)(obs)
        return _dense(1, 1.0)(x)[..., 0]


class BatchRenorm(nn.Module):
    """Batch renormalisation of ``[..., B, F]`` features (Ioffe, 2017, Algorithm 1).

    Training: ``x̂ = (x - μ_B) / σ_B · r + d`` with ``r = sg(clip(σ_B / σ, 1/r_max, r_max))`` and
    ``d = sg(clip((μ_B - μ) / σ, -d_max, d_max))``, where ``μ_B, σ_B² + ε`` are the (masked)
    statistics of the batch and ``μ, σ² + ε`` the moving averages. Unclipped, ``x̂`` equals
    ``(x - μ) / σ`` — the acting/evaluation output — while the gradient still flows through
    the batch statistics as in batch-norm (thesis Fig. 4.2). The moving averages then advance
    ``μ ← m μ + (1 - m) μ_B``, ``σ² ← m σ² + (1 - m) σ_B²`` (as ``flax.linen.BatchNorm``).
    Evaluation: ``x̂ = (x - μ) / σ``. Output ``scale · x̂ + bias``. Variables are named as in
    ``flax.linen.BatchNorm`` (``params``: scale, bias; ``batch_stats``: mean, var).

    Attributes:
      momentum: m.
      epsilon: ε added to the variances.
      r_max, d_max: clipping of the corrections (``r_max = 1, d_max = 0`` is plain batch-norm).
      axis_name: mapped axis over which the batch statistics are pooled in training.
    """

    momentum: float = 0.99
    epsilon: float = 1e-3
    r_max: float = 3.0
    d_max: float = 5.0
    axis_name: str | None = None

    @nn.compact
    def __call__(self, x: jax.Array, use_running_average: bool, mask: jax.Array | None = None) -> jax.Array:
        """``x [..., B, F] -> [..., B, F]``; ``mask`` broadcastable to ``x``: rows counted in the statistics."""
        features = x.shape[-1]
        scale = self.param("scale", nn.initializers.ones, (features,))
        bias = self.param("bias", nn.initializers.zeros, (features,))
        ra_mean = self.variable("batch_stats", "mean", lambda: jnp.zeros((features,), jnp.float32))
        ra_var = self.variable("batch_stats", "var", lambda: jnp.ones((features,), jnp.float32))
        sigma = jnp.sqrt(ra_var.value + self.epsilon)
        # y = scale · x̂ + bias written as x · a + b with per-feature a, b [F]: one multiply-add per
        # element (the longer per-element form, under vmap, crashed XLA's CPU fusion emitter).
        if use_running_average:
            a = scale / sigma
            b = bias - ra_mean.value * a
        else:
            mean_b, var_b = self._batch_stats(x, mask)
            sigma_b = jnp.sqrt(var_b + self.epsilon)
            r = jax.lax.stop_gradient(jnp.clip(sigma_b / sigma, 1.0 / self.r_max, self.r_max))
            d = jax.lax.stop_gradient(jnp.clip((mean_b - ra_mean.value) / sigma, -self.d_max, self.d_max))
            a = scale * r / sigma_b
            b = bias + scale * d - mean_b * a
            if not self.is_initializing():
                m = self.momentum
                ra_mean.value = m * ra_mean.value + (1.0 - m) * jax.lax.stop_gradient(mean_b)
                ra_var.value = m * ra_var.value + (1.0 - m) * jax.lax.stop_gradient(var_b)
        return x * a + b

    def _batch_stats(self, x: jax.Array, mask: jax.Array | None) -> tuple[jax.Array, jax.Array]:
        """Mean and (biased) variance ``[F]`` over every axis but the last, pooled over ``axis_name``."""
        axes = tuple(range(x.ndim - 1))
        if mask is None:
            mean, mean_sq = jnp.mean(x, axis=axes), jnp.mean(x * x, axis=axes)
            if self.axis_name is not None:
                mean, mean_sq = jax.lax.pmean(mean, self.axis_name), jax.lax.pmean(mean_sq, self.axis_name)
            return mean, jnp.maximum(mean_sq - mean * mean, 0.0)
        w = jnp.broadcast_to(mask, x.shape[:-1] + (1,)).astype(x.dtype)
        sums = jnp.sum(jnp.concatenate([x * w, w], axis=-1), axis=axes)  # [F + 1]: Σ w x, Σ w
        if self.axis_name is not None:
            sums = jax.lax.psum(sums, self.axis_name)
        total, count = sums[:-1], sums[-1]
        mean = total / jnp.maximum(count, 1.0)
        sq = jnp.sum(((x - mean) ** 2) * w, axis=axes)
        if self.axis_name is not None:
            sq = jax.lax.psum(sq, self.axis_name)
        return mean, sq / jnp.maximum(count, 1.0)


class GaussianActor(nn.Module):
    """Diagonal-Gaussian policy head: ``obs [..., D] -> (mean [..., A], log_std [..., A])``.

    Attributes:
      action_size: A.
      hidden: hidden layer widths (thesis arm: (200, 200); mobile robot: (256, 256)).
      sigma: initial / fixed standard deviation, one value per action dimension or a scalar.
      learn_std: False → σ is the fixed hyper-parameter ``sigma``; True → a learned log-std.
      state_std: with ``learn_std``, σ depends on the state: ``softplus(W h + b + c) + min_std``
        (brax's parametrisation), ``c`` chosen so that σ starts at ``sigma``.
      min_std: the floor of a state-dependent σ.
      squash: ``tanh`` on the mean (in ``[-1, 1]``); False: a linear mean (the acting side squashes).
      activation: the hidden layers' activation (:data:`ACTIVATIONS`).
      batch_norm: normalise the input and every hidden pre-activation (bias-free linear
        layers, as the BN shift replaces the bias).
      bn_momentum: moving-average decay of the batch-norm statistics.
      bn_epsilon: added to the variance; 1e-3 (not 1e-5) so that a feature nearly constant
        within a small mini-batch is not blown up into huge activations.
      bn_axis_name: mapped axis name over which batch statistics are averaged (set it when
        the actor runs inside ``shard_map``/``vmap`` with a named axis so that every device
        normalises with the global mini-batch statistics).
      bn_mode: ``'renorm'`` → :class:`BatchRenorm` (training outputs equal the acting ones);
        ``'batch'`` → plain ``flax.linen.BatchNorm`` (training normalises by the mini-batch alone).
      bn_r_max, bn_d_max: clipping of batch renormalisation's corrections r and d.
    """

    action_size: int
    hidden: Sequence[int] = (200, 200)
    sigma: Sequence[float] | float = 0.5
    learn_std: bool = False
    batch_norm: bool = False
    bn_momentum: float = 0.99
    bn_epsilon: float = 1e-3
    bn_axis_name: str | None = None
    bn_mode: str = "renorm"
    bn_r_max: float = 3.0
    bn_d_max: float = 5.0
    state_std: bool = False
    min_std: float = 1e-3
    squash: bool = True
    activation: str = "relu"

    @nn.compact
    def __call__(
        self, obs: jax.Array, train: bool = False, mask: jax.Array | None = None
    ) -> tuple[jax.Array, jax.Array]:
        x = obs
        act = activation_fn(self.activation)
        if self.batch_norm:
            x = self._bn(x, train, mask, 0)
        for i, width in enumerate(self.hidden):
            x = _dense(width, jnp.sqrt(2.0), use_bias=not self.batch_norm)(x)
            if self.batch_norm:
                x = self._bn(x, train, mask, i + 1)
            x = act(x)
        mean = _dense(self.action_size, 0.01)(x)
        mean = jnp.tanh(mean) if self.squash else mean
        sigma = jnp.broadcast_to(jnp.asarray(self.sigma, jnp.float32), (self.action_size,))
        if self.learn_std and self.state_std:
            offset = _inverse_softplus(jnp.maximum(sigma - self.min_std, 1e-6))
            raw = nn.Dense(self.action_size, kernel_init=nn.initializers.orthogonal(0.01), name="std")(x)
            return mean, jnp.log(jax.nn.softplus(raw + offset) + self.min_std)
        if self.learn_std:
            log_std = self.param("log_std", lambda _k, s: jnp.log(s), sigma)
        else:
            log_std = jnp.log(sigma)
        return mean, jnp.broadcast_to(log_std, mean.shape)

    def _bn(self, x: jax.Array, train: bool, mask: jax.Array | None, index: int) -> jax.Array:
        # mask [B] of the rows whose batch statistics count (rows past a worker's episode end).
        row_mask = None if mask is None or not train else jnp.asarray(mask, bool)[..., None]
        axis_name = self.bn_axis_name if train else None
        name = f"BatchNorm_{index}"  # one variable layout for both layers (checkpoints, tests)
        if self.bn_mode not in BN_MODES:
            raise ValueError(f"bn_mode={self.bn_mode!r} is not one of {', '.join(map(repr, BN_MODES))}")
        if self.bn_mode == "renorm":
            layer = BatchRenorm(self.bn_momentum, self.bn_epsilon, self.bn_r_max, self.bn_d_max, axis_name, name=name)
            return layer(x, use_running_average=not train, mask=row_mask)
        return nn.BatchNorm(
            use_running_average=not train,
            momentum=self.bn_momentum,
            epsilon=self.bn_epsilon,
            axis_name=axis_name,
            name=name,
        )(x, mask=row_mask)


def _inverse_softplus(y: jax.Array) -> jax.Array:
    """``x`` with ``softplus(x) = y`` for ``y > 0``: ``log(expm1(y))``."""
    return y + jnp.log(-jnp.expm1(-y))


def apply_actor(
    actor: nn.Module,
    params: Any,
    batch_stats: Any,
    obs: jax.Array,
    train: bool = False,
    mask: jax.Array | None = None,
) -> tuple[tuple[jax.Array, jax.Array], Any]:
    """Call ``actor`` in acting (``train=False``) or training mode.

    Args:
      actor: a :class:`GaussianActor` (or any module with the same call signature).
      params: the actor's ``params`` collection.
      batch_stats: its ``batch_stats`` collection, or ``{}`` / ``None`` without batch-norm.
      obs: ``[..., D]`` observations (a mini-batch ``[B, D]`` when ``train=True``).
      train: True → normalise with the statistics of ``obs`` and update the moving averages;
        False → normalise with the moving averages (one state is enough).
      mask: optional ``[B]`` bool/0-1 rows of ``obs`` that count in the batch statistics
        (training mode only); the other rows are still normalised with them.
    Returns:
      ``((mean, log_std), new_batch_stats)``; ``new_batch_stats is batch_stats`` unless
      batch-norm ran in training mode.
    """
    variables = {"params": params}
    if batch_stats:
        variables["batch_stats"] = batch_stats
    if train and batch_stats:
        kwargs = {} if mask is None else {"mask": mask}
        out, updates = actor.apply(variables, obs, train=True, mutable=["batch_stats"], **kwargs)
        return out, updates["batch_stats"]
    return actor.apply(variables, obs, train=False), batch_stats


def gaussian_log_prob(mean: jax.Array, log_std: jax.Array, action: jax.Array) -> jax.Array:
    """``log π(a|s)`` of a diagonal Gaussian, summed over the last axis: ``[..., A] -> [...]``."""
    chex.assert_equal_shape((mean, log_std, action))
    z = (action - mean) * jnp.exp(-log_std)
    return jnp.sum(-0.5 * z**2 - log_std - 0.5 * _LOG_2PI, axis=-1)


def gaussian_entropy(log_std: jax.Array) -> jax.Array:
    """Entropy ``H(π(·|s))`` of a diagonal Gaussian: ``[..., A] -> [...]``."""
    return jnp.sum(log_std + 0.5 * (1.0 + _LOG_2PI), axis=-1)


def tanh_log_det_jacobian(u: jax.Array) -> jax.Array:
    """``log |d tanh(u) / du| = log(1 − tanh(u)²) = 2 (log 2 − u − softplus(−2u))`` (the stable form),
    summed over the last axis: ``[..., A] -> [...]``."""
    return jnp.sum(2.0 * (math.log(2.0) - u - jax.nn.softplus(-2.0 * u)), axis=-1)


def tanh_gaussian_entropy(mean: jax.Array, log_std: jax.Array, noise: jax.Array) -> jax.Array:
    """One-sample estimate of the entropy of ``tanh(u)``, ``u ~ N(mean, exp(log_std)²)``:
    ``H(u) + log |d tanh(u)/du|`` at ``u = mean + exp(log_std) · noise`` (``noise ~ N(0, 1)``, reparametrised,
    so the estimate's gradient reaches mean and σ; brax's ``NormalTanhDistribution.entropy``). Unlike the
    Gaussian's, it falls as the mean moves into tanh's flat tails. ``[..., A] x 3 -> [...]``."""
    chex.assert_equal_shape((mean, log_std, noise))
    return gaussian_entropy(log_std) + tanh_log_det_jacobian(mean + jnp.exp(log_std) * noise)


def gaussian_kl(mean_p: jax.Array, log_std_p: jax.Array, mean_q: jax.Array, log_std_q: jax.Array) -> jax.Array:
    """``KL(p ‖ q)`` of diagonal Gaussians, summed over the last axis: ``[..., A] -> [...]``.

    With ``p = π_old`` and ``q = π_θ`` this is the penalty of Eq. 5.3.
    """
    chex.assert_equal_shape((mean_p, log_std_p, mean_q, log_std_q))
    var_ratio = jnp.exp(2.0 * (log_std_p - log_std_q))
    mahal = ((mean_p - mean_q) * jnp.exp(-log_std_q)) ** 2
    return jnp.sum(0.5 * (var_ratio + mahal - 1.0) + log_std_q - log_std_p, axis=-1)


def gaussian_sample(key: jax.Array, mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """Draw ``a ~ N(mean, exp(log_std)²)``: ``[..., A] -> [..., A]``."""
    return mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape, mean.dtype)


def init_running_stats(size: int) -> RunningStats:
    """Empty statistics for ``[size]`` observations (mean 0, variance 1)."""
    return RunningStats(
        count=jnp.asarray(1e-4, jnp.float32), mean=jnp.zeros((size,), jnp.float32), var=jnp.ones((size,), jnp.float32)
    )


def update_running_stats(
    stats: RunningStats, batch: jax.Array, axis_name: str | None = None, mask: jax.Array | None = None
) -> RunningStats:
    """Merge a batch ``[..., D]`` into ``stats`` (Chan et al.'s parallel variance update).

    ``axis_name``: a mapped axis (e.g. the device axis inside ``shard_map``) whose batches are
    pooled first, so every device ends with the same statistics. ``mask`` (``[...]``, the batch's
    leading shape): only rows where it is nonzero count; a batch with no such row changes nothing.
    """
    x = batch.reshape(-1, batch.shape[-1]).astype(jnp.float32)
    if mask is None:
        w = jnp.ones((x.shape[0], 1), jnp.float32)
    else:
        w = (mask.reshape(-1, 1) != 0).astype(jnp.float32)
    n = jnp.sum(w)
    total = jnp.sum(w * x, axis=0)
    if axis_name is not None:
        n, total = jax.lax.psum((n, total), axis_name)
    safe_n = jnp.maximum(n, 1.0)
    mean_b = total / safe_n
    sq = jnp.sum(w * (x - mean_b) ** 2, axis=0)
    if axis_name is not None:
        sq = jax.lax.psum(sq, axis_name)
    var_b = sq / safe_n
    count = stats.count + n
    safe_count = jnp.maximum(count, 1.0)
    delta = mean_b - stats.mean
    mean = stats.mean + delta * n / safe_count
    var = (stats.var * stats.count + var_b * n + delta**2 * stats.count * n / safe_count) / safe_count
    merged = RunningStats(count=count, mean=mean, var=var)
    return jax.tree.map(lambda new, old: jnp.where(n > 0, new, old), merged, stats)


def normalize(stats: RunningStats | None, obs: jax.Array, clip: float = 10.0) -> jax.Array:
    """``clip((obs - mean) / std)``; identity when ``stats`` is None. ``[..., D] -> [..., D]``."""
    if stats is None:
        return obs
    return jnp.clip((obs - stats.mean) / jnp.sqrt(stats.var + 1e-8), -clip, clip)
