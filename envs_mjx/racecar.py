"""``racecar`` — autonomous racing among nine scripted opponents (thesis ch. 6, §6.1.1–6.1.3).

The thesis drove in TORCS, which cannot be used here; this is a pure-JAX race with the same
interface and semantics: closed roads of given width (:mod:`envs_mjx.racetrack`), our car as a
planar dynamic bicycle model, nine scripted opponents on racing lines, collisions with damage,
ranking and overtakes.  There is no MJX model: a car on a flat road is a 3-DOF rigid body whose
forces come from a tyre law, not from contacts, and the road is a 2-D corridor; MJX would only
integrate the same six numbers at the cost of a full rigid-body pipeline per lane, and its
contact solver does not model tyres.  ``reset(key)`` / ``step(state, action)`` are pure,
unbatched and jit/vmap-able like the MJX environments.

**Action** ``a ∈ [−1, 1]^3`` (thesis §6.1.1): steering (−1 full right, +1 full left; wheel angle
``δ = steer_lock · a_0``), acceleration and brake, both pedals in ``[0, 1]``.  The policy's
outputs map to pedals by ``pedal_map``: ``"clip"`` (default) ``pedal = max(a, 0)``, as TORCS does
with out-of-range commands, so that the OU noise means of Table 6.1 (0.5 on acceleration, −0.1
on brake) mean "half throttle, brake mostly off"; ``"affine"`` ``pedal = (a + 1) / 2``.
:meth:`RaceCar.action_from_controls` inverts the map.

**Vehicle** (``n_substeps`` semi-implicit Euler steps of ``dt / n_substeps`` per control step).
Body-frame state ``(v_x, v_y, r)``, world pose ``(x, y, ψ)``; axle grips ``G_f = μ m g l_r / L``,
``G_r = k_r μ m g l_f / L`` (static loads, no load transfer; ``k_r = rear_grip`` > 1, wider rear
tyres, makes the car understeer at the limit).  Longitudinal: rear-wheel drive
``F_d = throttle · min(traction · G_r, P / max(v_x, 1))``, brake ``brake · B_max`` split
``brake_bias`` front / rest rear and capped at each axle's grip, aerodynamic drag ``c_d v_x |v_x|``
and rolling resistance ``c_rr m g``, the brakes and resistances opposing motion (``tanh(v_x / 0.5)``).
Lateral (simplified Pacejka "magic formula"): ``F_y = −D_y sin(C atan(B α))`` per axle with slip
angles ``α_f = atan2(v_y + l_f r, v̄) − δ``, ``α_r = atan2(v_y − l_r r, v̄)``, ``v̄ = max(v_x, 3)``, and
peak ``D_y = sqrt(G² − F_x²)`` (friction circle, kept ≥ 0.1 G).  Then::

    m (v̇_x − v_y r) = F_xr + F_xf cos δ − F_yf sin δ tanh(v_x / 0.5) − F_drag
    m (v̇_y + v_x r) = F_yr + F_yf cos δ + F_xf sin δ
    I_z ṙ          = l_f (F_yf cos δ + F_xf sin δ) − l_r F_yr

(the ``tanh`` keeps the front tyres' drag in a turn from reversing a car at standstill).

Below 5 m/s the lateral state blends linearly (fully at 2 m/s) into the kinematic bicycle
``r = v_x tan δ / L``, ``v_y = l_r r``, which keeps the slip angles defined at standstill.  Off
the road (``|d| > 1``) the grip is ``offroad_grip · μ``.  A wall stands ``runoff`` metres beyond
each edge.

**Opponents.**  ``n_opponents`` cars move along racing lines, constant offsets from the axis
chosen per episode from ``opponent_lanes`` (fractions of the half width).  Opponent ``i`` aims at
``min(v_top_i, f_i · v_prof(s))`` — ``v_prof`` the road's speed profile
(:func:`envs_mjx.racetrack.speed_profile` with lateral and braking accelerations ``profile_grip ·
μ g`` on the inner edge's curvature), ``f_i`` and ``v_top_i`` drawn per episode — follows
the nearest car ahead within its lane (ours included) at ``v_lead + (gap − 4 m) / 2 s``, and
changes speed by at most ``opponent_accel`` / ``opponent_decel``.  They start ahead of our car
with gaps drawn from ``opponent_gap``; they are kinematic (pushed by nothing).

**Collisions.**  Every physics step our car (a ``car_length × car_width`` rectangle) is tested
against each opponent by the separating-axis test and against the walls; on contact it is moved
out along the axis of least overlap, loses its velocity into the obstacle, and its ``damage``
grows by ``damage_gain · (1 + impact speed in m/s)``.  A step whose damage grew is a collision
(thesis §6.1.2).

**Observation** (60-dim, thesis §6.1.1, in the thesis's order; :data:`OBS_SLICES`)::

    [θ, tracks_1..19, d, v_x, v_y, v_z, opponents_1..36]

* ``θ = wrap(ψ − ψ_axis) ∈ [−π, π)``: angle between the car and the track axis (rad).
* ``tracks``: range finders at ``rangefinder_angles`` from the car's heading (TORCS's default
  −90°…90°), distance to the first road edge, capped at ``max_range`` (200 m); all −1 when the
  car is off the road (as TORCS), so ``min(tracks) < 0`` ⇔ out of track.
* ``d = e / (w / 2)``: signed distance to the axis (+1 left edge, −1 right edge).
* ``v_x, v_y``: body-frame speeds; ``v_z = 0`` on these flat roads (kept for the layout).
* ``opponents``: 36 sectors of 10°; sector ``k`` covers bearings ``[−π + kπ/18, −π + (k+1)π/18)``
  from the car's heading (anticlockwise positive: sectors 0–17 on the right, 18–35 on the left,
  straight ahead between 17 and 18), each the centre distance to the nearest opponent in it,
  ``max_range`` when none is closer.

With ``opponent_speeds`` (off by default) 36 more values follow (96-dim): per sector the closing
speed of the opponent it reports (positive when we approach it), 0 where none.  With
``opponent_offsets`` (off by default) 36 more follow those: per sector that opponent's offset from
the axis relative to ours, in half widths (left positive), 0 where none.

With ``normalize_obs`` (default) distances are divided by ``max_range`` (or, with
``distance_scale="log"``, mapped by ``log(1 + d) / log(1 + max_range)``) and speeds by
``speed_scale`` (300 km/h, the scale of the usual TORCS client); ``θ`` and ``d`` are unchanged and
out-of-track range finders still read −1.

**Reward** (Eq. 6.1), SI units (m/s): ``r = r_1 + r_2``, ``r_1 = v_x cos θ − v_x |sin θ| − v_x |d|``,
``r_2 = 2 (n − rank)`` with ``n = n_opponents + 1`` cars and ``rank`` 1 for the leader.  A step
with a collision (damage grew), out of track (``min(tracks) < 0``) or driving backwards
(``cos θ < 0``) gets ``penalty = −10`` instead (``penalty_mode="replace"``, the thesis's wording;
``"add"`` adds it).  The named terms are in ``metrics`` (``r_speed``, ``r_lateral``, ``r_offset``,
``r_rank``, ``penalty``).

**Termination**: lap(s) finished (``success``; ``laps``), driving backwards, the out-of-track
counter (steps off the road, cumulative) above ``out_limit`` (100), or the speed along the axis
``v_x cos θ`` below ``slow_speed`` for more than ``slow_limit`` consecutive steps (too slow /
stuck).  The time limit ``max_steps`` is the wrappers' truncation.

**Expert**: :func:`expert_action` (module end), a scripted driver for the imitation stage of
§6.1.2 (the thesis used TORCS's example driver).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import State
from flax import struct

from envs_mjx import racetrack
from envs_mjx.base import RobotEnv, sanitize_action
from envs_mjx.config import ConfigError, check_choice, check_range, check_vector

__all__ = [
    "OBS_SLICES",
    "PEDAL_MAPS",
    "RaceCar",
    "RaceCarConfig",
    "RaceState",
    "Road",
    "TORCS_RANGEFINDER_ANGLES",
    "LAP_OUTCOMES",
    "expert_action",
    "lap_summary",
    "make_lap_test",
    "race_reward",
]

PEDAL_MAPS = ("clip", "affine")
ROAD_CHOICES = (*racetrack.ROADS, "random")
PENALTY_MODES = ("replace", "add")
DISTANCE_SCALES = ("linear", "log")
GRAVITY = 9.81

TORCS_RANGEFINDER_ANGLES = (-90, -75, -60, -45, -30, -20, -15, -10, -5, 0, 5, 10, 15, 20, 30, 45, 60, 75, 90)
"""Range-finder directions (degrees from the car's heading, left positive): TORCS's default set."""

OBS_SLICES = {
    "angle": slice(0, 1),
    "tracks": slice(1, 20),
    "track_pos": slice(20, 21),
    "speed": slice(21, 24),
    "opponents": slice(24, 60),
}
"""Where each sensor of thesis §6.1.1 sits in the 60-dim observation."""

N_SECTORS = 36


@dataclasses.dataclass(frozen=True)
class RaceCarConfig:
    """Settings of ``racecar``; SI units (m, s, kg, N, W, rad unless said)."""

    road: str = "train"
    """'train' (12 m) or the unseen 'test1' (10 m), 'test2', 'test3' (12 m); :mod:`envs_mjx.racetrack`.
    'random': every episode drives a road drawn from a bank of ``road_bank`` roads — 'train' and
    ``road_bank − 1`` roads of the generated family :func:`envs_mjx.racetrack.random_road_spec`
    (never the test roads), so that a policy learns driving rather than one road."""
    road_bank: int = 64
    """Roads of the bank that ``road='random'`` draws from ('train' included)."""
    road_seed: int = 0
    """Which generated family ``road='random'`` takes its roads from."""
    track_points: int = 1024
    """Samples of the road's centre line (about 2 m apart); roads with equal counts share compiled code."""
    dt: float = 0.1
    """Control period."""
    n_substeps: int = 10
    """Physics steps per control step."""
    max_steps: int = 3000
    """Time limit in control steps (applied by the wrappers)."""
    laps: int = 1
    """The episode succeeds and ends after this many laps."""
    random_start: bool = True
    """Start at a uniformly drawn point of the lap (else at arc length 0)."""
    start_speed: float = 0.0
    """Our car's initial forward speed."""
    n_opponents: int = 9
    """Scripted opponents (the thesis: 10 cars in all)."""
    opponent_lanes: tuple[float, ...] = (-0.5, 0.0, 0.5)
    """Racing lines: offsets from the axis in half widths, one drawn per opponent and episode."""
    opponent_speed_factor: tuple[float, float] = (0.55, 0.9)
    """Range of f_i, the fraction of the speed profile an opponent drives at."""
    opponent_top_speed: tuple[float, float] = (18.0, 45.0)
    """Range of an opponent's top speed v_top_i."""
    opponent_gap: tuple[float, float] = (20.0, 40.0)
    """Range of the start gaps between successive cars, ours first."""
    opponent_accel: float = 4.0
    """Largest speed gain of an opponent (m/s²)."""
    opponent_decel: float = 9.0
    """Largest speed loss of an opponent (m/s²)."""
    mass: float = 1150.0
    yaw_inertia: float = 2000.0
    l_front: float = 1.25
    """Centre of mass to front axle."""
    l_rear: float = 1.35
    """Centre of mass to rear axle."""
    car_length: float = 4.6
    car_width: float = 1.9
    steer_lock: float = 0.366
    """Wheel angle at full steering (TORCS's default steer lock, 21°)."""
    power: float = 250e3
    """Engine power."""
    brake_force: float = 13e3
    """Total brake force at full brake."""
    brake_bias: float = 0.5
    """Front share of the brake force."""
    drag: float = 0.4
    """c_d of the drag force c_d v² (N s²/m²)."""
    rolling: float = 0.015
    """Rolling-resistance coefficient c_rr."""
    mu: float = 1.2
    """Tyre–road friction coefficient."""
    tyre_b: float = 12.0
    """Pacejka stiffness factor B."""
    tyre_c: float = 1.5
    """Pacejka shape factor C."""
    rear_grip: float = 1.1
    """Rear tyres' grip (peak force and stiffness) relative to the front's: wider rear tyres make the
    car understeer at the limit instead of spinning."""
    traction: float = 0.8
    """Largest drive force as a fraction of the rear tyres' grip (a traction control)."""
    offroad_grip: float = 0.6
    """Grip off the road as a fraction of mu."""
    runoff: float = 4.0
    """Distance from each road edge to its wall."""
    damage_gain: float = 10.0
    """Damage per contact is damage_gain (1 + impact speed)."""
    profile_grip: tuple[float, float] = (0.65, 0.45)
    """Lateral and braking acceleration of the speed profile, as fractions of mu g."""
    rangefinder_angles: tuple[float, ...] = TORCS_RANGEFINDER_ANGLES
    """19 range-finder directions, degrees from the heading, left positive."""
    max_range: float = 200.0
    """Range of the range finders and opponent sensors."""
    normalize_obs: bool = True
    """Divide distances by max_range and speeds by speed_scale in the observation."""
    distance_scale: str = "linear"
    """How ``normalize_obs`` maps range-finder and opponent distances ``d`` into [0, 1]: 'linear'
    ``d / max_range`` (the thesis's scaling), or 'log' ``log(1 + d) / log(1 + max_range)``, which
    spreads the near distances that decide a braking point (4.6 m and 6 m: 0.023 and 0.030 linear,
    0.32 and 0.37 log)."""
    opponent_speeds: bool = False
    """Append 36 values to the observation (96-dim): per 10° sector, the closing speed (m/s, positive
    when approaching) of the opponent the sector reports, 0 where none.  TORCS's sensors (the 60-dim
    observation of §6.1.1) give distances only, from which one frame cannot tell a slower car ahead
    from a faster one."""
    opponent_offsets: bool = False
    """Append 36 more values (after the closing speeds, if any): per 10° sector, the offset across the
    road of the opponent the sector reports relative to ours, ``(o_i − e) / (w / 2)`` (left positive), 0
    where none.  A 10° sector is 3.5 m wide at 20 m and 13 m at 75 m, so the distances alone cannot
    tell whether a car ahead holds our line or the next one, which decides where to overtake."""
    speed_scale: float = 300.0 / 3.6
    """Speed unit of the normalised observation (300 km/h)."""
    pedal_map: str = "clip"
    """'clip': pedal = max(a, 0); 'affine': pedal = (a + 1) / 2."""
    rank_weight: float = 2.0
    """The 2 of r_2 = 2 (n − rank) (Eq. 6.1)."""
    penalty: float = -10.0
    """Reward of a collision, out-of-track or backwards step."""
    penalty_mode: str = "replace"
    """'replace': a penalised step's reward is the penalty; 'add': r_1 + r_2 + penalty."""
    out_limit: int = 100
    """The episode ends when the out-of-track counter exceeds this."""
    slow_speed: float = 1.5
    """Speed along the axis below which a step counts as too slow (m/s, ≈ 5 km/h)."""
    slow_limit: int = 20
    """The episode ends after more than this many consecutive too-slow steps."""
    end_on_collision: bool = False
    """End the episode at a collision (the thesis's training only penalises it)."""

    def validate(self) -> None:
        check_choice("road", self.road, ROAD_CHOICES)
        _check_int("road_bank", self.road_bank, 1, 4096)
        _check_int("road_seed", self.road_seed, 0)
        _check_int("track_points", self.track_points, 64, 1 << 16)
        check_range("dt", self.dt, 0.0, 1.0, lo_open=True)
        for name in ("n_substeps", "max_steps", "laps"):
            _check_int(name, getattr(self, name), 1)
        _check_int("n_opponents", self.n_opponents, 0, 19)
        check_range("start_speed", self.start_speed, 0.0, 80.0)
        if not self.opponent_lanes:
            raise ConfigError("opponent_lanes must name at least one lane")
        check_vector("opponent_lanes", self.opponent_lanes, len(self.opponent_lanes), -0.8, 0.8)
        for name, lo, hi in (
            ("opponent_speed_factor", 0.05, 1.0),
            ("opponent_top_speed", 1.0, 100.0),
            ("opponent_gap", 6.0, 500.0),
        ):
            value = getattr(self, name)
            check_vector(name, value, 2, lo, hi)
            if value[0] > value[1]:
                raise ConfigError(f"{name}={value!r} must be (low, high) with low <= high")
        for name in (
            "opponent_accel",
            "opponent_decel",
            "mass",
            "yaw_inertia",
            "l_front",
            "l_rear",
            "car_length",
            "car_width",
            "steer_lock",
            "power",
            "mu",
            "tyre_b",
            "tyre_c",
            "max_range",
            "speed_scale",
        ):
            check_range(name, getattr(self, name), 0.0, lo_open=True)
        for name in ("brake_force", "drag", "rolling", "runoff", "damage_gain", "rank_weight", "slow_speed"):
            check_range(name, getattr(self, name), 0.0)
        check_range("brake_bias", self.brake_bias, 0.0, 1.0)
        check_range("offroad_grip", self.offroad_grip, 0.05, 1.0)
        check_range("rear_grip", self.rear_grip, 0.5, 2.0)
        check_range("traction", self.traction, 0.0, 1.0, lo_open=True)
        check_vector("profile_grip", self.profile_grip, 2, 0.05, 1.0)
        check_range("steer_lock", self.steer_lock, 0.0, 1.2, lo_open=True)
        check_range("penalty", self.penalty, None, 0.0)
        check_vector("rangefinder_angles", self.rangefinder_angles, 19, -180.0, 180.0)
        check_choice("pedal_map", self.pedal_map, PEDAL_MAPS)
        check_choice("penalty_mode", self.penalty_mode, PENALTY_MODES)
        check_choice("distance_scale", self.distance_scale, DISTANCE_SCALES)
        _check_int("out_limit", self.out_limit, 0)
        _check_int("slow_limit", self.slow_limit, 0)


def _check_int(field: str, value: Any, lo: int, hi: int | None = None) -> None:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ConfigError(f"{field}={value!r} must be an integer >= {lo}")
    check_range(field, value, lo, hi)


@struct.dataclass
class Road:
    """A road as ``racecar`` drives it: ``track`` and its speed profile ``profile [M]`` (m/s)."""

    track: racetrack.Track
    profile: jax.Array


COUNTERS = ("damage", "collisions", "car_collisions", "wall_collisions", "out_count", "slow_count", "overtakes",
            "overtaken", "time")
"""The counters of :class:`RaceState`, zero at the start of an episode."""


@struct.dataclass
class RaceState:
    """``pipeline_state`` of ``racecar`` (unbatched; ``N = n_opponents``).

    Our car: ``pos [2]``, ``yaw []``, body-frame ``vel [3] = (v_x, v_y, r)``, nearest centre-line
    segment ``seg []`` (int32), arc length ``s []`` in ``[0, L)``, signed lateral offset
    ``lateral []`` (m), axis heading ``axis_heading []``, ``progress []`` (m driven along the
    axis since the start, unwrapped) from ``start_s []``; last applied ``controls [3] =
    (steer, accel, brake)``.  Opponents: ``opp_progress [N]`` (m along the axis from our start
    line, unwrapped), ``opp_offset [N]`` (m, left positive), ``opp_speed [N]``, ``opp_factor [N]``,
    ``opp_top [N]`` and ``opp_ahead [N]`` (1 where ahead of us after the last step).  Counters:
    ``damage``, ``collisions`` (steps with a collision; ``car_collisions`` / ``wall_collisions`` those with
    a contact of that kind), ``out_count``, ``slow_count``,
    ``overtakes``, ``overtaken``, ``time`` (s).  ``road []`` (int32): the index of the road driven
    in the env's bank (``road='random'``), 0 otherwise.
    """

    pos: jax.Array
    yaw: jax.Array
    vel: jax.Array
    seg: jax.Array
    s: jax.Array
    lateral: jax.Array
    axis_heading: jax.Array
    progress: jax.Array
    start_s: jax.Array
    controls: jax.Array
    opp_progress: jax.Array
    opp_offset: jax.Array
    opp_speed: jax.Array
    opp_factor: jax.Array
    opp_top: jax.Array
    opp_ahead: jax.Array
    damage: jax.Array
    collisions: jax.Array
    car_collisions: jax.Array
    wall_collisions: jax.Array
    out_count: jax.Array
    slow_count: jax.Array
    overtakes: jax.Array
    overtaken: jax.Array
    time: jax.Array
    road: jax.Array


def race_reward(
    theta: jax.Array,
    d: jax.Array,
    v_x: jax.Array,
    rank: jax.Array,
    n_cars: int,
    penalised: jax.Array,
    rank_weight: float = 2.0,
    penalty: float = -10.0,
    penalty_mode: str = "replace",
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Eq. 6.1 with the thesis's penalty.

    ``r_1 = v_x cos θ − v_x |sin θ| − v_x |d|`` (terms ``r_speed``, ``r_lateral``, ``r_offset``),
    ``r_2 = rank_weight (n − rank)`` (``r_rank``).  Where ``penalised`` (collision, out of track or
    backwards) the reward is ``penalty`` (``"replace"``) or ``r_1 + r_2 + penalty`` (``"add"``).

    Args:
      theta, d, v_x, rank, penalised: same-shaped arrays (``penalised`` 0/1 or bool).
    Returns:
      ``(reward, terms)``; ``terms`` holds ``r_speed``, ``r_lateral``, ``r_offset``, ``r_rank``
      and ``penalty`` (the penalty where applied, else 0).
    """
    terms = {
        "r_speed": v_x * jnp.cos(theta),
        "r_lateral": -v_x * jnp.abs(jnp.sin(theta)),
        "r_offset": -v_x * jnp.abs(d),
        "r_rank": rank_weight * (n_cars - jnp.asarray(rank, jnp.float32)),
    }
    base = terms["r_speed"] + terms["r_lateral"] + terms["r_offset"] + terms["r_rank"]
    hit = jnp.asarray(penalised) > 0
    terms["penalty"] = jnp.where(hit, jnp.float32(penalty), jnp.float32(0.0))
    if penalty_mode == "replace":
        reward = jnp.where(hit, penalty, base)
    else:
        reward = base + terms["penalty"]
    return reward, terms


def _rot(yaw: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Heading and left unit vectors ``[..., 2]`` of ``yaw``."""
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    return jnp.stack([c, s], -1), jnp.stack([-s, c], -1)


def _wrap_ds(x: jax.Array, length: float) -> jax.Array:
    """Arc-length difference wrapped to ``[−L/2, L/2)``."""
    return jnp.mod(x + 0.5 * length, length) - 0.5 * length


class RaceCar(RobotEnv):
    """Racing among scripted opponents; see the module docstring for dynamics, observation and reward."""

    name = "racecar"
    Config = RaceCarConfig
    action_size = 3
    evaluation_kind = "racing"
    """How a policy is evaluated on this env: laps on every road (:func:`make_lap_test`)."""

    @property
    def steps_mjx_physics(self) -> bool:
        """The car's dynamics and range finders are plain JAX (no MJX model)."""
        return False

    @property
    def observation_size(self) -> int:
        """60 (thesis §6.1.1), 36 more with each of ``opponent_speeds`` and ``opponent_offsets``."""
        return 60 + N_SECTORS * (int(self.config.opponent_speeds) + int(self.config.opponent_offsets))

    def __init__(self, config: RaceCarConfig | None = None, **overrides: Any):
        super().__init__(config, **overrides)
        cfg = self.config
        if cfg.road == "random":
            specs = [racetrack.random_road_spec(i, cfg.road_seed) for i in range(1, cfg.road_bank)]
            tracks = [racetrack.make_road("train", cfg.track_points)]
            tracks += [racetrack.make_spec_road(spec, cfg.track_points) for spec in specs]
        else:
            tracks = [racetrack.make_road(cfg.road, cfg.track_points)]
        roads = [Road(track=t, profile=self._speed_profile(t)) for t in tracks]
        self.track, self.speed_profile = roads[0].track, roads[0].profile
        self.bank: Road | None = jax.tree.map(lambda *x: jnp.stack(x), *roads) if len(roads) > 1 else None
        self._angles = jnp.deg2rad(jnp.asarray(cfg.rangefinder_angles, jnp.float32))
        # 15 % slack: the window (in samples) also serves roads of this sample count sampled more densely
        windows = [racetrack.ray_window(t, 45.0, 1.15 * (cfg.max_range + 60.0)) for t in tracks]
        self._ray_window = (max(w[0] for w in windows), max(w[1] for w in windows))
        if sum(self._ray_window) >= cfg.track_points:
            self._ray_window = (0, cfg.track_points)

    def _speed_profile(self, track: racetrack.Track) -> jax.Array:
        """Speed profile ``[M]`` of ``track`` (m/s): for the tightest line a car may take, the axis
        curvature at the inner edge, with the lateral and braking accelerations of ``profile_grip``."""
        cfg = self.config
        a_lat, a_brake = (f * cfg.mu * GRAVITY for f in cfg.profile_grip)
        kappa = np.abs(np.asarray(track.curvature, np.float64))
        inner = kappa / np.maximum(1.0 - kappa * (float(track.half_width) - 1.0), 0.3)
        return jnp.asarray(racetrack.speed_profile(track.replace(curvature=jnp.asarray(inner)), a_lat, a_brake, 80.0))

    # ------------------------------------------------------------------ roads
    @property
    def road(self) -> Road:
        """This env's road: the track and its speed profile (a pytree); with ``road='random'`` the bank's
        first road ('train')."""
        return Road(track=self.track, profile=self.speed_profile)

    @property
    def n_roads(self) -> int:
        """Roads an episode may drive: ``road_bank`` with ``road='random'``, else 1."""
        return 1 if self.bank is None else int(self.bank.profile.shape[0])

    def bank_road(self, index: jax.Array | int) -> Road:
        """Road ``index`` of the bank (``index`` may be traced); the env's road without a bank."""
        if self.bank is None:
            return self.road
        return jax.tree.map(lambda x: x[index], self.bank)

    def on_road(self, road: Road) -> RaceCar:
        """This env driving on ``road`` alone (same sample count; its arrays may be traced).

        One compiled function then serves every road, and roads stacked along a leading axis can
        be vmapped: ``jax.vmap(lambda r, k: run(env.on_road(r), k))(stacked_roads, keys)``.
        """
        env = copy.copy(self)
        env.track, env.speed_profile, env.bank = road.track, road.profile, None
        return env

    def driving(self, state: State | RaceState) -> RaceCar:
        """The single-road env of the road that ``state`` (or its ``RaceState``) drives; ``self``
        without a bank.  Its sensors, observation and expert read that road."""
        if self.bank is None:
            return self
        rs = state.pipeline_state if isinstance(state, State) else state
        return self.on_road(self.bank_road(rs.road))

    # ----------------------------------------------------------------- sizes
    @property
    def action_scale(self) -> jax.Array:
        """Ones: actions are the steering command and the pedal commands of the module docstring."""
        return jnp.ones(3, jnp.float32)

    @property
    def backend(self) -> str:
        return "jax"

    @property
    def n_cars(self) -> int:
        return self.config.n_opponents + 1

    # ---------------------------------------------------------------- actions
    def controls(self, action: jax.Array) -> jax.Array:
        """``(steer ∈ [−1, 1], accel ∈ [0, 1], brake ∈ [0, 1])`` from a clean action ``[3]`` in [−1, 1]."""
        if self.config.pedal_map == "clip":
            pedals = jnp.maximum(action[1:], 0.0)
        else:
            pedals = 0.5 * (action[1:] + 1.0)
        return jnp.concatenate([action[:1], pedals])

    def action_from_controls(self, steer: jax.Array, accel: jax.Array, brake: jax.Array) -> jax.Array:
        """The action ``[3]`` that :meth:`controls` maps to ``(steer, accel, brake)``."""
        pedals = jnp.stack([accel, brake])
        if self.config.pedal_map == "affine":
            pedals = 2.0 * pedals - 1.0
        return jnp.concatenate([jnp.reshape(steer, (1,)), pedals]).astype(jnp.float32)

    # ------------------------------------------------------------ road helpers
    def profile_at(self, s: jax.Array) -> jax.Array:
        """Speed profile (m/s) at arc length ``s`` (any shape), linear between samples."""
        u = jnp.mod(s, self.track.length) / self.track.ds
        i = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, self.track.n - 1)
        f = u - i
        return (1.0 - f) * self.speed_profile[i] + f * self.speed_profile[(i + 1) % self.track.n]

    def opponent_poses(self, rs: RaceState) -> tuple[jax.Array, jax.Array, jax.Array]:
        """World positions ``[N, 2]``, headings ``[N]`` and velocities ``[N, 2]`` of the opponents."""
        c, t, n = racetrack.point_at(self.track, rs.start_s + rs.opp_progress)
        pos = c + rs.opp_offset[:, None] * n
        return pos, jnp.arctan2(t[:, 1], t[:, 0]), rs.opp_speed[:, None] * t

    def rank(self, rs: RaceState) -> jax.Array:
        """1 + the number of opponents further along than us (unwrapped progress)."""
        return 1.0 + jnp.sum((rs.opp_progress > rs.progress).astype(jnp.float32))

    def expert(self, state: State) -> jax.Array:
        """The scripted driver's action ``[3]`` for ``state`` (:func:`expert_action`) on the road it
        drives: the teacher of the imitation stage (thesis §6.1.2; ``jaxrl_robot.imitation.expert_of``)."""
        return expert_action(self.driving(state), state)

    # --------------------------------------------------------------- sensors
    def sensors(self, rs: RaceState) -> dict[str, jax.Array]:
        """Raw sensor readings: ``angle``, ``tracks [19]``, ``track_pos``, ``speed [3]``, ``opponents [36]``."""
        cfg = self.config
        theta = racetrack.wrap_angle(rs.yaw - rs.axis_heading)
        d = rs.lateral / self.track.half_width
        out = jnp.abs(d) > 1.0
        tracks = racetrack.range_finders(
            self.track, rs.pos, rs.yaw, rs.seg, self._angles, cfg.max_range, self._ray_window
        )
        tracks = jnp.where(out, -1.0, tracks)
        opp_pos, _, opp_vel = self.opponent_poses(rs)
        rel = opp_pos - rs.pos
        dist = jnp.linalg.norm(rel, axis=-1)
        bearing = racetrack.wrap_angle(jnp.arctan2(rel[:, 1], rel[:, 0]) - rs.yaw)
        sector = jnp.clip(jnp.floor((bearing + jnp.pi) / (2 * jnp.pi / N_SECTORS)).astype(jnp.int32), 0, N_SECTORS - 1)
        in_sector = sector[None, :] == jnp.arange(N_SECTORS)[:, None]  # [36, N]
        masked = jnp.where(in_sector, dist[None, :], jnp.inf)
        opponents = jnp.minimum(jnp.min(masked, axis=1, initial=jnp.inf), cfg.max_range)
        speed = jnp.stack([rs.vel[0], rs.vel[1], jnp.zeros_like(rs.vel[0])])
        out = {"angle": theta, "tracks": tracks, "track_pos": d, "speed": speed, "opponents": opponents}
        nearest = jnp.argmin(masked, axis=1)  # [36] the opponent each sector reports
        seen = jnp.any(in_sector, axis=1) & (opponents < cfg.max_range)
        if cfg.opponent_speeds:
            fwd, left = _rot(rs.yaw)
            v_rel = (rs.vel[0] * fwd + rs.vel[1] * left)[None, :] - opp_vel  # [N, 2] our velocity relative to theirs
            closing = jnp.sum(v_rel * rel, axis=-1) / jnp.maximum(dist, 1e-3)  # [N] > 0: we approach
            out["opponent_speeds"] = jnp.where(seen, closing[nearest], 0.0)
        if cfg.opponent_offsets:
            out["opponent_offsets"] = jnp.where(seen, (rs.opp_offset - rs.lateral)[nearest], 0.0)
        return out

    def observe(self, rs: RaceState) -> jax.Array:
        """The 60-dim observation ``[θ, tracks (19), d, v_x, v_y, v_z, opponents (36)]``."""
        cfg = self.config
        sen = self.sensors(rs)
        tracks, opponents, speed = sen["tracks"], sen["opponents"], sen["speed"]
        if cfg.normalize_obs:
            if cfg.distance_scale == "log":
                scale = lambda d: jnp.log1p(jnp.maximum(d, 0.0)) / np.log1p(cfg.max_range)  # noqa: E731
            else:
                scale = lambda d: d / cfg.max_range  # noqa: E731
            tracks = jnp.where(tracks < 0.0, -1.0, scale(tracks))
            opponents = scale(opponents)
            speed = speed / cfg.speed_scale
        parts = [sen["angle"][None], tracks, sen["track_pos"][None], speed, opponents]
        if cfg.opponent_speeds:
            closing = sen["opponent_speeds"]
            parts.append(closing / cfg.speed_scale if cfg.normalize_obs else closing)
        if cfg.opponent_offsets:
            offsets = sen["opponent_offsets"]
            parts.append(offsets / self.track.half_width if cfg.normalize_obs else offsets)
        return jnp.concatenate(parts)

    # ---------------------------------------------------------------- physics
    def _forces(self, vel: jax.Array, controls: jax.Array, grip: jax.Array) -> jax.Array:
        """Body-frame accelerations ``(v̇_x, v̇_y, ṙ)`` of the dynamic bicycle model (module docstring)."""
        cfg = self.config
        vx, vy, r = vel[0], vel[1], vel[2]
        delta = cfg.steer_lock * controls[0]
        wheelbase = cfg.l_front + cfg.l_rear
        mu = cfg.mu * grip
        dzf = mu * cfg.mass * GRAVITY * cfg.l_rear / wheelbase
        dzr = cfg.rear_grip * mu * cfg.mass * GRAVITY * cfg.l_front / wheelbase
        moving = jnp.tanh(vx / 0.5)
        drive = controls[1] * jnp.minimum(cfg.traction * dzr, cfg.power / jnp.maximum(vx, 1.0))
        brake = controls[2] * cfg.brake_force
        fxf = -jnp.minimum(cfg.brake_bias * brake, dzf) * moving
        fxr = jnp.clip(drive - (1.0 - cfg.brake_bias) * brake * moving, -dzr, dzr)
        resist = (cfg.drag * vx * jnp.abs(vx)) + cfg.rolling * cfg.mass * GRAVITY * moving
        dyf = jnp.sqrt(jnp.maximum(dzf**2 - fxf**2, (0.1 * dzf) ** 2))
        dyr = jnp.sqrt(jnp.maximum(dzr**2 - fxr**2, (0.1 * dzr) ** 2))
        vbar = jnp.maximum(vx, 3.0)
        alpha_f = jnp.arctan2(vy + cfg.l_front * r, vbar) - delta
        alpha_r = jnp.arctan2(vy - cfg.l_rear * r, vbar)
        fyf = -dyf * jnp.sin(cfg.tyre_c * jnp.arctan(cfg.tyre_b * alpha_f))
        fyr = -dyr * jnp.sin(cfg.tyre_c * jnp.arctan(cfg.tyre_b * alpha_r))
        cd, sd = jnp.cos(delta), jnp.sin(delta)
        # the front tyre's drag in a turn vanishes at standstill (it must not drive the car backwards)
        ax = (fxr + fxf * cd - fyf * sd * moving - resist) / cfg.mass + vy * r
        ay = (fyr + fyf * cd + fxf * sd) / cfg.mass - vx * r
        ar = (cfg.l_front * (fyf * cd + fxf * sd) - cfg.l_rear * fyr) / cfg.yaw_inertia
        return jnp.stack([ax, ay, ar])

    def _vehicle_step(self, rs: RaceState, controls: jax.Array, h: float) -> RaceState:
        """One semi-implicit Euler step of length ``h`` of our car (no contacts)."""
        cfg = self.config
        grip = jnp.where(jnp.abs(rs.lateral) > self.track.half_width, cfg.offroad_grip, 1.0)
        vel = rs.vel + h * self._forces(rs.vel, controls, grip)
        wheelbase = cfg.l_front + cfg.l_rear
        r_kin = vel[0] * jnp.tan(cfg.steer_lock * controls[0]) / wheelbase
        w = jnp.clip((vel[0] - 2.0) / 3.0, 0.0, 1.0)
        vel = jnp.stack([vel[0], w * vel[1] + (1.0 - w) * cfg.l_rear * r_kin, w * vel[2] + (1.0 - w) * r_kin])
        fwd, left = _rot(rs.yaw)
        pos = rs.pos + h * (vel[0] * fwd + vel[1] * left)
        return rs.replace(pos=pos, yaw=rs.yaw + h * vel[2], vel=vel)

    def _contacts(self, rs: RaceState) -> tuple[RaceState, jax.Array]:
        """Walls and opponents: move our car out, drop its velocity into them; returns the damage added
        ``[2]`` by the walls and by the opponents."""
        cfg = self.config
        hl, hw = 0.5 * cfg.car_length, 0.5 * cfg.car_width
        fwd, left = _rot(rs.yaw)
        v_world = rs.vel[0] * fwd + rs.vel[1] * left

        # wall: |lateral| + half extent across the road must stay within half width + runoff
        theta = rs.yaw - rs.axis_heading
        extent = hw * jnp.abs(jnp.cos(theta)) + hl * jnp.abs(jnp.sin(theta))
        excess = jnp.abs(rs.lateral) + extent - (self.track.half_width + cfg.runoff)
        side = jnp.sign(rs.lateral)
        n_wall = side * jnp.stack([-jnp.sin(rs.axis_heading), jnp.cos(rs.axis_heading)])  # outward
        wall = excess > 0.0
        v_out = jnp.maximum(jnp.dot(v_world, n_wall), 0.0)
        pos = rs.pos - jnp.where(wall, excess, 0.0) * n_wall
        v_world = v_world - jnp.where(wall, v_out, 0.0) * n_wall
        wall_damage = jnp.where(wall, cfg.damage_gain * (1.0 + v_out), 0.0)

        # opponents: separating-axis test of two rectangles, vectorised over the N opponents
        opp_pos, opp_yaw, opp_vel = self.opponent_poses(rs)
        o_fwd, o_left = _rot(opp_yaw)  # [N, 2]
        axes = jnp.stack([jnp.broadcast_to(fwd, o_fwd.shape), jnp.broadcast_to(left, o_fwd.shape), o_fwd, o_left], 1)
        delta = pos - opp_pos  # [N, 2]
        along = jnp.einsum("nkj,nj->nk", axes, delta)  # [N, 4]
        r_us = hl * jnp.abs(axes @ fwd) + hw * jnp.abs(axes @ left)
        r_them = hl * jnp.abs(jnp.einsum("nkj,nj->nk", axes, o_fwd))
        r_them = r_them + hw * jnp.abs(jnp.einsum("nkj,nj->nk", axes, o_left))
        overlap = r_us + r_them - jnp.abs(along)
        hit = jnp.all(overlap > 0.0, axis=1)  # [N]
        k = jnp.argmin(overlap, axis=1)
        depth = jnp.take_along_axis(overlap, k[:, None], 1)[:, 0]
        sign = jnp.where(jnp.take_along_axis(along, k[:, None], 1)[:, 0] >= 0.0, 1.0, -1.0)
        normal = sign[:, None] * jnp.take_along_axis(axes, k[:, None, None], 1)[:, 0]  # [N, 2], towards us
        pos = pos + jnp.sum(jnp.where(hit, depth, 0.0)[:, None] * normal, axis=0)
        closing = jnp.minimum(jnp.sum((v_world - opp_vel) * normal, axis=1), 0.0)  # [N], ≤ 0
        v_world = v_world - jnp.sum(jnp.where(hit, closing, 0.0)[:, None] * normal, axis=0)
        car_damage = jnp.sum(jnp.where(hit, cfg.damage_gain * (1.0 - closing), 0.0))

        vel = jnp.stack([jnp.dot(v_world, fwd), jnp.dot(v_world, left), rs.vel[2]])
        return rs.replace(pos=pos, vel=vel), jnp.stack([wall_damage, car_damage])

    def _locate(self, rs: RaceState) -> RaceState:
        """Update the projection on the axis and the unwrapped progress."""
        proj = racetrack.project(self.track, rs.pos, rs.seg)
        progress = rs.progress + _wrap_ds(proj.s - rs.s, self.track.length)
        return rs.replace(seg=proj.seg, s=proj.s, lateral=proj.lateral, axis_heading=proj.heading, progress=progress)

    def _opponent_speeds(self, rs: RaceState) -> jax.Array:
        """Speeds ``[N]`` for the next control step: the target, car-following, acceleration limits."""
        cfg = self.config
        length = self.track.length
        target = jnp.minimum(rs.opp_top, rs.opp_factor * self.profile_at(rs.start_s + rs.opp_progress))
        our_speed = rs.vel[0] * jnp.cos(rs.yaw - rs.axis_heading)
        prog = jnp.concatenate([rs.opp_progress, rs.progress[None]])
        offset = jnp.concatenate([rs.opp_offset, rs.lateral[None]])
        speed = jnp.concatenate([rs.opp_speed, our_speed[None]])
        gap = _wrap_ds(prog[None, :] - rs.opp_progress[:, None], length) - cfg.car_length  # [N, N+1]
        ahead = _wrap_ds(prog[None, :] - rs.opp_progress[:, None], length) > 0.0
        same_lane = jnp.abs(offset[None, :] - rs.opp_offset[:, None]) < cfg.car_width + 0.6
        lead = ahead & same_lane & (gap < 80.0)
        follow = jnp.maximum(speed[None, :] + (gap - 4.0) / 2.0, 0.0)
        cap = jnp.min(jnp.where(lead, follow, jnp.inf), axis=1, initial=jnp.inf)
        want = jnp.minimum(target, cap)
        dv = jnp.clip(want - rs.opp_speed, -cfg.opponent_decel * cfg.dt, cfg.opponent_accel * cfg.dt)
        return jnp.maximum(rs.opp_speed + dv, 0.0)

    # -------------------------------------------------------------------- api
    def default_params(self) -> dict[str, jax.Array]:
        return {}

    def reset(self, rng: jax.Array, params: Mapping[str, jax.Array] | None = None) -> State:
        """Our car at rest (``start_speed``) on the axis, the opponents on their lines ahead of it;
        with a bank (``road='random'``) on a road drawn uniformly from it."""
        if self.bank is None:
            return self._reset_on_road(rng, params, jnp.zeros((), jnp.int32))
        k_road, rng = jax.random.split(rng)
        index = jax.random.randint(k_road, (), 0, self.n_roads, dtype=jnp.int32)
        return self.on_road(self.bank_road(index))._reset_on_road(rng, params, index)

    def _reset_on_road(self, rng: jax.Array, params: Mapping[str, jax.Array] | None, road: jax.Array) -> State:
        cfg = self.config
        n = cfg.n_opponents
        k_start, k_gap, k_lane, k_factor, k_top = jax.random.split(rng, 5)
        s0 = jax.random.uniform(k_start, (), maxval=self.track.length) if cfg.random_start else jnp.zeros(())
        s0 = jnp.asarray(s0, jnp.float32)
        pos0 = racetrack.point_at(self.track, s0)[0]
        proj = racetrack.project(self.track, pos0, (s0 / self.track.ds).astype(jnp.int32))

        def draw(key, bounds):
            return jax.random.uniform(key, (n,), minval=bounds[0], maxval=bounds[1])

        gaps = draw(k_gap, cfg.opponent_gap)
        lane = jax.random.randint(k_lane, (n,), 0, len(cfg.opponent_lanes))
        lanes = jnp.asarray(cfg.opponent_lanes, jnp.float32)[lane]
        factor = draw(k_factor, cfg.opponent_speed_factor)
        top = draw(k_top, cfg.opponent_top_speed)
        opp_progress = jnp.cumsum(gaps)
        zero = jnp.zeros((), jnp.float32)
        rs = RaceState(
            pos=pos0,
            yaw=proj.heading,
            vel=jnp.array([cfg.start_speed, 0.0, 0.0], jnp.float32),
            seg=proj.seg,
            s=proj.s,
            lateral=proj.lateral,
            axis_heading=proj.heading,
            progress=zero,
            start_s=s0,
            controls=jnp.zeros(3, jnp.float32),
            opp_progress=opp_progress,
            opp_offset=lanes * self.track.half_width,
            opp_speed=jnp.minimum(top, factor * self.profile_at(s0 + opp_progress)),
            opp_factor=factor,
            opp_top=top,
            opp_ahead=jnp.ones((n,), jnp.float32),
            **dict.fromkeys(COUNTERS, zero),
            road=road,
        )
        metrics = {name: zero for name in METRIC_NAMES}
        metrics.update(rank=self.rank(rs))
        return State(
            pipeline_state=rs,
            obs=self.observe(rs),
            reward=zero,
            done=zero,
            metrics=metrics,
            info={"params": dict(self.default_params() if params is None else params)},
        )

    def step(self, state: State, action: jax.Array) -> State:
        """One control step of ``dt`` with ``action [3]`` in [−1, 1] (unbatched), on the state's road."""
        self.check_action(action)
        if self.bank is not None:
            return self.driving(state).step(state, action)
        cfg = self.config
        a, invalid = sanitize_action(action)
        controls = self.controls(a)
        rs0: RaceState = state.pipeline_state
        rs = rs0.replace(opp_speed=self._opponent_speeds(rs0), controls=controls)
        h = cfg.dt / cfg.n_substeps

        def substep(_, carry):
            rs, damage = carry
            rs = self._vehicle_step(rs, controls, h)
            rs = rs.replace(opp_progress=rs.opp_progress + h * rs.opp_speed)
            rs = self._locate(rs)
            rs, hit = self._contacts(rs)
            return rs, damage + hit

        rs, damages = jax.lax.fori_loop(0, cfg.n_substeps, substep, (rs, jnp.zeros(2, jnp.float32)))
        damage = jnp.sum(damages)
        rs = self._locate(rs)

        sen = self.sensors(rs)
        theta, d, vx = sen["angle"], sen["track_pos"], rs.vel[0]
        collision = (damage > 0.0).astype(jnp.float32)
        out = (jnp.min(sen["tracks"]) < 0.0).astype(jnp.float32)
        backwards = (jnp.cos(theta) < 0.0).astype(jnp.float32)
        slow = vx * jnp.cos(theta) < cfg.slow_speed
        slow_count = jnp.where(slow, rs.slow_count + 1.0, 0.0)
        out_count = rs.out_count + out
        ahead = (rs.opp_progress > rs.progress).astype(jnp.float32)
        rank = 1.0 + jnp.sum(ahead)
        overtakes = rs.overtakes + jnp.sum(rs.opp_ahead * (1.0 - ahead))
        overtaken = rs.overtaken + jnp.sum((1.0 - rs.opp_ahead) * ahead)
        success = (rs.progress >= cfg.laps * self.track.length).astype(jnp.float32)
        too_slow = (slow_count > cfg.slow_limit).astype(jnp.float32)
        out_limit = (out_count > cfg.out_limit).astype(jnp.float32)
        penalised = jnp.maximum(jnp.maximum(collision, out), backwards)
        reward, terms = race_reward(
            theta, d, vx, rank, self.n_cars, penalised, cfg.rank_weight, cfg.penalty, cfg.penalty_mode
        )
        events = {"success": success, "collision": collision, "out_of_track": out, "backwards": backwards,
                  "too_slow": too_slow, "out_limit": out_limit}  # fmt: skip
        ending = ("success", "backwards", "too_slow", "out_limit") + (("collision",) if cfg.end_on_collision else ())
        done = jnp.max(jnp.stack([events[k] for k in ending]))
        counts = {  # the episode's running counts: kept in the state and reported as metrics
            "damage": rs.damage + damage,
            "collisions": rs.collisions + collision,
            "car_collisions": rs.car_collisions + (damages[1] > 0.0),
            "wall_collisions": rs.wall_collisions + (damages[0] > 0.0),
            "out_count": out_count,
            "overtakes": overtakes,
            "overtaken": overtaken,
            "time": rs.time + cfg.dt,
        }
        rs = rs.replace(opp_ahead=ahead, slow_count=slow_count, **counts)
        metrics = {**state.metrics, **terms, **events, **counts, "rank": rank, "progress": rs.progress, "speed": vx,
                   "invalid_action": invalid}  # fmt: skip
        obs = self.observe(rs)
        return state.replace(pipeline_state=rs, obs=obs, reward=reward, done=done, metrics=metrics)


METRIC_NAMES = (
    "r_speed",
    "r_lateral",
    "r_offset",
    "r_rank",
    "penalty",
    "success",
    "collision",
    "out_of_track",
    "backwards",
    "too_slow",
    "out_limit",
    "damage",
    "collisions",
    "car_collisions",
    "wall_collisions",
    "out_count",
    "overtakes",
    "overtaken",
    "rank",
    "progress",
    "speed",
    "time",
    "invalid_action",
)
"""Keys of ``state.metrics`` (every one a float32 scalar per lane)."""


def _curvature_at(track: racetrack.Track, s: jax.Array) -> jax.Array:
    """Signed axis curvature at arc length ``s``, linear between samples."""
    u = jnp.mod(s, track.length) / track.ds
    i = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, track.n - 1)
    f = u - i
    return (1.0 - f) * track.curvature[i] + f * track.curvature[(i + 1) % track.n]


def expert_action(env: RaceCar, state: State) -> jax.Array:
    """The scripted driver's action ``[3]`` for ``state`` (unbatched; pure, jit/vmap-able).

    Reads the privileged ``state.pipeline_state`` (the thesis's imitation stage, §6.1.2, used TORCS's
    example driver).  Three parts, ``v`` our forward speed, ``e`` our offset from the axis:

    * **Line choice.**  Candidate offsets: the axis and ``o_i ± (car_width + 1.3)`` beside every
      opponent ``i``, kept ``car_width / 2 + 0.6`` m inside the edges.  An opponent between
      ``car_length + 3`` m behind and ``15 + 2v`` m ahead (and not ahead and faster) blocks the
      candidates within ``car_width + 1.2`` of its line, and — while it is alongside or will be
      reached within 2.5 s — those on its other side (no cutting across a car).  The free
      candidate of least ``|c − e| + 0.3 |c|`` wins: overtaking on the free side, back to the
      axis after; with none free the car holds its offset and follows.
    * **Steering.**  On the course angle ``χ`` (heading plus side-slip, relative to the axis) the
      wanted course is ``χ* = −atan((e − c) / (1.2 v̄))`` (clipped to ±0.25 rad, ``v̄ = max(v, 5)``);
      the wanted yaw rate ``r* = v κ(s + 0.2 v) + (χ* − χ) / 0.3 s``, the correction bounded by
      ``0.4 μ g / v̄``; ``δ = atan(L r* / v̄) + 0.2 (r* − r)``, ``L`` the wheelbase (the yaw-rate
      feedback holds the line when braking in a corner costs the front tyres grip).
    * **Speed.**  The road's speed profile ``0.5 v`` metres ahead, capped at ``v_i + (gap − 6 m) /
      1.5 s`` behind any car ahead whose line lies within ``car_width + 1`` of the band between
      ``e`` and ``c``; throttle ``0.5 (v* − v)``, brake ``0.3 (v − v* − 0.5)``, each capped by the
      grip left after cornering, ``sqrt(1 − (v r / 0.85 μ g)²)`` (brake at least 0.3).

    Over 2400 laps (300 per road with each of two test keys, random starts and opponents) it
    finished every lap, never left the road, and touched another car in 4 laps (3 on ``test2``);
    with a yaw-rate feedback of 0.1 instead of 0.2 it touched one in 22 of the 600 laps on ``test2``.
    """
    cfg = env.config
    track = env.track
    rs: RaceState = state.pipeline_state
    v = jnp.maximum(rs.vel[0], 0.0)
    hw_road = track.half_width
    limit = hw_road - 0.5 * cfg.car_width - 0.6

    # line choice
    ds = _wrap_ds(rs.opp_progress - rs.progress, track.length)  # [N], > 0 ahead
    horizon = 15.0 + 2.0 * v
    near = (ds > -(cfg.car_length + 3.0)) & (ds < horizon)
    faster_ahead = (ds > cfg.car_length + 2.0) & (rs.opp_speed > v + 1.0)
    relevant = near & ~faster_ahead
    clear = cfg.car_width + 1.3
    cands = jnp.concatenate([jnp.zeros(1), rs.opp_offset - clear, rs.opp_offset + clear])
    cands = jnp.clip(cands, -limit, limit)
    side = cands[:, None] - rs.opp_offset[None, :]  # [C, N]
    overlap = jnp.abs(side) < cfg.car_width + 1.2
    # a car alongside cannot be crossed: stay on our side of it
    reach = cfg.car_length + 4.0 + 2.5 * jnp.maximum(v - rs.opp_speed, 0.0)
    alongside = (ds > -(cfg.car_length + 3.0)) & (ds < reach)
    crossing = alongside[None, :] & (jnp.sign(side) != jnp.sign(rs.lateral - rs.opp_offset)[None, :])
    beside_or_ahead = ds > -(cfg.car_length + 0.5)  # a car behind us does not block moving across its line
    blocked = jnp.any(relevant[None, :] & ((overlap & beside_or_ahead[None, :]) | crossing), axis=1)
    cost = jnp.abs(cands - rs.lateral) + 0.3 * jnp.abs(cands) + 1e3 * blocked
    best = jnp.argmin(cost)
    free = ~blocked[best]
    edge = hw_road - 0.5 * cfg.car_width - 0.2
    target = jnp.where(free, cands[best], jnp.clip(rs.lateral, -edge, edge))

    # steering: approach the line at a heading set by the offset error, turn at a bounded yaw rate
    vbar = jnp.maximum(v, 5.0)
    kappa = _curvature_at(track, rs.s + 0.2 * v)
    # course (direction of travel) relative to the axis: a sliding car drifts along its velocity
    theta = racetrack.wrap_angle(rs.yaw - rs.axis_heading + jnp.arctan2(rs.vel[1], jnp.maximum(rs.vel[0], 1.0)))
    theta_des = -jnp.clip(jnp.arctan((rs.lateral - target) / (vbar * 1.2)), -0.25, 0.25)
    turn = jnp.clip((theta_des - theta) / 0.3, -0.4 * cfg.mu * GRAVITY / vbar, 0.4 * cfg.mu * GRAVITY / vbar)
    r_des = v * kappa + turn
    wheelbase = cfg.l_front + cfg.l_rear
    delta = jnp.arctan(wheelbase * r_des / vbar) + 0.2 * (r_des - rs.vel[2])
    steer = jnp.clip(delta / cfg.steer_lock, -1.0, 1.0)

    # speed
    v_star = env.profile_at(rs.s + 0.5 * v)
    # cars anywhere across the band we sweep on the way to the line
    lo, hi = jnp.minimum(rs.lateral, target), jnp.maximum(rs.lateral, target)
    in_lane = (rs.opp_offset > lo - cfg.car_width - 1.0) & (rs.opp_offset < hi + cfg.car_width + 1.0)
    lead = (ds > 0.0) & (ds < horizon + 20.0) & in_lane
    gap = ds - cfg.car_length
    follow = jnp.maximum(rs.opp_speed + (gap - 6.0) / 1.5, 0.0)
    v_star = jnp.minimum(v_star, jnp.min(jnp.where(lead, follow, jnp.inf), initial=jnp.inf))
    grip = jnp.abs(v * rs.vel[2]) / (0.85 * cfg.mu * GRAVITY)  # lateral acceleration used, of the tyres' limit
    budget = jnp.sqrt(jnp.maximum(1.0 - grip**2, 0.0))
    accel = jnp.clip(0.5 * (v_star - v), 0.0, budget)
    brake = jnp.clip(0.3 * (v - v_star - 0.5), 0.0, jnp.maximum(budget, 0.3))
    return env.action_from_controls(steer, accel, brake)


CONTACTS = ("car_contact", "wall_contact")
"""What a test lap's collisions touched (both may be 1; either implies the outcome ``collision``)."""

LAP_OUTCOMES = ("success", "collision", "out_of_track", "stalled")
"""How a test lap ends (thesis Tables 6.2–6.3): a collision (with a car or a wall) at any point;
else out of the track at any point; else ``success`` if the lap was finished; else ``stalled``
(too slow, backwards on the road, or the time limit)."""


def make_lap_test(
    env: RaceCar, laps: int = 20, roads: tuple[str, ...] = tuple(racetrack.ROADS)
) -> Callable[[Callable[[RaceCar, State], jax.Array], jax.Array], dict[str, jax.Array]]:
    """``test(act, key)``: ``laps`` one-lap episodes on each of ``roads`` driven by ``act(env, state) -> action [3]``.

    Every road is ``env``'s configuration with that road (one lap per episode, random start and
    opponents from ``key`` as ``env.reset`` draws them); all roads and laps run as one vmapped
    program until every episode has ended.  ``act`` gets the env of the road being driven and the
    state; a policy reads the observation (``lambda e, s: policy(s.obs)``), the expert the road and
    the whole state (``expert_action``).  ``test`` is pure and
    jit-able (the roads are built here, outside any trace).

    ``test`` returns ``[R, laps]`` arrays: one 0/1 entry per outcome of :data:`LAP_OUTCOMES`,
    ``car_contact`` / ``wall_contact`` (0/1: the lap touched another car / a wall),
    ``overtakes``, ``overtaken``, ``rank`` (final), ``speed`` (mean speed along the axis, m/s),
    ``time`` (s) and ``progress`` (m).
    """
    cfg = dataclasses.replace(env.config, laps=1)
    envs = [RaceCar(dataclasses.replace(cfg, road=name)) for name in roads]
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *[e.road for e in envs])
    driver = envs[0]
    limit = cfg.max_steps

    def road_laps(road: Road, keys: jax.Array, act: Callable[[RaceCar, State], jax.Array]) -> dict[str, jax.Array]:
        e = driver.on_road(road)
        s = jax.vmap(e.reset)(keys)

        def body(c):
            s, done, t = c
            n = jax.vmap(lambda st: e.step(st, act(e, st)))(s)
            n = jax.tree.map(lambda a, b: jnp.where(done.reshape(done.shape + (1,) * (a.ndim - 1)), a, b), s, n)
            return n, done | (n.done > 0), t + 1

        s, _, _ = jax.lax.while_loop(lambda c: (c[2] < limit) & ~jnp.all(c[1]), body, (s, jnp.zeros(laps, bool), 0))
        m, rs = s.metrics, s.pipeline_state
        collision = (rs.collisions > 0).astype(jnp.float32)
        out = (1.0 - collision) * (rs.out_count > 0)
        success = (1.0 - collision) * (1.0 - out) * m["success"]
        time = jnp.maximum(rs.time, cfg.dt)
        return {"success": success, "collision": collision, "out_of_track": out,
                "stalled": 1.0 - collision - out - success, "car_contact": (rs.car_collisions > 0).astype(jnp.float32),
                "wall_contact": (rs.wall_collisions > 0).astype(jnp.float32),
                "overtakes": rs.overtakes, "overtaken": rs.overtaken,
                "rank": m["rank"], "speed": rs.progress / time, "time": rs.time, "progress": rs.progress}  # fmt: skip

    def test(act: Callable[[RaceCar, State], jax.Array], key: jax.Array) -> dict[str, jax.Array]:
        keys = jax.random.split(key, len(roads) * laps).reshape(len(roads), laps, -1)
        return jax.vmap(lambda road, k: road_laps(road, k, act))(stacked, keys)

    return test


def lap_summary(result: Mapping[str, Any], roads: tuple[str, ...] = tuple(racetrack.ROADS)) -> dict[str, dict]:
    """Per road (host numbers) from the arrays of :func:`make_lap_test`'s test: ``laps``, the count of each outcome,
    the laps with a contact with another car (``car_contact``) and with a wall (``wall_contact``),
    ``overtakes`` (mean per lap), ``speed_kmh`` (mean), ``rank`` (mean final rank)."""
    r = {k: np.asarray(v) for k, v in result.items()}
    out = {}
    for i, road in enumerate(roads):
        row = {"laps": int(r["success"].shape[1])}
        row.update({k: int(round(float(r[k][i].sum()))) for k in (*LAP_OUTCOMES, *CONTACTS) if k in r})
        row.update(overtakes=float(r["overtakes"][i].mean()), speed_kmh=float(3.6 * r["speed"][i].mean()),
                   rank=float(r["rank"][i].mean()))  # fmt: skip
        out[road] = row
    return out
