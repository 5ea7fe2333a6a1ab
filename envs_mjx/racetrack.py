"""Closed race tracks for ``racecar``: centre lines with a width, and the geometry on them.

A :class:`Track` is a closed centre line resampled at ``M`` points spaced ``ds`` apart in arc
length (``M · ds`` the lap length ``L``), with unit tangents, left normals, the signed curvature
(positive in a left turn) and a constant width.  Width, length and spacing are array leaves, so
tracks of the same ``M`` share one compiled function (and can be stacked and vmapped); the roads
have ``M = 1024`` by default.  The two edges are the centre line offset by ``±width / 2`` along
the normal.  Arc length ``s`` is
measured from point 0 in the driving direction and wraps at ``L``; the signed lateral offset ``e``
is positive to the left of the centre line, so ``d = e / (width / 2)`` is the thesis's normalised
distance to the track axis (+1 on the left edge, −1 on the right one, §6.1.1).

Roads (:data:`ROADS`, :func:`make_road`).  Each is a periodic cubic spline through ``n_points``
control points at polar angles ``2π(j + u_j')/n`` and radii ``R(1 + a u_j)`` about the origin,
with ``u, u'`` uniform in ``[−1, 1]`` (``u'`` scaled by 0.3) drawn by NumPy's PCG64 from the seed
``(seed, attempt)``.  :func:`road_control_points` tries ``attempt = 0, 1, …`` and keeps the first
spline whose smallest radius of curvature lies in the road's ``radius_range`` and whose parts
more than ``3 · width + 40`` m apart in arc length stay ``2 · width + 20`` m apart in the plane
(no crossing, no touching run-off areas).  The attempt is fixed by the seed, so a road is the
same on every machine.

=====  =========  =======  ==========  ====================================================
road   width (m)  lap (m)  min radius  character
=====  =========  =======  ==========  ====================================================
train  12         2006     57 m        8 control points: a smooth loop of sweeping bends
test1  10         2146     26 m        14 points: narrow, many medium bends both ways
test2  12         2428     20 m        10 points, large jitter: fast sweepers, a hairpin
test3  12         1981     21 m        20 points: a chain of quick S-bends
=====  =========  =======  ==========  ====================================================

The widths are those of the thesis's Table 6.2; the test roads turn more (total |curvature|
1.6–2.7 turns per lap against 1.06) and more tightly than the training road, as the thesis's
unseen roads are more tortuous or narrower (§6.1.3).

Generated training roads (:func:`random_road_spec`, ``racecar``'s ``road='random'``): the same
generator with widths, control-point counts and jitters drawn per road from their own seeds, so
that a policy can be trained on many layouts of the named roads' character and tested on the
three test roads it has never driven.

Geometry (all pure JAX, vectorised, no Python loops over points or rays):

* :func:`point_at` — position, tangent and normal at arc length ``s`` (linear between samples).
* :func:`project` — nearest point of the centre line within a window of segments around a guess
  (the car moves less than a segment per physics step); :func:`locate` searches all segments.
* :func:`range_finders` — the distances along rays from a point to the first crossing of either
  edge polyline, capped at ``max_range`` (the TORCS range finders of §6.1.1).  The rays are
  intersected with every edge segment in a window of arc length around the car (``[R, S]``
  array); a ray inside the corridor meets its first edge within that window.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from scipy.interpolate import CubicSpline

__all__ = [
    "ROADS",
    "Projection",
    "RoadSpec",
    "Track",
    "circle",
    "from_control_points",
    "from_polyline",
    "locate",
    "make_road",
    "make_spec_road",
    "point_at",
    "project",
    "random_road_spec",
    "range_finders",
    "road_control_points",
    "spec_control_points",
    "speed_profile",
    "stadium",
    "wrap_angle",
]


def wrap_angle(x: jax.Array) -> jax.Array:
    """Angle wrapped to ``[−π, π)``."""
    return (x + jnp.pi) % (2.0 * jnp.pi) - jnp.pi


@struct.dataclass
class Track:
    """A closed track sampled uniformly in arc length.

    Attributes:
      centre: ``[M, 2]`` centre-line points, ``centre[i]`` at arc length ``i · ds``.
      tangent: ``[M, 2]`` unit tangents (driving direction).
      normal: ``[M, 2]`` unit left normals (tangent turned by +90°).
      curvature: ``[M]`` signed curvature (1/m), positive in a left turn.
      left, right: ``[M, 2]`` edge points ``centre ± (width / 2) · normal``.
      width: ``[]`` track width (m); ``length``: ``[]`` lap length ``L = M · ds`` (m); ``ds``: ``[]``
        sample spacing (m).
    """

    centre: jax.Array
    tangent: jax.Array
    normal: jax.Array
    curvature: jax.Array
    left: jax.Array
    right: jax.Array
    width: jax.Array
    length: jax.Array
    ds: jax.Array

    @property
    def n(self) -> int:
        """Number of samples ``M``."""
        return int(self.centre.shape[0])

    @property
    def half_width(self) -> jax.Array:
        return 0.5 * self.width


def _build(centre: np.ndarray, tangent: np.ndarray, curvature: np.ndarray, width: float, length: float) -> Track:
    hw = 0.5 * float(width)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    return Track(
        centre=f32(centre),
        tangent=f32(tangent),
        normal=f32(normal),
        curvature=f32(curvature),
        left=f32(centre + hw * normal),
        right=f32(centre - hw * normal),
        width=f32(width),
        length=f32(length),
        ds=f32(float(length) / len(centre)),
    )


def from_polyline(points: np.ndarray, width: float, ds: float = 2.0) -> Track:
    """A track from a dense closed polyline ``[K, 2]`` (last point not repeated), resampled every ≈ ``ds``.

    Tangents are central differences of the resampled points; curvature is the change of heading
    between neighbours over ``2 ds``.
    """
    pts = np.asarray(points, np.float64)
    closed = np.concatenate([pts, pts[:1]])
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    length = float(cum[-1])
    m = max(int(round(length / ds)), 8)
    s = np.arange(m) * (length / m)
    centre = np.stack([np.interp(s, cum, closed[:, 0]), np.interp(s, cum, closed[:, 1])], axis=1)
    diff = np.roll(centre, -1, axis=0) - np.roll(centre, 1, axis=0)
    tangent = diff / np.linalg.norm(diff, axis=1, keepdims=True)
    heading = np.arctan2(tangent[:, 1], tangent[:, 0])
    dh = np.roll(heading, -1) - np.roll(heading, 1)
    curvature = ((dh + np.pi) % (2 * np.pi) - np.pi) / (2 * length / m)
    return _build(centre, tangent, curvature, width, length)


def _spline(points: np.ndarray) -> tuple[CubicSpline, float]:
    """The periodic cubic spline (chord-length knots) through ``points [K, 2]`` and its parameter period."""
    pts = np.asarray(points, np.float64)
    closed = np.concatenate([pts, pts[:1]])
    t = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    return CubicSpline(t, closed, bc_type="periodic"), float(t[-1])


def _spline_samples(spline: CubicSpline, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points ``[N, 2]``, unit tangents ``[N, 2]`` and signed curvature ``[N]`` of ``spline`` at ``t``."""
    d1, d2 = spline(t, 1), spline(t, 2)
    speed = np.linalg.norm(d1, axis=1)
    kappa = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / speed**3
    return spline(t), d1 / speed[:, None], kappa


def from_control_points(points: np.ndarray, width: float, n_samples: int = 1024, samples_per_point: int = 256) -> Track:
    """A track whose centre line is the periodic cubic spline (chord-length knots) through ``points [K, 2]``.

    The arc length of the spline is integrated on ``samples_per_point · K`` parameter steps
    (trapezoid rule); the ``M = n_samples`` samples sit at equal arc-length steps on the spline
    itself, with its exact tangents and curvature ``(x′y″ − y′x″) / |r′|³``.
    """
    spline, period = _spline(points)
    tt = np.linspace(0.0, period, samples_per_point * len(points) + 1)
    speed = np.linalg.norm(spline(tt, 1), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(tt))])
    length = float(cum[-1])
    t_of_s = np.interp(np.arange(n_samples) * (length / n_samples), cum, tt)
    centre, tangent, kappa = _spline_samples(spline, t_of_s)
    return _build(centre, tangent, kappa, width, length)


def circle(radius: float, width: float, ds: float = 1.0) -> Track:
    """A circle of centre-line ``radius`` about the origin, driven anticlockwise from ``(radius, 0)``."""
    n = max(int(round(2 * math.pi * radius / ds)) * 8, 64)
    phi = 2 * np.pi * np.arange(n) / n
    return from_polyline(radius * np.stack([np.cos(phi), np.sin(phi)], axis=1), width, ds)


def stadium(straight: float, radius: float, width: float, ds: float = 1.0) -> Track:
    """Two straights of length ``straight`` joined by half circles of ``radius``; anticlockwise.

    Point 0 is the start of the lower straight ``(0, −radius)``, heading along +x; the straights
    are exact lines (samples every ``ds / 8`` on the arcs).
    """
    k = max(int(round(math.pi * radius / ds)) * 8, 16)
    arc = np.pi * np.arange(k) / k
    lower = np.stack([np.linspace(0.0, straight, 2, endpoint=False), np.full(2, -radius)], axis=1)
    right = np.stack([straight + radius * np.sin(arc), -radius * np.cos(arc)], axis=1)
    upper = np.stack([np.linspace(straight, 0.0, 2, endpoint=False), np.full(2, radius)], axis=1)
    left = np.stack([-radius * np.sin(arc), radius * np.cos(arc)], axis=1)
    return from_polyline(np.concatenate([lower, right, upper, left]), width, ds)


@dataclasses.dataclass(frozen=True)
class RoadSpec:
    """Parameters of a generated road (module docstring)."""

    width: float
    n_points: int
    radius: float
    jitter: float
    radius_range: tuple[float, float]
    seed: int


ROADS: dict[str, RoadSpec] = {
    "train": RoadSpec(width=12.0, n_points=8, radius=300.0, jitter=0.25, radius_range=(30.0, 60.0), seed=1),
    "test1": RoadSpec(width=10.0, n_points=14, radius=280.0, jitter=0.30, radius_range=(20.0, 28.0), seed=2),
    "test2": RoadSpec(width=12.0, n_points=10, radius=300.0, jitter=0.45, radius_range=(15.0, 22.0), seed=3),
    "test3": RoadSpec(width=12.0, n_points=20, radius=300.0, jitter=0.22, radius_range=(18.0, 26.0), seed=4),
}

_MAX_ATTEMPTS = 1000


def _clearance(points: np.ndarray, spacing: float, width: float) -> float:
    """Smallest distance between points more than ``3 · width + 40`` m apart along the closed curve."""
    n = len(points)
    dist = np.linalg.norm(points[:, None] - points[None], axis=-1)
    idx = np.arange(n)
    sep = np.abs(idx[:, None] - idx[None])
    far = np.minimum(sep, n - sep) * spacing > 3 * width + 40
    return float(dist[far].min()) if far.any() else math.inf


def road_control_points(name: str) -> tuple[np.ndarray, int]:
    """``(control points [n_points, 2], attempt)`` of road ``name`` (module docstring)."""
    return spec_control_points(ROADS[name])


@functools.cache
def spec_control_points(spec: RoadSpec) -> tuple[np.ndarray, int]:
    """``(control points [n_points, 2], attempt)`` of the road generated from ``spec`` (module docstring)."""
    for attempt in range(_MAX_ATTEMPTS):
        rng = np.random.default_rng([spec.seed, attempt])
        u_phi = 0.3 * rng.uniform(-1.0, 1.0, spec.n_points)
        u_r = rng.uniform(-1.0, 1.0, spec.n_points)
        phi = 2 * np.pi * (np.arange(spec.n_points) + u_phi) / spec.n_points
        r = spec.radius * (1.0 + spec.jitter * u_r)
        pts = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)
        spline, period = _spline(pts)
        dense, _, kappa = _spline_samples(spline, np.linspace(0.0, period, 32 * spec.n_points, endpoint=False))
        r_min = 1.0 / np.abs(kappa).max()
        if not spec.radius_range[0] <= r_min <= spec.radius_range[1]:
            continue
        spacing = np.linalg.norm(np.diff(dense, axis=0), axis=1).mean()
        if _clearance(dense[::2], 2 * spacing, spec.width) >= 2 * spec.width + 20:
            return pts, attempt
    raise RuntimeError(f"no road found for {spec!r} in {_MAX_ATTEMPTS} attempts")


@functools.cache
def make_road(name: str, n_samples: int = 1024) -> Track:
    """The road ``name`` (one of :data:`ROADS`) sampled at ``n_samples`` points (about 2 m apart)."""
    if name not in ROADS:
        raise ValueError(f"unknown road {name!r}; valid roads: {', '.join(ROADS)}")
    return make_spec_road(ROADS[name], n_samples)


@functools.cache
def make_spec_road(spec: RoadSpec, n_samples: int = 1024) -> Track:
    """The road generated from ``spec`` sampled at ``n_samples`` points."""
    pts, _ = spec_control_points(spec)
    return from_control_points(pts, spec.width, n_samples)


RANDOM_ROAD_SEED = 1_000_000
"""Seeds of the generated training roads start here, far from the named roads' seeds 1–4."""


def random_road_spec(index: int, family_seed: int = 0) -> RoadSpec:
    """Road ``index`` of the generated family of training roads number ``family_seed``.

    Drawn by PCG64 from ``(RANDOM_ROAD_SEED, family_seed, index)``: width 10 or 12 m, 8–20
    control points, radial jitter 0.15–0.45 about 300 m; accepted (as every road, module
    docstring) when its smallest radius of curvature lies in 15–60 m and it keeps its clearance.
    This spans the character of all four named roads — the training road's sweeping bends and
    the test roads' narrow, hairpin and S-bend layouts — while every road is a different curve
    (the generator's seed is ``RANDOM_ROAD_SEED + 1000 · family_seed + index``, never 1–4).
    """
    if index < 0 or family_seed < 0:
        raise ValueError(f"index={index} and family_seed={family_seed} must be >= 0")
    rng = np.random.default_rng([RANDOM_ROAD_SEED, family_seed, index])
    return RoadSpec(
        width=float(rng.choice([10.0, 12.0])),
        n_points=int(rng.integers(8, 21)),
        radius=300.0,
        jitter=float(rng.uniform(0.15, 0.45)),
        radius_range=(15.0, 60.0),
        seed=RANDOM_ROAD_SEED + 1000 * family_seed + index,
    )


def speed_profile(track: Track, a_lat: float, a_brake: float, v_max: float) -> np.ndarray:
    """Fastest speed ``[M]`` (m/s) along the line of ``track.curvature``, ``a_lat`` / ``a_brake`` the limits.

    ``v_i = min(v_max, sqrt(a_lat / |κ_i|))``, then a backward pass around the loop (twice, so the
    wrap is covered) enforces ``v_i² ≤ v_{i+1}² + 2 a_brake ds``: every corner can be reached
    from the speed allowed before it.
    """
    kappa = np.abs(np.asarray(track.curvature, np.float64))
    v = np.minimum(v_max, np.sqrt(a_lat / np.maximum(kappa, 1e-9)))
    m = len(v)
    for k in range(2 * m - 1, -1, -1):
        i = k % m
        v[i] = min(v[i], math.sqrt(v[(i + 1) % m] ** 2 + 2.0 * a_brake * float(track.ds)))
    return v.astype(np.float32)


def point_at(track: Track, s: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Centre-line point, unit tangent and left normal at arc length ``s`` (any shape; wraps at ``L``).

    Returns ``(pos [..., 2], tangent [..., 2], normal [..., 2])``, linear between samples.
    """
    u = jnp.mod(jnp.asarray(s, jnp.float32), track.length) / track.ds
    i = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, track.n - 1)
    j = (i + 1) % track.n
    f = (u - i)[..., None]
    pos = (1.0 - f) * track.centre[i] + f * track.centre[j]
    tan = (1.0 - f) * track.tangent[i] + f * track.tangent[j]
    tan = tan / jnp.maximum(jnp.linalg.norm(tan, axis=-1, keepdims=True), 1e-6)
    return pos, tan, jnp.stack([-tan[..., 1], tan[..., 0]], axis=-1)


class Projection(NamedTuple):
    """Nearest centre-line point of a position: segment ``seg`` (int32), arc length ``s`` in ``[0, L)``,
    signed lateral offset ``lateral`` (m, left positive) and the axis heading ``heading`` (rad)."""

    seg: jax.Array
    s: jax.Array
    lateral: jax.Array
    heading: jax.Array


def _project_on(track: Track, p: jax.Array, segs: jax.Array) -> Projection:
    """Nearest point of ``p [2]`` on the centre-line segments ``segs [K]`` (``i → i + 1``)."""
    a = track.centre[segs]
    b = track.centre[(segs + 1) % track.n]
    ab = b - a
    lam = jnp.clip(jnp.sum((p - a) * ab, -1) / jnp.maximum(jnp.sum(ab * ab, -1), 1e-9), 0.0, 1.0)
    foot = a + lam[:, None] * ab
    k = jnp.argmin(jnp.sum((p - foot) ** 2, -1))
    seg = segs[k]
    f = lam[k]
    tan = (1.0 - f) * track.tangent[seg] + f * track.tangent[(seg + 1) % track.n]
    rel = p - foot[k]
    lateral = tan[0] * rel[1] - tan[1] * rel[0]
    s = jnp.mod((seg.astype(jnp.float32) + f) * track.ds, track.length)
    return Projection(seg.astype(jnp.int32), s, lateral, jnp.arctan2(tan[1], tan[0]))


def project(track: Track, p: jax.Array, seg: jax.Array, window: int = 8) -> Projection:
    """Nearest centre-line point of ``p [2]`` among segments ``seg − window … seg + window``."""
    segs = (jnp.asarray(seg, jnp.int32) + jnp.arange(-window, window + 1, dtype=jnp.int32)) % track.n
    return _project_on(track, p, segs)


def locate(track: Track, p: jax.Array) -> Projection:
    """Nearest centre-line point of ``p [2]`` over the whole track (``M`` segments)."""
    return _project_on(track, p, jnp.arange(track.n, dtype=jnp.int32))


def ray_window(track: Track, behind: float = 40.0, ahead: float = 260.0) -> tuple[int, int]:
    """Segments behind and ahead of the car that the range finders test, capped so they cover the lap once.

    Static sizes from a concrete ``track`` (not traced).
    """
    ds = float(track.ds)
    nb = int(math.ceil(behind / ds))
    na = int(math.ceil(ahead / ds))
    if nb + na >= track.n:
        return 0, track.n
    return nb, na


def range_finders(
    track: Track,
    p: jax.Array,
    yaw: jax.Array,
    seg: jax.Array,
    angles: jax.Array,
    max_range: float = 200.0,
    window: tuple[int, int] | None = None,
) -> jax.Array:
    """Distances ``[R]`` from ``p [2]`` along the rays at ``yaw + angles [R]`` to the first edge crossing.

    Every ray is intersected with every segment of both edge polylines between ``seg − behind``
    and ``seg + ahead`` (``window``, static; default :func:`ray_window` of a concrete track):
    with ``p + t u = a + λ (b − a)``,
    ``t = ((a − p) × (b − a)) / (u × (b − a))`` and ``λ = ((a − p) × u) / (u × (b − a))``; the
    smallest ``t ≥ 0`` with ``0 ≤ λ ≤ 1`` wins, ``max_range`` when none is closer.
    """
    nb, na = ray_window(track) if window is None else window
    segs = (jnp.asarray(seg, jnp.int32) + jnp.arange(-nb, na, dtype=jnp.int32)) % track.n
    nxt = (segs + 1) % track.n
    a = jnp.concatenate([track.left[segs], track.right[segs]])  # [S, 2]
    b = jnp.concatenate([track.left[nxt], track.right[nxt]])
    theta = yaw + angles
    u = jnp.stack([jnp.cos(theta), jnp.sin(theta)], axis=-1)  # [R, 2]
    e = b - a
    q = a - p

    def cross(x, y):
        return x[..., 0] * y[..., 1] - x[..., 1] * y[..., 0]

    denom = cross(u[:, None, :], e[None])  # [R, S]
    ok = jnp.abs(denom) > 1e-9
    safe = jnp.where(ok, denom, 1.0)
    t = cross(q[None], e[None]) / safe
    lam = cross(q[None], u[:, None, :]) / safe
    hit = ok & (t >= 0.0) & (lam >= 0.0) & (lam <= 1.0)
    return jnp.minimum(jnp.min(jnp.where(hit, t, jnp.inf), axis=1), max_range)
