"""Reference trajectories: values and derivatives at hand-computed times (Eq. 3.24–3.27)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs_mjx import trajectories as tr

PI = math.pi
S = math.sqrt(0.5)  # sin(π/4)
Q = math.sqrt(2.0)  # 2 sin(π/4)


def _ref(name, t):
    r = tr.planar_reference(name, jnp.float32(t))
    return np.asarray(r.pos), np.asarray(r.vel), np.asarray(r.cmd)


def test_sine_values_at_hand_computed_times():
    # t = 0: on the origin, heading arctan(0.4); v = sqrt(1 + 0.16); w = -0.08 sin(0)/(...) = 0.
    pos, vel, cmd = _ref("sine", 0.0)
    np.testing.assert_allclose(pos, [0.0, 0.0, math.atan(0.4)], atol=1e-6)
    np.testing.assert_allclose(vel, [1.0, 0.4, 0.0], atol=1e-6)
    np.testing.assert_allclose(cmd, [math.sqrt(1.16), 0.0], atol=1e-6)
    # t = 2.5π (0.2 t = π/2): crest y = 2, ẏ = 0, heading 0, ÿ = -0.08 so θ̇ = -0.08.
    pos, vel, cmd = _ref("sine", 2.5 * PI)
    np.testing.assert_allclose(pos, [2.5 * PI, 2.0, 0.0], atol=1e-5)
    np.testing.assert_allclose(vel, [1.0, 0.0, -0.08], atol=1e-5)
    np.testing.assert_allclose(cmd, [1.0, -0.08], atol=1e-5)
    # t = 5π: y = 0 going down, ẏ = -0.4, heading -arctan(0.4) (range -π/2..π/2, Eq. 3.25).
    pos, vel, _ = _ref("sine", 5 * PI)
    np.testing.assert_allclose(pos, [5 * PI, 0.0, -math.atan(0.4)], atol=1e-5)
    np.testing.assert_allclose(vel[:2], [1.0, -0.4], atol=1e-5)


@pytest.mark.parametrize(
    "t, xy, vxy, theta",
    [
        # (x, y) = (sin πt/8, -2 cos πt/8); (ẋ, ẏ) = (π/8 cos, π/4 sin).
        (0.0, (0.0, -2.0), (PI / 8, 0.0), 0.0),  # ẋ > 0, ẏ = 0: arctan(0) = 0
        (2.0, (S, -Q), (PI / 8 * S, PI / 4 * S), math.atan(2.0)),
        (4.0, (1.0, 0.0), (0.0, PI / 4), PI / 2),  # ẋ ≈ 0, ẏ > 0
        (6.0, (S, Q), (-PI / 8 * S, PI / 4 * S), PI - math.atan(2.0)),
        (8.0, (0.0, 2.0), (-PI / 8, 0.0), PI),  # ẋ < 0: arctan(0) + π
        (10.0, (-S, Q), (-PI / 8 * S, -PI / 4 * S), PI + math.atan(2.0)),
        (12.0, (-1.0, 0.0), (0.0, -PI / 4), 1.5 * PI),  # ẋ ≈ 0, ẏ < 0
        (14.0, (-S, -Q), (PI / 8 * S, -PI / 4 * S), 2 * PI - math.atan(2.0)),  # ẋ > 0, ẏ < 0: arctan + 2π
    ],
)
def test_ellipse_values_and_eq_3_27_quadrants(t, xy, vxy, theta):
    pos, vel, _ = _ref("ellipse", t)
    np.testing.assert_allclose(pos[:2], xy, atol=1e-5)
    np.testing.assert_allclose(vel[:2], vxy, atol=1e-5)
    np.testing.assert_allclose(pos[2], theta, atol=1e-4)
    assert 0.0 <= pos[2] < 2 * PI


def test_eq_3_27_exact_zero_x_velocity_cases():
    h = tr.heading_quadrant
    np.testing.assert_allclose(h(0.0, 1.0), PI / 2, atol=1e-7)
    np.testing.assert_allclose(h(0.0, 0.0), PI / 2, atol=1e-7)  # ẏ >= 0 branch
    np.testing.assert_allclose(h(0.0, -1.0), 1.5 * PI, atol=1e-6)
    np.testing.assert_allclose(h(-0.0, -2.0), 1.5 * PI, atol=1e-6)
    # the other branches with exact inputs
    np.testing.assert_allclose(h(1.0, 1.0), PI / 4, atol=1e-7)
    np.testing.assert_allclose(h(1.0, -1.0), 2 * PI - PI / 4, atol=1e-6)
    np.testing.assert_allclose(h(-1.0, 1.0), 0.75 * PI, atol=1e-6)
    np.testing.assert_allclose(h(-1.0, -1.0), 1.25 * PI, atol=1e-6)
    np.testing.assert_allclose(h(-1.0, 0.0), PI, atol=1e-6)
    # no inf/nan leaks from the ẋ = 0 division, and the range stays [0, 2π)
    grads = jax.grad(lambda y: tr.heading_quadrant(jnp.float32(0.0), y))(jnp.float32(1.0))
    assert np.isfinite(grads)
    assert float(h(1.0, -1e-30)) < 2 * PI


def test_ellipse_turn_rate_and_speed_hand_computed():
    # At t = 0 the robot is at the end of the major axis: speed π/8, curvature b/a² = 2, w = π/4.
    _, vel, cmd = _ref("ellipse", 0.0)
    np.testing.assert_allclose(cmd, [PI / 8, PI / 4], rtol=1e-5)
    np.testing.assert_allclose(vel[2], PI / 4, rtol=1e-5)
    # At t = 4 (end of the minor axis): speed π/4, curvature a/b² = 1/4, w = π/16.
    _, _, cmd = _ref("ellipse", 4.0)
    np.testing.assert_allclose(cmd, [PI / 4, PI / 16], rtol=1e-5)


@pytest.mark.parametrize("name", ["sine", "ellipse"])
def test_derivatives_match_autodiff(name):
    """vel is d(pos)/dt (θ away from the 2π jump) and cmd is (|(ẋ, ẏ)|, θ̇)."""
    times = jnp.linspace(0.3, 15.7, 23)
    d_pos = jax.vmap(jax.jacfwd(lambda t: tr.planar_reference(name, t).pos))(times)
    ref = jax.vmap(lambda t: tr.planar_reference(name, t))(times)
    np.testing.assert_allclose(d_pos, ref.vel, atol=2e-4)
    np.testing.assert_allclose(ref.cmd[:, 0], jnp.hypot(ref.vel[:, 0], ref.vel[:, 1]), rtol=1e-6)
    np.testing.assert_allclose(ref.cmd[:, 1], ref.vel[:, 2], rtol=1e-6)
    # the heading is the direction of motion (no lateral reference velocity, Eq. 3.17)
    lateral = -ref.vel[:, 0] * jnp.sin(ref.pos[:, 2]) + ref.vel[:, 1] * jnp.cos(ref.pos[:, 2])
    np.testing.assert_allclose(lateral, 0.0, atol=1e-5)


def test_joint_sinusoids_values_and_derivatives():
    c, a, w, p = [0.1, 1.0, 0.2], [0.5, 0.2, 0.1], [2.0, 1.0, 0.5], [0.0, PI / 2, 0.0]
    r = tr.joint_sinusoids(PI / 4, c, a, w, p)
    # joint 0: 0.1 + 0.5 sin(π/2) = 0.6, rate 0.5·2·cos(π/2) = 0, acc -0.5·4·1 = -2
    # joint 1: 1 + 0.2 sin(π/4 + π/2), rate 0.2 cos(3π/4), acc -0.2 sin(3π/4)
    # joint 2: 0.2 + 0.1 sin(π/8)
    s2 = S
    np.testing.assert_allclose(r.q, [0.6, 1.0 + 0.2 * s2, 0.2 + 0.1 * math.sin(PI / 8)], atol=1e-6)
    np.testing.assert_allclose(r.qd, [0.0, -0.2 * s2, 0.05 * math.cos(PI / 8)], atol=1e-6)
    np.testing.assert_allclose(r.qdd, [-2.0, -0.2 * s2, -0.025 * math.sin(PI / 8)], atol=1e-6)
    dq = jax.jacfwd(lambda t: tr.joint_sinusoids(t, c, a, w, p).q)(jnp.float32(0.7))
    np.testing.assert_allclose(dq, tr.joint_sinusoids(0.7, c, a, w, p).qd, atol=1e-5)


def test_unknown_trajectory_names_choices():
    with pytest.raises(ValueError, match="trajectory='circle'.*'sine', 'ellipse'"):
        tr.planar_reference("circle", 0.0)
    assert tr.default_duration("sine") == pytest.approx(10 * PI)
    assert tr.default_duration("ellipse") == 16.0
