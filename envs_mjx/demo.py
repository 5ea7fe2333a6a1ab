"""Scripted controllers driving the environments: ``python -m envs_mjx.demo [--env arm7|racecar]``.

``arm7`` (default): a greedy straight-to-goal controller.  Runs one episode on each of ``--lanes``
parallel lanes per physics mode, the action being the largest step ``C`` allows along the straight
line to the goal, and prints the success rate, the mean extra distance (path length minus the
straight start-goal distance, successful episodes), the mean episode length and the control steps
per second (after compilation). ``python -m benchmarks.arm7_greedy`` runs the same controller and writes
its results file with the run's provenance.

``racecar``: the scripted expert driver (:func:`envs_mjx.racecar.expert_action`) races one lap
among the nine opponents on each of ``--roads`` in ``--lanes`` parallel episodes, prints the lap
success, laps with a collision or off the road, overtakes, final rank, lap time and the wall time
(compilation and run), and writes into ``--out`` a picture of lane 0's lap (``racecar-<road>.png``:
the road from above with our path coloured by speed and everyone's final place; our speed against
the speed profile, our offset from the axis and our rank along the lap) and, when pillow is
installed, a chase view of it as an animation (``racecar-<road>.gif``, every ``--gif-stride``-th
step), and a picture of the four roads beside twelve of the generated training roads
(``racecar-roads.png``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import jax.numpy as jnp

import envs_mjx
from envs_mjx import xla


def greedy_action(env, state):
    """``[B, 3]`` action moving straight at the goal by at most ``C`` per axis."""
    d = (state.info["goal"] - state.info["ee_pos"]) / env.action_scale
    return d / jnp.maximum(jnp.max(jnp.abs(d), axis=-1, keepdims=True), 1.0)


def make_rollout(env, lanes: int):
    """``rollout(key) -> dict`` of per-lane first-episode results, ``[lanes]`` each (pure, jittable)."""
    steps = env.episode_length

    def rollout(key):
        state = jax.vmap(env.reset)(jax.random.split(key, lanes))

        def body(carry, _):
            state, done, success, length, extra = carry
            nxt = jax.vmap(env.step)(state, greedy_action(env, state))
            live = 1.0 - done
            ended = live * nxt.done
            success = success + ended * nxt.metrics["success"]
            extra = jnp.where(ended > 0, nxt.metrics["extra_distance"], extra)
            return (nxt, jnp.maximum(done, nxt.done), success, length + live, extra), None

        zero = jnp.zeros(lanes)
        (_, _, success, length, extra), _ = jax.lax.scan(body, (state, zero, zero, zero, zero), None, steps)
        return {"success": success, "length": length, "extra": extra}

    return rollout


def run(mode: str, lanes: int, seed: int, env_name: str = "arm7") -> dict[str, float]:
    """The greedy controller's first episode on ``lanes`` lanes of ``env_name`` in ``mode`` from key
    ``fold_in(PRNGKey(seed), 1)`` (``PRNGKey(seed)``'s batch compiles the program first): success count and
    rate, mean extra steps of the successes, mean length, env steps/s and the compile time."""
    env = envs_mjx.make(env_name, mode=mode)
    rollout = xla.jit(make_rollout(env, lanes))
    key = jax.random.PRNGKey(seed)
    t0 = time.perf_counter()
    jax.block_until_ready(rollout(key))
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = jax.block_until_ready(rollout(jax.random.fold_in(key, 1)))
    run_s = time.perf_counter() - t0
    ok = out["success"] > 0
    return {
        "successes": int(ok.sum()),
        "episodes": lanes,
        "success": float(ok.mean()),
        "extra": float(jnp.where(ok, out["extra"], 0.0).sum() / jnp.maximum(ok.sum(), 1)),
        "length": float(out["length"].mean()),
        "steps_per_s": lanes * env.episode_length / run_s,
        "compile_s": compile_s,
    }


def make_race_rollout(env, lanes: int, act=None):
    """``rollout(key) -> (final State [lanes], records)``: ``act(env, state) -> action [3]`` (default: the
    expert, :func:`envs_mjx.racecar.expert_action`) drives until each lane's episode ends.

    ``records`` holds per step ``[T, lanes, ...]``: our ``pos`` (2), ``yaw``, ``speed`` (v_x),
    ``progress``, arc length ``s``, ``lateral`` offset and ``rank``, the opponents' ``opp_pos``
    (N, 2) and ``opp_yaw`` (N), and ``live`` (1 until the step that ends the episode, included).
    Finished lanes stay frozen.
    """
    from envs_mjx.racecar import expert_action

    act = expert_action if act is None else act

    def one(key):
        state = env.reset(key)

        def body(carry, _):
            state, done = carry
            nxt = env.step(state, act(env, state))
            nxt = jax.tree.map(lambda a, b: jnp.where(done > 0, a, b), state, nxt)
            rs = nxt.pipeline_state
            opp_pos, opp_yaw, _ = env.opponent_poses(rs)
            rec = {"pos": rs.pos, "yaw": rs.yaw, "speed": rs.vel[0], "opp_pos": opp_pos, "opp_yaw": opp_yaw}
            rec.update(progress=rs.progress, s=rs.s, lateral=rs.lateral, rank=nxt.metrics["rank"], live=1.0 - done)
            return (nxt, jnp.maximum(done, nxt.done)), rec

        (state, _), rec = jax.lax.scan(body, (state, jnp.zeros(())), None, env.episode_length)
        return state, rec

    def rollout(key):
        state, rec = jax.vmap(one)(jax.random.split(key, lanes))
        return state, jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), rec)

    return rollout


def _car_outline(pos, yaw, length: float, width: float):
    """Corners ``[5, 2]`` (closed) of a car rectangle."""
    import numpy as np

    c, s = np.cos(yaw), np.sin(yaw)
    local = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1], [1, 1]]) * [0.5 * length, 0.5 * width]
    return pos + local @ np.array([[c, s], [-s, c]])


def race_figures(env, rec: dict, out_dir: str, road: str, summary: str, gif_stride: int | None = 5) -> list[str]:
    """Write the lap picture and (``gif_stride`` not None, pillow installed) the chase animation of lane 0.

    Returns the paths written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.collections import LineCollection

    track = env.track
    r = {k: np.asarray(v)[:, 0] for k, v in rec.items()}
    steps = max(int(r["live"].sum()), 1)
    pos, speed = r["pos"][:steps], r["speed"][:steps] * 3.6
    left, right = np.asarray(track.left), np.asarray(track.right)
    loop = lambda a: np.concatenate([a, a[:1]])
    os.makedirs(out_dir, exist_ok=True)
    paths = []

    fig = plt.figure(figsize=(15, 8))
    grid = fig.add_gridspec(3, 2, width_ratios=(1.25, 1.0))
    ax = fig.add_subplot(grid[:, 0])
    ax.fill(*loop(right).T, color="0.85", zorder=0)
    ax.fill(*loop(left).T, color="white", zorder=0)
    ax.plot(*loop(left).T, "k", lw=0.6)
    ax.plot(*loop(right).T, "k", lw=0.6)
    segs = np.stack([pos[:-1], pos[1:]], axis=1)
    lines = LineCollection(segs, cmap="plasma", linewidths=2.0)
    lines.set_array(speed[1:])
    ax.add_collection(lines)
    fig.colorbar(lines, ax=ax, shrink=0.6, label="our speed (km/h)")
    for i in range(r["opp_pos"].shape[1]):
        ax.plot(*r["opp_pos"][steps - 1, i], "s", color="tab:blue", ms=6, mec="k", zorder=3)
    ax.plot(*pos[0], "go", ms=9, zorder=4, label="start")
    ax.plot(*pos[-1], "*", color="tab:red", ms=14, mec="k", zorder=4, label="our car at the end")
    ax.plot([], [], "s", color="tab:blue", mec="k", label="opponents at the end")
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"racecar, road {road} ({float(track.width):g} m): {summary}", fontsize=9)

    dist = r["progress"][:steps]
    ax1 = fig.add_subplot(grid[0, 1])
    ax1.plot(dist, speed, color="tab:red", label="our speed")
    ax1.plot(dist, 3.6 * np.asarray(env.profile_at(r["s"][:steps])), color="0.5", lw=0.8, label="speed profile")
    ax1.set_ylabel("km/h")
    ax1.legend(fontsize=8)
    ax2 = fig.add_subplot(grid[1, 1], sharex=ax1)
    ax2.plot(dist, r["lateral"][:steps], color="tab:red")
    for edge in (-0.5, 0.5):
        ax2.axhline(edge * float(track.width), color="k", lw=0.8)
    ax2.set_ylabel("offset from axis (m)")
    ax3 = fig.add_subplot(grid[2, 1], sharex=ax1)
    ax3.plot(dist, r["rank"][:steps], color="tab:red", drawstyle="steps-post")
    ax3.set_ylabel("rank")
    ax3.set_xlabel("distance along the axis (m)")
    ax3.invert_yaxis()
    png = os.path.join(out_dir, f"racecar-{road}.png")
    fig.savefig(png, dpi=120, bbox_inches="tight")
    plt.close(fig)
    paths.append(png)
    if gif_stride is None:
        return paths
    try:
        import PIL  # noqa: F401
    except ImportError:
        print("pillow is not installed: no animation written")
        return paths
    from matplotlib.animation import FuncAnimation, PillowWriter

    fig, draw = chase_view(env, r, steps)
    anim = FuncAnimation(fig, draw, frames=list(range(0, steps, max(gif_stride, 1))), blit=False)
    gif = os.path.join(out_dir, f"racecar-{road}.gif")
    anim.save(gif, writer=PillowWriter(fps=10))
    plt.close(fig)
    paths.append(gif)
    return paths


def chase_view(env, r: dict, steps: int, size: float = 5.0):
    """``(figure, draw)``: the chase view of one episode, ``draw(k)`` showing step ``k < steps`` (the road
    140 m around our car, the last 100 steps of our path, every car, the time and our speed).

    ``r`` holds one lane's records of :func:`make_race_rollout` (host arrays ``[T, ...]``); ``size``: inches.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    cfg = env.config
    left, right = np.asarray(env.track.left), np.asarray(env.track.right)
    loop = lambda a: np.concatenate([a, a[:1]])  # noqa: E731
    pos, speed = r["pos"][:steps], r["speed"][:steps] * 3.6
    fig, ax = plt.subplots(figsize=(size, size))
    ax.fill(*loop(right).T, color="0.85", zorder=0)
    ax.fill(*loop(left).T, color="white", zorder=0)
    ax.plot(*loop(left).T, "k", lw=0.8)
    ax.plot(*loop(right).T, "k", lw=0.8)
    ax.set_aspect("equal")
    (trail,) = ax.plot([], [], color="tab:red", lw=1.0, alpha=0.6)
    ours = ax.fill([], [], color="tab:red")[0]
    opps = [ax.fill([], [], color="tab:blue")[0] for _ in range(r["opp_pos"].shape[1])]
    text = ax.text(0.02, 0.97, "", transform=ax.transAxes, va="top", fontsize=8)

    def draw(k):
        p = pos[k]
        ax.set_xlim(p[0] - 70, p[0] + 70)
        ax.set_ylim(p[1] - 70, p[1] + 70)
        trail.set_data(*pos[max(0, k - 100) : k + 1].T)
        ours.set_xy(_car_outline(p, r["yaw"][k], cfg.car_length, cfg.car_width))
        for i, patch in enumerate(opps):
            patch.set_xy(_car_outline(r["opp_pos"][k, i], r["opp_yaw"][k, i], cfg.car_length, cfg.car_width))
        text.set_text(f"t = {k * cfg.dt:5.1f} s   {speed[k]:5.1f} km/h")
        return [trail, ours, text, *opps]

    return fig, draw


def roads_figure(out_dir: str, generated: int = 12, family_seed: int = 0) -> str:
    """Write ``racecar-roads.png``: the four named roads and the first ``generated`` roads of the
    generated training family (``road='random'``'s bank after 'train'), each from above with its
    width, lap length and smallest radius.  Returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from envs_mjx import racetrack

    roads = [(name, racetrack.make_road(name)) for name in racetrack.ROADS]
    roads += [(f"generated {i}", racetrack.make_spec_road(racetrack.random_road_spec(i, family_seed)))
              for i in range(1, generated + 1)]  # fmt: skip
    cols = 4
    fig, axes = plt.subplots((len(roads) + cols - 1) // cols, cols, figsize=(3.2 * cols, 3.2 * len(roads) / cols + 1))
    loop = lambda a: np.concatenate([a, a[:1]])  # noqa: E731
    for ax, (name, track) in zip(np.ravel(axes), roads, strict=False):
        left, right = np.asarray(track.left), np.asarray(track.right)
        ax.fill(*loop(right).T, color="0.8" if name in racetrack.ROADS else "0.9")
        ax.fill(*loop(left).T, color="white")
        ax.plot(*loop(left).T, "k", lw=0.5)
        ax.plot(*loop(right).T, "k", lw=0.5)
        radius = 1.0 / float(np.abs(np.asarray(track.curvature)).max())
        title = f"{name}: {float(track.width):g} m, {float(track.length):.0f} m lap, r_min {radius:.0f} m"
        ax.set_title(title, fontsize=8)
        ax.set_aspect("equal")
        ax.axis("off")
    for ax in np.ravel(axes)[len(roads):]:
        ax.axis("off")
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, "racecar-roads.png")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def run_racecar(args) -> None:
    """The ``--env racecar`` demo (module docstring)."""
    import numpy as np

    lanes = args.lanes or 16
    print(f"racecar expert driver, {lanes} laps per road, device: {jax.devices()[0].device_kind}")
    print(
        f"{'road':<6} {'width':>5} {'success':>8} {'collision':>9} {'off-road':>8} {'overtakes':>9}"
        f" {'rank':>5} {'lap (s)':>8} {'km/h':>6} {'wall (s)':>8}"
    )
    for road in args.roads:
        env = envs_mjx.make("racecar", road=road)
        rollout = jax.jit(make_race_rollout(env, lanes))
        t0 = time.perf_counter()
        state, rec = jax.block_until_ready(rollout(jax.random.PRNGKey(args.seed)))
        elapsed = time.perf_counter() - t0
        m = {k: np.asarray(v) for k, v in state.metrics.items()}
        ok = m["success"] > 0
        lap = float(np.where(ok, m["time"], 0).sum() / max(ok.sum(), 1))
        kmh = 3.6 * float(env.track.length) / lap if ok.any() else 0.0
        print(
            f"{road:<6} {float(env.track.width):>5.0f} {ok.mean():>8.1%} {(m['collisions'] > 0).mean():>9.1%}"
            f" {(m['out_count'] > 0).mean():>8.1%} {m['overtakes'].mean():>9.2f} {m['rank'].mean():>5.2f}"
            f" {lap:>8.1f} {kmh:>6.1f} {elapsed:>8.1f}"
        )
        summary = (
            f"lap {'finished' if ok[0] else 'not finished'} in {m['time'][0]:.1f} s, rank {m['rank'][0]:.0f}, "
            f"{m['overtakes'][0]:.0f} overtakes, {m['collisions'][0]:.0f} collision steps"
        )
        for path in race_figures(env, rec, args.out, road, summary, args.gif_stride if args.gif else None):
            print(f"  wrote {path}")
    print(f"wrote {roads_figure(args.out)}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="arm7", choices=["arm7", "racecar"])
    parser.add_argument("--lanes", type=int, default=None, help="episodes per mode/road (arm7 256, racecar 16)")
    parser.add_argument("--modes", nargs="+", default=["kinematic", "pd"], choices=["kinematic", "pd"])
    parser.add_argument("--roads", nargs="+", default=["train", "test1", "test2", "test3"])
    parser.add_argument("--out", default=os.path.join("runs", "demo-racecar"), help="racecar: folder for the pictures")
    parser.add_argument("--gif-stride", type=int, default=5, help="racecar: control steps per animation frame")
    parser.add_argument("--no-gif", dest="gif", action="store_false", help="racecar: skip the animation")
    parser.add_argument("--seed", type=int, default=0)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    if args.env == "racecar":
        run_racecar(args)
        return
    args.lanes = args.lanes or 256
    print(f"arm7 greedy controller, {args.lanes} lanes, device: {jax.devices()[0].device_kind}")
    print(f"{'mode':<10} {'success':>8} {'extra (m)':>10} {'steps/ep':>9} {'steps/s':>10} {'compile (s)':>12}")
    rows = []
    for mode in args.modes:
        r = run(mode, args.lanes, args.seed)
        rows.append({"mode": mode, **r})
        print(
            f"{mode:<10} {r['success']:>8.1%} {r['extra']:>10.4f} {r['length']:>9.1f}"
            f" {r['steps_per_s']:>10.0f} {r['compile_s']:>12.1f}"
        )


if __name__ == "__main__":
    main()
