"""``racecar``: range finders against hand-computed distances (straight, circle), Eq. 6.1 terms by
hand, collisions, rank and overtakes on constructed scenes, the sensor layout, the expert's laps on
every road, robustness to extreme and non-finite actions, jit/vmap without recompiling.

Compiled functions are module fixtures, each used with one input shape, so each compiles once; the
four roads share one compiled lap rollout (``RaceCar.on_road``).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_mjx
from envs_mjx import racetrack
from envs_mjx.config import ConfigError
from envs_mjx.racecar import LAP_OUTCOMES, OBS_SLICES, RaceCar, expert_action, lap_summary, make_lap_test, race_reward

ANGLES = np.deg2rad(np.array(envs_mjx.racecar.TORCS_RANGEFINDER_ANGLES, np.float64))


@pytest.fixture(scope="module")
def env():
    return RaceCar(random_start=False)


@pytest.fixture(scope="module")
def jstep(env):
    return jax.jit(env.step)


@pytest.fixture(scope="module")
def start(env):
    """The reset state at arc length 0 (our car on the axis at rest), with opponents far ahead."""
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    rs = state.pipeline_state
    return state.replace(pipeline_state=rs.replace(opp_progress=rs.opp_progress + 600.0))


def _scene(state, **fields):
    return state.replace(pipeline_state=state.pipeline_state.replace(**{k: jnp.asarray(v) for k, v in fields.items()}))


# ------------------------------------------------------------------- roads, rays


def test_roads_as_documented():
    widths = {"train": 12.0, "test1": 10.0, "test2": 12.0, "test3": 12.0}
    turns = {}
    for name, width in widths.items():
        track = racetrack.make_road(name)
        spec = racetrack.ROADS[name]
        kappa = np.asarray(track.curvature)
        assert track.n == 1024 and float(track.width) == width
        assert spec.radius_range[0] - 0.5 <= 1.0 / np.abs(kappa).max() <= spec.radius_range[1] + 0.5
        np.testing.assert_allclose(kappa.sum() * float(track.ds), 2 * math.pi, rtol=1e-3)  # one anticlockwise loop
        np.testing.assert_allclose(np.linalg.norm(np.asarray(track.left - track.right), axis=1), width, rtol=1e-5)
        turns[name] = np.abs(kappa).sum() * float(track.ds) / (2 * math.pi)
    assert min(turns["test1"], turns["test2"], turns["test3"]) > 1.4 * turns["train"]
    with pytest.raises(ConfigError, match="test3"):
        RaceCar(road="test4")


def test_random_roads_are_a_bank_of_distinct_generated_roads_and_step_as_each_road_alone():
    """``road='random'``: the bank is 'train' and generated roads (widths 10 / 12 m, smallest radius 15–60 m,
    one anticlockwise loop) none of which is a test road; reset draws roads uniformly; a step and the
    expert on a bank road equal those of the single-road env of that road (two code paths; the step to float
    rounding)."""
    bank = RaceCar(road="random", road_bank=6)
    assert bank.n_roads == 6
    first = bank.bank_road(0).track
    np.testing.assert_array_equal(np.asarray(first.centre), np.asarray(racetrack.make_road("train").centre))
    tests = [np.asarray(racetrack.make_road(name).centre) for name in ("test1", "test2", "test3")]
    for i in range(1, 6):
        track = bank.bank_road(i).track
        kappa = np.asarray(track.curvature)
        assert float(track.width) in (10.0, 12.0) and 14.5 <= 1.0 / np.abs(kappa).max() <= 60.5
        np.testing.assert_allclose(kappa.sum() * float(track.ds), 2 * math.pi, rtol=1e-3)
        centre = np.asarray(track.centre)
        for other in tests:  # a different curve: far from the test road somewhere along the lap
            assert np.linalg.norm(centre[:, None] - other[None], axis=-1).min(axis=1).max() > 20.0
    states = jax.jit(jax.vmap(bank.reset))(jax.random.split(jax.random.PRNGKey(3), 48))
    drawn = np.bincount(np.asarray(states.pipeline_state.road), minlength=6)
    assert drawn.min() >= 2 and drawn.sum() == 48
    lane = int(np.argmax(np.asarray(states.pipeline_state.road) == 4))
    state = jax.tree.map(lambda x: x[lane], states)
    alone = bank.on_road(bank.bank_road(4))
    action = jnp.array([0.2, 0.7, 0.0])
    for got, want in zip(jax.tree.leaves(jax.jit(bank.step)(state, action)),
                         jax.tree.leaves(jax.jit(alone.step)(state, action)), strict=True):  # fmt: skip
        # two programs, compiled apart: XLA:CPU may round them differently (1 ulp with its older fusion
        # code generator, which the tests use), so equal to float rounding, not to the bit
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(jax.jit(bank.expert)(state)), np.asarray(expert_action(alone, state)))
    with pytest.raises(ConfigError, match="road_bank"):
        RaceCar(road="random", road_bank=0)


def test_range_finders_on_a_straight():
    """Stadium with 1000 m straights: rays from 1 m left of the axis, heading along it or 0.2 rad off, hit the
    edge lines y = −100 ± 6 at (y_edge − y) / sin(ψ + α); the straight-ahead ray exceeds 200 m."""
    track = racetrack.stadium(1000.0, 100.0, 12.0, ds=1.0)
    p = np.array([500.0, -99.0])
    proj = racetrack.locate(track, jnp.asarray(p, jnp.float32))
    np.testing.assert_allclose([float(proj.s), float(proj.lateral), float(proj.heading)], [500.0, 1.0, 0.0], atol=1e-3)
    for yaw in (0.0, 0.2):
        got = racetrack.range_finders(track, jnp.asarray(p, jnp.float32), yaw, proj.seg, jnp.asarray(ANGLES))
        world = yaw + ANGLES
        edge = np.where(np.sin(world) > 0, -94.0, -106.0)
        with np.errstate(divide="ignore"):
            want = np.minimum(np.abs((edge - p[1]) / np.sin(world)), 200.0)
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-3)
        if yaw == 0.0:  # straight ahead beyond range; 7 m to the right edge, 5 m to the left one
            np.testing.assert_allclose([got[9], got[0], got[18]], [200.0, 7.0, 5.0], atol=1e-3)


def test_range_finders_on_a_circle():
    """Circle of radius 100, width 12: rays from radius 98 hit the circles r = 94 or 106 at the root of
    |p + t u|² = r² (the nearer crossing of the inner circle if the ray meets it)."""
    track = racetrack.circle(100.0, 12.0, ds=1.0)
    p = np.array([98.0 * math.cos(0.7), 98.0 * math.sin(0.7)])
    proj = racetrack.locate(track, jnp.asarray(p, jnp.float32))
    np.testing.assert_allclose(float(proj.lateral), 2.0, atol=2e-3)  # inside = left of an anticlockwise loop
    np.testing.assert_allclose(float(racetrack.wrap_angle(proj.heading - (0.7 + math.pi / 2))), 0.0, atol=2e-3)
    for yaw in (0.7 + math.pi / 2, 0.7 + math.pi / 2 - 0.3):
        got = racetrack.range_finders(track, jnp.asarray(p, jnp.float32), yaw, proj.seg, jnp.asarray(ANGLES))
        u = np.stack([np.cos(yaw + ANGLES), np.sin(yaw + ANGLES)], axis=1)
        pu = u @ p
        t_out = -pu + np.sqrt(pu**2 - p @ p + 106.0**2)
        disc = pu**2 - p @ p + 94.0**2
        t_in = np.where(disc > 0, -pu - np.sqrt(np.maximum(disc, 0.0)), np.inf)
        t_in = np.where(t_in >= 0, t_in, np.inf)
        want = np.minimum(np.minimum(t_out, t_in), 200.0)
        assert np.abs(disc[np.isfinite(disc)]).min() > 50.0  # no grazing ray: the polygon edges give the same hits
        np.testing.assert_allclose(got, want, atol=0.02)
        assert (want < 200.0).all() and (t_in < np.inf).any()  # both circles are hit by some ray


# --------------------------------------------------------------------- reward


def test_reward_terms_by_hand():
    theta, d, v, rank = 0.3, -0.4, 20.0, 4
    reward, terms = race_reward(jnp.float32(theta), jnp.float32(d), jnp.float32(v), rank, 10, 0.0)
    by_hand = {"r_speed": 20 * math.cos(0.3), "r_lateral": -20 * math.sin(0.3), "r_offset": -8.0, "r_rank": 12.0}
    for k, value in by_hand.items():
        np.testing.assert_allclose(terms[k], value, rtol=1e-6)
    np.testing.assert_allclose(reward, sum(by_hand.values()), rtol=1e-6)  # Eq. 6.1: r_1 + r_2 = 17.196
    assert float(terms["penalty"]) == 0.0
    hit, hit_terms = race_reward(jnp.float32(theta), jnp.float32(d), jnp.float32(v), rank, 10, 1.0)
    assert float(hit) == -10.0 and float(hit_terms["penalty"]) == -10.0
    added, _ = race_reward(jnp.float32(theta), jnp.float32(d), jnp.float32(v), rank, 10, 1.0, penalty_mode="add")
    np.testing.assert_allclose(added, sum(by_hand.values()) - 10.0, rtol=1e-6)


def test_step_reward_matches_its_terms(env, jstep, start):
    s = jstep(_scene(start, vel=[15.0, 0.0, 0.0]), jnp.array([0.0, 0.5, 0.0]))
    m = s.metrics
    assert float(m["penalty"]) == 0.0 and float(m["collision"]) == 0.0 and float(m["rank"]) == 10.0
    total = m["r_speed"] + m["r_lateral"] + m["r_offset"] + m["r_rank"]
    np.testing.assert_allclose(s.reward, total, rtol=1e-6)
    theta, d, vx = s.obs[0], s.obs[20], s.pipeline_state.vel[0]
    np.testing.assert_allclose(m["r_speed"], vx * jnp.cos(theta), rtol=1e-5)
    np.testing.assert_allclose(m["r_offset"], -vx * jnp.abs(d), rtol=1e-5, atol=1e-6)
    assert float(m["r_rank"]) == 0.0  # last of 10: 2 (n − rank) = 0


# ------------------------------------------------------------ scenes: contacts, rank


def test_rear_end_collision(env, jstep, start):
    """An opponent standing 3 m ahead on our line overlaps our 4.6 m car: contact, damage, −10, pushed out."""
    rs = start.pipeline_state
    progress = rs.opp_progress.at[0].set(3.0)
    scene = _scene(start, vel=[10.0, 0.0, 0.0], opp_progress=progress, opp_offset=rs.opp_offset.at[0].set(0.0))
    scene = _scene(scene, opp_speed=rs.opp_speed.at[0].set(0.0), opp_top=rs.opp_top.at[0].set(0.0))
    s = jstep(scene, jnp.array([0.0, 0.0, 0.0]))
    m = s.metrics
    assert float(m["collision"]) == 1.0 and float(m["collisions"]) == 1.0
    assert float(m["car_collisions"]) == 1.0 and float(m["wall_collisions"]) == 0.0
    assert float(m["damage"]) >= env.config.damage_gain * 10.0  # at least one contact at the 10 m/s impact
    assert float(s.reward) == -10.0 and float(m["penalty"]) == -10.0
    assert float(s.pipeline_state.vel[0]) < 0.5  # its velocity into the standing car is gone
    gap = float(s.pipeline_state.opp_progress[0] - s.pipeline_state.progress)
    assert gap >= env.config.car_length - 0.05  # moved out of the overlap


def test_side_by_side_no_collision_then_wall(env, jstep, start):
    rs = start.pipeline_state
    beside = _scene(
        start,
        vel=[10.0, 0.0, 0.0],
        opp_progress=rs.opp_progress.at[0].set(0.0),
        opp_offset=rs.opp_offset.at[0].set(env.config.car_width + 0.3),
        opp_speed=rs.opp_speed.at[0].set(10.0),
    )
    s = jstep(beside, jnp.zeros(3))
    assert float(s.metrics["collision"]) == 0.0 and float(s.metrics["damage"]) == 0.0
    # 0.2 m from the wall (half width + runoff), sliding at it sideways at 5 m/s: a wall contact
    lateral = -(float(env.track.half_width) + env.config.runoff - 0.5 * env.config.car_width - 0.2)
    _, _, normal = racetrack.point_at(env.track, rs.s)
    wall = _scene(start, pos=rs.pos + lateral * normal, lateral=lateral, vel=[10.0, -5.0, 0.0])
    s = jstep(wall, jnp.zeros(3))
    m = s.metrics
    assert float(m["collision"]) == 1.0 and float(m["out_of_track"]) == 1.0 and float(s.reward) == -10.0
    assert float(m["wall_collisions"]) == 1.0 and float(m["car_collisions"]) == 0.0
    assert (np.asarray(s.obs[OBS_SLICES["tracks"]]) == -1.0).all()  # off the road: range finders read −1
    limit = float(env.track.half_width) + env.config.runoff
    assert abs(float(s.pipeline_state.lateral)) <= limit - 0.5 * env.config.car_width + 0.05


def test_rank_overtakes_and_opponent_sensors(env, jstep, start):
    """Opponents at known places: the rank counts those ahead; passing one counts an overtake, being passed
    an 'overtaken'; each opponent sensor holds the distance to the nearest car in its 10° sector."""
    n = env.config.n_opponents
    progress = jnp.asarray([0.1, -1.0, 20.0, -30.0, 300.0, 320.0, 340.0, 360.0, 380.0], jnp.float32)
    offset = jnp.asarray([4.0, -4.0, 1.5, 0.0, 0, 0, 0, 0, 0], jnp.float32)
    speed = jnp.asarray([0.0, 30.0, 20.0, 0.0, 0, 0, 0, 0, 0], jnp.float32)
    scene = _scene(
        start,
        vel=[10.0, 0.0, 0.0],
        opp_progress=progress,
        opp_offset=offset,
        opp_speed=speed,
        opp_top=speed,
        opp_factor=jnp.ones(n),
        opp_ahead=(progress > 0).astype(jnp.float32),
    )
    rs = scene.pipeline_state
    assert float(env.rank(rs)) == 1 + 7  # 0.1, 20 and 300…380 m are ahead
    rel = np.asarray(env.opponent_poses(rs)[0] - rs.pos, np.float64)
    bearing = np.arctan2(rel[:, 1], rel[:, 0]) - float(rs.yaw)
    sector = (((bearing + np.pi) % (2 * np.pi)) // (np.pi / 18)).astype(int)
    want = np.full(36, 200.0)
    for k, dist in zip(sector, np.linalg.norm(rel, axis=1), strict=True):
        want[k] = min(want[k], dist)
    np.testing.assert_allclose(env.sensors(rs)["opponents"], want, atol=1e-3)
    assert sector[0] >= 18 and sector[1] < 18  # left and right of us
    assert sum(want < 200) == 4 and abs(want[sector[2]] - 20.0) < 1.0
    obs = env.observe(rs)
    np.testing.assert_allclose(obs[OBS_SLICES["opponents"]], want / 200.0, atol=1e-5)

    s = jstep(scene, jnp.array([0.0, 0.0, 0.0]))
    m = s.metrics
    assert float(m["overtakes"]) == 1.0  # passed the standing car 0.1 m ahead, 4 m to our left
    assert float(m["overtaken"]) == 1.0  # the 30 m/s car 1 m behind, 4 m to our right, passed us
    assert float(m["rank"]) == 8.0 and float(m["collision"]) == 0.0
    np.testing.assert_allclose(m["r_rank"], 2.0 * (10 - 8))


def test_action_maps():
    for pedal_map in ("clip", "affine"):
        e = RaceCar(pedal_map=pedal_map, n_opponents=0)
        a = e.action_from_controls(jnp.float32(-0.3), jnp.float32(0.7), jnp.float32(0.0))
        np.testing.assert_allclose(e.controls(a), [-0.3, 0.7, 0.0], atol=1e-6)
    np.testing.assert_allclose(RaceCar(n_opponents=0).controls(jnp.array([1.0, -0.5, -0.1])), [1.0, 0.0, 0.0])


# ----------------------------------------------------------------- the expert


@pytest.fixture(scope="module")
def expert_laps():
    """Two laps per road (random start points) through :func:`make_lap_test`: one vmapped program."""
    test = make_lap_test(RaceCar(), laps=2)
    return tuple(racetrack.ROADS), {k: np.asarray(v) for k, v in jax.jit(lambda k: test(expert_action, k))(
        jax.random.PRNGKey(7)).items()}  # fmt: skip


def test_expert_finishes_laps_on_every_road(expert_laps):
    names, m = expert_laps
    assert (m["success"] == 1.0).all(), dict(zip(names, m["success"].tolist(), strict=True))
    assert (m["out_of_track"] == 0).all() and (m["stalled"] == 0).all()
    assert m["collision"].sum() <= 2  # measured: none
    np.testing.assert_array_equal(m["collision"], np.maximum(m["car_contact"], m["wall_contact"]))
    assert (m["overtakes"] >= 3).all()  # it passes the slower cars (9 start ahead of it)
    lengths = np.array([float(racetrack.make_road(n).length) for n in names])[:, None]
    # one lap, then the episode ends
    np.testing.assert_allclose(m["progress"], np.broadcast_to(lengths, m["progress"].shape), rtol=0.01)
    assert (m["speed"] > 15.0).all()  # > 54 km/h average


def test_lap_outcomes_of_a_car_that_never_drives():
    """Full brake from a standing start: every lap is 'stalled' (too slow), none a success; the outcomes
    partition the laps, and the summary counts them per road."""
    test = make_lap_test(RaceCar(road="test1"), laps=3, roads=("test1", "train"))
    brake = jnp.array([0.0, -1.0, 1.0])
    m = jax.jit(lambda k: test(lambda e, s: brake, k))(jax.random.PRNGKey(0))
    total = sum(np.asarray(m[k]) for k in LAP_OUTCOMES)
    np.testing.assert_array_equal(total, np.ones((2, 3)))
    np.testing.assert_array_equal(m["stalled"], np.ones((2, 3)))
    assert not np.asarray(m["car_contact"]).any() and not np.asarray(m["wall_contact"]).any()
    summary = lap_summary(m, ("test1", "train"))
    assert summary["train"]["stalled"] == 3 and summary["test1"]["success"] == 0 and summary["train"]["laps"] == 3
    assert summary["train"]["car_contact"] == 0 and summary["train"]["wall_contact"] == 0
    assert summary["train"]["speed_kmh"] < 1.0


def test_opponent_closing_speeds_by_hand(start):
    """With ``opponent_speeds``, each sector also reports how fast we close on the car it sees."""
    env = RaceCar(random_start=False, opponent_speeds=True)
    assert env.observation_size == 96
    n = env.config.n_opponents
    progress = jnp.asarray([25.0] + [600.0 + 30 * i for i in range(n - 1)], jnp.float32)
    speed = jnp.asarray([12.0] + [0.0] * (n - 1), jnp.float32)
    scene = _scene(start, vel=[20.0, 0.0, 0.0], opp_progress=progress, opp_offset=jnp.zeros(n), opp_speed=speed)
    sen = env.sensors(scene.pipeline_state)
    ahead = int(np.argmin(np.asarray(sen["opponents"])))
    assert 16 <= ahead <= 19 and abs(float(sen["opponents"][ahead]) - 25.0) < 1.0  # ahead, the road bends a little
    # nearly straight ahead: closing speed ≈ 20 - 12 m/s
    assert float(sen["opponent_speeds"][ahead]) == pytest.approx(8.0, abs=0.3)
    others = np.delete(np.asarray(sen["opponent_speeds"]), ahead)
    seen = np.delete(np.asarray(sen["opponents"]), ahead) < 200.0
    assert (others[~seen] == 0.0).all()
    obs = env.observe(scene.pipeline_state)
    np.testing.assert_allclose(obs[60:], sen["opponent_speeds"] / env.config.speed_scale, atol=1e-6)
    np.testing.assert_allclose(obs[:60], RaceCar(random_start=False).observe(scene.pipeline_state), atol=1e-6)


def test_opponent_offsets_by_hand(start):
    """With ``opponent_offsets``, each sector also reports its car's offset across the road relative to ours:
    a car 25 m ahead 3 m left of the axis, ours 1 m right of it: 4 m, i.e. 4 / 6 half widths on the 12 m road."""
    env = RaceCar(random_start=False, opponent_speeds=True, opponent_offsets=True)
    assert env.observation_size == 132
    n = env.config.n_opponents
    progress = jnp.asarray([25.0] + [600.0 + 30 * i for i in range(n - 1)], jnp.float32)
    offset = jnp.asarray([3.0] + [0.0] * (n - 1), jnp.float32)
    scene = _scene(start, opp_progress=progress, opp_offset=offset, lateral=-1.0)
    sen = env.sensors(scene.pipeline_state)
    ahead = int(np.argmin(np.asarray(sen["opponents"])))
    assert float(sen["opponent_offsets"][ahead]) == pytest.approx(4.0, abs=1e-5)
    seen = np.asarray(sen["opponents"]) < 200.0
    assert (np.asarray(sen["opponent_offsets"])[~seen] == 0.0).all()
    obs = env.observe(scene.pipeline_state)
    np.testing.assert_allclose(obs[96:], sen["opponent_offsets"] / 6.0, atol=1e-6)
    np.testing.assert_allclose(obs[:96], RaceCar(random_start=False, opponent_speeds=True).observe(
        scene.pipeline_state), atol=1e-6)  # fmt: skip


# ------------------------------------------------------- robustness, recompiles


@pytest.fixture(scope="module")
def wrapped():
    env = envs_mjx.make("racecar", road="test1")
    train_env = envs_mjx.wrap_for_training(env, episode_length=16, num_envs=8)
    traces = []

    def step(state, action):
        traces.append(1)
        return train_env.step(state, action)

    return train_env, jax.jit(train_env.reset), jax.jit(step), traces


def test_extreme_and_nonfinite_actions_no_nan_no_recompile(wrapped):
    train_env, reset, step, traces = wrapped
    state = reset(jax.random.PRNGKey(3))
    assert state.obs.shape == (8, 60)
    lanes = jnp.arange(8)[:, None]
    extreme = jnp.where(lanes % 2 == 0, 1e6, -jnp.inf) * jnp.ones((8, 3), jnp.float32)
    nan = jnp.full((8, 3), jnp.nan, jnp.float32).at[::3, 1].set(1.0)
    key = jax.random.PRNGKey(4)
    ends = 0.0
    full_left = jnp.tile(jnp.array([1.0, 1.0, -1.0]), (8, 1))  # full throttle into the wall
    for t in range(40):
        key, sub = jax.random.split(key)
        rand = jax.random.uniform(sub, (8, 3), minval=-3.0, maxval=3.0)
        actions = (rand, extreme, nan, -extreme)[t % 4] if t < 32 else full_left
        state = step(state, actions)
        ends += float(state.done.sum())
        leaves = (state.obs, state.reward, state.pipeline_state.pos, state.pipeline_state.vel, state.info["final_obs"])
        assert all(bool(jnp.all(jnp.isfinite(x))) for x in leaves), t
        assert float(jnp.max(jnp.abs(state.obs))) <= 4.0  # the normalised observation stays in range
    np.testing.assert_array_equal(state.metrics["invalid_action"], 0.0)
    assert ends > 0  # episodes ended (16-step limit or a termination) and were reset
    assert len(traces) == 1
    assert step._cache_size() == 1
