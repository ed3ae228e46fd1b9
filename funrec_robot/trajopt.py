"""Base placement by nonlinear optimisation in casadi (IPOPT): where the mobile base stands while the arm
moves the handle.

One or more base poses (x, y, yaw) each serve a stretch of the handle path: every wrist target of a stretch
stays within [r_min, r_max] of the shoulder (cost: distance from a well-conditioned mid-range, plus facing
the targets), the robot's floor discs stay clear of the furniture footprints and of the volume the part
sweeps meanwhile, and consecutive poses stay close. Pinocchio's casadi bindings are not in the PyPI wheel,
so the forward kinematics of the base (a planar rigid motion of the shoulder and the discs) is written here.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace

import casadi as ca
import numpy as np
import numpy.typing as npt

from funrec.errors import PlanningError
from funrec.typed import FloatArray, IntArray
from funrec_robot.budget import check_time_limit, remaining_time
from funrec_robot.robot_geometry import Circle
from funrec_robot.scene import Polygon, lower_distances

log = logging.getLogger(__name__)


class PlacementError(PlanningError):
    """No pose of the base stops keeps the handle path within reach and the base clear."""


@dataclass(frozen=True)
class PlacementConfig:
    """Settings of base placement."""

    r_min_fraction: float = 0.3
    """Nearest a wrist target may come to the shoulder, as a fraction of the arm's reach."""
    r_max_fraction: float = 0.95
    """Farthest a wrist target may be from the shoulder, as a fraction of the arm's reach."""
    r_mid_fraction: float = 0.62
    """Preferred shoulder-to-wrist distance (well-conditioned, elbow bent), fraction of the reach."""
    clearance: float = 0.06
    """Gap kept between the robot's floor discs and any footprint, m."""
    sharpness: float = 60.0
    """Sharpness of the smooth maximum over a polygon's edges, 1/m; the constraint subtracts log(edges)/sharpness
    so that it stays conservative."""
    facing_weight: float = 0.3
    """Weight of the facing cost (1 - cos of the angle between the base's x and each wrist target)."""
    move_weight: float = 2.0
    """Weight of the squared distance between consecutive base poses, 1/m^2."""
    max_targets: int = 24
    """Wrist targets per base pose used in the optimisation (evenly subsampled), for speed."""
    grid_radii: tuple[float, ...] = (0.3, 0.45, 0.6, 0.75, 0.9, 1.05)
    """Distances of the initial-guess grid from the targets' centroid, m."""
    grid_angles: int = 24
    """Directions of the initial-guess grid around the targets' centroid."""
    grid_yaw_offsets: tuple[float, ...] = (0.0, -0.6, 0.6)
    """Yaws tried at each grid point relative to facing the centroid, rad."""
    grid_batch: int = 32
    """Grid points whose full score (with the footprints) is computed at a time, best reach first."""
    max_iterations: int = 80
    """IPOPT iteration limit."""
    violation_tolerance: float = 1e-3
    """Largest summed constraint violation accepted (m^2 for reach, m for clearance: about a millimetre)."""
    active_radius: float = 0.5
    """IPOPT sees only the footprints within this distance of the robot's discs at the poses tried so far (the
    grid's best guess first), m: furniture further away cannot bind in the few decimetres IPOPT moves the base.
    The solution is then checked against every footprint; one it violates adds the footprints near the solution
    and IPOPT runs again from there (``active_rounds``). Fewer constraints: a kitchen's far side and the small
    objects on its shelves no longer enter each iteration's Hessian."""
    active_rounds: int = 3
    """Most IPOPT runs with a grown set of footprints before the full set is used."""


@dataclass(frozen=True)
class PlacementProblem:
    """Base placement for one handle path (all in the world frame of the scene, z up)."""

    wrist_world: FloatArray
    """(K, 3) wrist-centre targets along the path (grasp point minus approach times the wrist-to-grasp length), m."""
    stretch: IntArray
    """(K,) index of the base pose that serves each target, 0..B-1, non-decreasing."""
    base_free: tuple[bool, bool, bool]
    """Which of x, y, yaw the robot can choose."""
    base_fixed: FloatArray
    """(3,) values of the coordinates it cannot choose (x, y in m, yaw in rad)."""
    p_base_shoulder: FloatArray
    """(3,) shoulder centre in the base frame, m."""
    reach: float
    """Shoulder-to-wrist reach at full stretch, m."""
    base_circles: tuple[Circle, ...]
    """Discs covering the robot body (kept clear at every base pose)."""
    arm_circles: tuple[Circle, ...]
    """Discs covering the arm at home (kept clear at the first base pose, where the robot arrives)."""
    static: tuple[Polygon, ...]
    """Footprints of the furniture (everything but the moving part)."""
    sweep: tuple[tuple[Polygon, ...], ...]
    """Per base pose, footprints of the moving part while the base stands there."""
    start_part: tuple[Polygon, ...]
    """Footprints of the moving part at the start state (for the arm at home)."""
    reach_yaw: float = 0.0
    """Direction the arm reaches in, relative to the base's x, rad (``RobotGeometry.reach_yaw``): the facing
    cost turns it towards the targets."""
    reach_min: float = 0.0
    """Nearest the wrist comes to the shoulder when the arm's shape sets it (a telescoping arm drawn in), m;
    0: ``PlacementConfig.r_min_fraction`` of the reach (an elbow folding)."""
    rolling: bool = False
    """The stops share one heading and lie on one line along it: a differential drive rolls straight from one
    to the next (its wheels cannot move it sideways)."""
    passing: tuple[tuple[FloatArray, tuple[Polygon, ...]], ...] = ()
    """The base on its way between stops while the part moves: (B,) weights of the stops' poses (the base's pose
    is their weighted sum) and the footprints of the moving part it keeps clear of there."""
    stretch_sweep: tuple[tuple[Polygon, ...], ...] = ()
    """Per base pose, footprints of the moving part over the states of its stretch and of the next one: the
    conservative placement, in which each stop keeps clear of those whatever the base does on its way, is solved
    first (one convex footprint per geom: IPOPT slides round it where it stuck between the windows' pieces)."""

    def window(self, config: PlacementConfig) -> tuple[float, float, float]:
        """(r_min, r_max, r_mid): the wrist distances from the shoulder allowed and preferred, m."""
        r_min = self.reach_min if self.reach_min > 0.0 else self.reach * config.r_min_fraction
        r_max = self.reach * config.r_max_fraction
        return r_min, r_max, max(self.reach * config.r_mid_fraction, (r_min + r_max) / 2.0 if self.reach_min > 0.0 else 0.0)

    @property
    def bases(self) -> int:
        return int(self.stretch.max()) + 1


@dataclass(frozen=True)
class BasePlacement:
    """Result of :func:`place_base`."""

    poses: FloatArray
    """(B, 3) base poses x, y (m), yaw (rad) in the world frame."""
    cost: float
    """Final cost."""
    clearance: float
    """Smallest gap between a robot disc and a footprint (exact polygon distance, lower bound), m."""
    distances: FloatArray
    """(K,) shoulder-to-wrist distance of every target from its base pose, m."""


def _overlap(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return a[0] < b[1] and b[0] < a[1]


SOFT_CLIP_M = (-2.0, 0.5)
"""Edge distances are clipped to this interval before the smooth maximum (keeps exp finite). Clipping from
above only lowers the bound; from below it matters only 2 m deep inside a footprint, where the constraint is
violated anyway."""


@dataclass(frozen=True)
class _PolygonStack:
    """All edges of several polygons, for one matrix expression of their soft distances."""

    A: FloatArray  # (E, 2)
    b: FloatArray  # (E,)
    S: ca.DM  # (P, E) sparse 0/1: which edges belong to which polygon
    log_edges: FloatArray  # (P,)

    @staticmethod
    def of(polygons: tuple[Polygon, ...]) -> _PolygonStack | None:
        if not polygons:
            return None
        counts = [p.A.shape[0] for p in polygons]
        rows = np.repeat(np.arange(len(polygons)), counts)
        S = ca.DM(ca.Sparsity.triplet(len(polygons), len(rows), rows.tolist(), list(range(len(rows)))), 1.0)
        return _PolygonStack(
            A=np.vstack([p.A for p in polygons]),
            b=np.concatenate([p.b for p in polygons]),
            S=S,
            log_edges=np.log(np.array(counts, dtype=np.float64)),
        )


def _soft_distances(stack: _PolygonStack, centres: ca.MX, sharpness: float) -> ca.MX:
    """(P, C) smooth lower bounds of the distances from C points (2, C) to P convex polygons."""
    d = ca.mtimes(ca.DM(stack.A), centres) - ca.repmat(ca.DM(stack.b), 1, centres.shape[1])
    d = ca.fmin(ca.fmax(d, SOFT_CLIP_M[0]), SOFT_CLIP_M[1])
    lse = ca.log(ca.mtimes(stack.S, ca.exp(sharpness * d))) / sharpness
    return lse - ca.repmat(ca.DM(stack.log_edges), 1, centres.shape[1]) / sharpness


def _rotation(yaw: ca.MX) -> ca.MX:
    c, s = ca.cos(yaw), ca.sin(yaw)
    return ca.vertcat(ca.horzcat(c, -s), ca.horzcat(s, c))


class _Terms:
    """Symbolic costs and constraints of the placement."""

    def __init__(self) -> None:
        self.cost: ca.MX = ca.MX(0)
        self.g: list[ca.MX] = []
        self.lbg: list[FloatArray] = []
        self.ubg: list[FloatArray] = []

    def add(self, g: ca.MX, low: npt.ArrayLike, high: npt.ArrayLike) -> None:
        n = g.numel()
        self.g.append(ca.vec(g))
        self.lbg.append(np.broadcast_to(np.asarray(low, dtype=np.float64), (n,)).ravel())
        self.ubg.append(np.broadcast_to(np.asarray(high, dtype=np.float64), (n,)).ravel())

    def extend(self, other: _Terms) -> None:
        self.cost += other.cost
        self.g += other.g
        self.lbg += other.lbg
        self.ubg += other.ubg

    def bounds(self) -> tuple[FloatArray, FloatArray]:
        return np.concatenate(self.lbg), np.concatenate(self.ubg)


def _relevant(polygons: tuple[Polygon, ...], circles: tuple[Circle, ...], region: FloatArray, radius: float) -> tuple[Polygon, ...]:
    """The polygons whose height overlaps the discs' and that come within ``radius`` of a region point."""
    banded = [polygon for polygon in polygons if any(_overlap(c.z_band, polygon.z_band) for c in circles)]
    near = lower_distances(banded, region).min(axis=0, initial=np.inf) <= radius
    return tuple(polygon for polygon, keep in zip(banded, near) if keep)


def _clearance_terms(
    terms: _Terms, pose: ca.MX, circles: tuple[Circle, ...], polygons: tuple[Polygon, ...], config: PlacementConfig
) -> None:
    if not circles or not polygons:
        return
    for band in sorted({c.z_band for c in circles}):
        group = [c for c in circles if c.z_band == band]
        stack = _PolygonStack.of(tuple(p for p in polygons if _overlap(band, p.z_band)))
        if stack is None:
            continue
        centres = ca.repmat(pose[:2], 1, len(group)) + ca.mtimes(_rotation(pose[2]), ca.DM(np.array([c.centre_base for c in group]).T))
        radii = np.array([c.radius for c in group])
        soft = _soft_distances(stack, centres, config.sharpness)
        low = np.tile(radii + config.clearance, (stack.S.shape[0], 1))
        terms.add(soft, low.ravel(order="F"), np.inf)


def _near(polygons: tuple[Polygon, ...], circles: tuple[Circle, ...], poses: FloatArray | None, radius: float) -> tuple[Polygon, ...]:
    """The polygons that come within ``radius`` of one of the discs at one of the (P, 3) base poses (all of them
    when ``poses`` is None); the distance is a lower bound, so a polygon is kept rather than dropped."""
    if poses is None or not polygons:
        return polygons
    centres, radii = [], []
    for pose in np.atleast_2d(poses):
        c, s = np.cos(pose[2]), np.sin(pose[2])
        R = np.array([[c, -s], [s, c]])
        centres += [pose[:2] + R @ circle.centre_base for circle in circles]
        radii += [circle.radius for circle in circles]
    centres_xy, reach = np.array(centres), np.array(radii) + radius
    near = np.any(lower_distances(polygons, centres_xy) < reach[:, None], axis=0)
    return tuple(p for p, keep in zip(polygons, near) if keep)


def _base_terms(
    problem: PlacementProblem, b: int, pose: ca.MX, config: PlacementConfig, near: FloatArray | None = None
) -> _Terms:
    """Costs and constraints of base stop ``b``; with ``near`` (P, 3) poses, only the footprints near them."""
    terms = _Terms()
    targets = _targets(problem, b, config)
    R = _rotation(pose[2])
    shoulder_xy = pose[:2] + ca.mtimes(R, ca.DM(problem.p_base_shoulder[:2]))
    r_min, r_max, r_mid = problem.window(config)
    heading = ca.vertcat(ca.cos(pose[2] + problem.reach_yaw), ca.sin(pose[2] + problem.reach_yaw))
    dxy = ca.DM(targets[:, :2].T) - ca.repmat(shoulder_xy, 1, len(targets))  # (2, K)
    dz2 = ca.DM((targets[:, 2] - problem.p_base_shoulder[2]) ** 2).T  # (1, K)
    horizontal2 = ca.sum1(dxy**2)
    d2 = horizontal2 + dz2
    terms.add(d2, r_min**2, r_max**2)  # the first constraint: _stop_functions relies on it
    terms.cost += ca.sumsqr(ca.sqrt(d2 + 1e-9) - r_mid) / len(targets)
    along = ca.mtimes(heading.T, dxy)  # (1, K) how far out along the arm's reach direction each target lies
    facing = along / ca.sqrt(horizontal2 + 1e-6)
    terms.cost += config.facing_weight * ca.sum2(1.0 - facing) / len(targets)
    if problem.reach_min > 0.0:
        # A telescoping arm drawn in still holds its wrist ``reach_min`` out along its slide, whatever lies ahead of
        # or behind the base (rolling serves that): the distance from the shoulder alone let Stretch 3's stops stand
        # where a fridge's bar came within a few centimetres of the base's line, the telescope drew in to its
        # limit, and the IK missed the bar (dark_rev_fridge_00_r3: no plan after the 10 s budget).
        terms.add(along, problem.reach_min, np.inf)
    region = targets[:, :2]
    window = r_max + max(float(np.linalg.norm(c.centre_base)) + c.radius for c in problem.base_circles + problem.arm_circles)
    window += float(np.linalg.norm(problem.p_base_shoulder[:2])) + config.clearance
    polygons = _relevant(problem.static + problem.sweep[b], problem.base_circles, region, window)
    _clearance_terms(terms, pose, problem.base_circles, _near(polygons, problem.base_circles, near, config.active_radius), config)
    if b == 0:
        polygons = _relevant(problem.static + problem.start_part, problem.arm_circles, region, window)
        _clearance_terms(terms, pose, problem.arm_circles, _near(polygons, problem.arm_circles, near, config.active_radius), config)
    return terms


def _targets(problem: PlacementProblem, b: int, config: PlacementConfig) -> FloatArray:
    mine = problem.wrist_world[problem.stretch == b]
    if len(mine) > config.max_targets:
        mine = mine[np.round(np.linspace(0, len(mine) - 1, config.max_targets)).astype(int)]
    return mine


def _grid(problem: PlacementProblem, b: int, config: PlacementConfig) -> FloatArray:
    """(N, 3) initial guesses around the centroid of a stretch's targets."""
    centroid = _targets(problem, b, config)[:, :2].mean(axis=0)
    angles = np.linspace(0.0, 2 * np.pi, config.grid_angles, endpoint=False)
    guesses = []
    for radius in config.grid_radii:
        for angle in angles:
            xy = centroid + radius * np.array([np.cos(angle), np.sin(angle)])
            for offset in config.grid_yaw_offsets:
                yaw = angle + np.pi + offset - problem.reach_yaw
                pose = np.where(problem.base_free, [xy[0], xy[1], yaw], problem.base_fixed)
                guesses.append(pose)
    return np.unique(np.round(np.array(guesses), 9), axis=0)


def _violation(g: FloatArray, lbg: FloatArray, ubg: FloatArray) -> FloatArray:
    return np.maximum(lbg[:, None] - g, 0.0).sum(axis=0) + np.maximum(g - ubg[:, None], 0.0).sum(axis=0)


def _best_guess(problem: PlacementProblem, b: int, functions: tuple[ca.Function, ca.Function], terms: _Terms,
                config: PlacementConfig) -> FloatArray:
    """The grid point of stop ``b`` with the least cost plus ``1e3`` times its constraint violation.

    ``functions`` map a pose to (cost, constraints) and to (cost, reach constraints). The reach alone is cheap
    (a few dozen targets against hundreds of footprint constraints) and its score is a lower bound of the full
    one, so the full score is computed only for the grid points whose bound can still beat the best found,
    in batches of ``grid_batch`` in the order of their bounds: the same point as scoring the whole grid.
    """
    full, reach = functions
    grid = _grid(problem, b, config)
    cost, g = reach.map(len(grid))(grid.T)
    lbg, ubg = terms.bounds()
    n = g.shape[0]
    bound = np.asarray(cost).ravel() + 1e3 * _violation(np.asarray(g), lbg[:n], ubg[:n])
    order = np.argsort(bound, kind="stable")
    best, best_score = int(order[0]), np.inf
    for start in range(0, len(order), config.grid_batch):
        if bound[order[start]] >= best_score:
            break
        batch = order[start : start + config.grid_batch]
        cost, g = full.map(len(batch))(grid[batch].T)
        score = np.asarray(cost).ravel() + 1e3 * _violation(np.asarray(g), lbg, ubg)
        if score.min() < best_score:
            best, best_score = int(batch[int(np.argmin(score))]), float(score.min())
    return grid[best]


def _gap(pose: FloatArray, circles: tuple[Circle, ...], polygons: tuple[Polygon, ...]) -> float:
    """Smallest (lower-bound) gap between the discs at a base pose and the polygons of their height, m."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    R = np.array([[c, -s], [s, c]])
    gap = np.inf
    for circle in circles:
        banded = [polygon for polygon in polygons if _overlap(circle.z_band, polygon.z_band)]
        if banded:
            gap = min(gap, float(lower_distances(banded, pose[:2] + R @ circle.centre_base).min()) - circle.radius)
    return gap


def exact_clearance(
    poses: npt.ArrayLike, problem: PlacementProblem
) -> float:
    """Smallest (lower-bound) gap between the robot's discs and the footprints at the given base poses and on
    the way between them (``PlacementProblem.passing``), m."""
    poses = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    gap = np.inf
    for b, pose in enumerate(poses):
        gap = min(gap, _gap(pose, problem.base_circles, problem.static + problem.sweep[b]))
        if b == 0:
            gap = min(gap, _gap(pose, problem.arm_circles, problem.static + problem.start_part))
    for weights, footprints in problem.passing:
        gap = min(gap, _gap(weights @ poses, problem.base_circles, footprints))
    return gap


def _stop_functions(
    problem: PlacementProblem, b: int, config: PlacementConfig, near: FloatArray | None
) -> tuple[tuple[ca.Function, ca.Function], _Terms]:
    """Base stop ``b``'s cost and constraints as a function of its pose, the same with its reach constraints
    alone (the first of its terms), and its terms (for the bounds)."""
    pose = ca.MX.sym(f"pose{b}", 3)
    own = _base_terms(problem, b, pose, config, near)
    full = ca.Function(f"base{b}", [pose], [own.cost, ca.vertcat(*own.g)])
    return (full, ca.Function(f"reach{b}", [pose], [own.cost, own.g[0]])), own


def _assemble(problem: PlacementProblem, x: ca.MX, config: PlacementConfig, near: list[FloatArray] | None) -> _Terms:
    """The whole placement on the stacked poses ``x``: every stop's terms, the moves between stops and the
    clearance half-way; with ``near`` (per stop, (P, 3) poses), only the footprints near those poses."""
    B = problem.bases
    poses = [x[3 * b : 3 * b + 3] for b in range(B)]
    terms = _Terms()
    for b in range(B):
        (f, _), own = _stop_functions(problem, b, config, None if near is None else near[b])
        cost_b, g_b = f(poses[b])
        terms.cost += cost_b
        terms.add(g_b, *own.bounds())
    for b in range(1, B if problem.rolling else 0):  # on the first stop's line of travel, at its heading
        yaw = poses[0][2]
        terms.add(poses[b][2] - yaw, 0.0, 0.0)
        terms.add(-ca.sin(yaw) * (poses[b][0] - poses[0][0]) + ca.cos(yaw) * (poses[b][1] - poses[0][1]), 0.0, 0.0)
    for b in range(B - 1):
        terms.cost += config.move_weight * ca.sumsqr(poses[b + 1][:2] - poses[b][:2])
        region = _targets(problem, b + 1, config)[:, :2]
        # Half-way between stops (posed without ``passing``: clear of the part over the next stop's footprints).
        polygons = _relevant(problem.static + (() if problem.passing else problem.sweep[b + 1]), problem.base_circles, region, 2.0)
        if near is not None:
            polygons = _near(polygons, problem.base_circles, (near[b] + near[b + 1]) / 2.0, config.active_radius)
        _clearance_terms(terms, (poses[b] + poses[b + 1]) / 2, problem.base_circles, polygons, config)
    for weights, footprints in problem.passing:  # the base on its way between stops, the part moving on
        polygons = footprints
        if near is not None:
            polygons = _near(polygons, problem.base_circles, sum(w * n for w, n in zip(weights, near)), config.active_radius)
        pose = sum((float(w) * p for w, p in zip(weights, poses) if w > 0.0), ca.MX.zeros(3))
        _clearance_terms(terms, pose, problem.base_circles, polygons, config)
    return terms


def _ipopt(x: ca.MX, terms: _Terms, x0: FloatArray, lbx: FloatArray, ubx: FloatArray, config: PlacementConfig) -> tuple[FloatArray, float, float]:
    """IPOPT from ``x0``; returns the solution, its cost and its violation of ``terms``' constraints."""
    lbg, ubg = terms.bounds()
    solver = ca.nlpsol(
        "placement",
        "ipopt",
        {"x": x, "f": terms.cost, "g": ca.vertcat(*terms.g)},
        {
            "ipopt.print_level": 0,
            "print_time": False,
            "ipopt.sb": "yes",
            "ipopt.max_iter": config.max_iterations,
            # 1e-6 is ample for a violation bound of 1e-3. (An adaptive barrier parameter took 2-3 times fewer
            # iterations but ended in other local optima, from which Spot missed 4 handle paths of 22 by millimetres.)
            "ipopt.tol": 1e-6,
            **({} if remaining_time() is None else {"ipopt.max_cpu_time": max(remaining_time(), 1e-3)}),
        },
    )
    check_time_limit("base placement")
    result = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    check_time_limit("base placement")
    g_value = np.asarray(result["g"]).ravel()
    return np.asarray(result["x"]).ravel(), float(result["f"]), float(_violation(g_value[:, None], lbg, ubg)[0])


def _initial_guess(problem: PlacementProblem, config: PlacementConfig) -> FloatArray:
    """(3 B,) each stop's best grid point, on the first's line of travel for a differential drive."""
    B = problem.bases
    x0 = np.concatenate([_best_guess(problem, b, *_stop_functions(problem, b, config, None), config) for b in range(B)])
    if problem.rolling:  # the other stops' guesses moved onto the first's line of travel
        heading = np.array([np.cos(x0[2]), np.sin(x0[2])])
        for b in range(1, B):
            x0[3 * b : 3 * b + 2] = x0[:2] + heading * float(heading @ (x0[3 * b : 3 * b + 2] - x0[:2]))
            x0[3 * b + 2] = x0[2]
    return x0


def _violation_of(x: ca.MX, terms: _Terms) -> Callable[[FloatArray], float]:
    """The largest violation of ``terms``' constraints at a solution of ``x``."""
    g = ca.Function("g", [x], [ca.vertcat(*terms.g)])
    lbg, ubg = terms.bounds()
    return lambda solution: float(_violation(np.asarray(g(solution)), lbg, ubg)[0])


def _refine(problem: PlacementProblem, x: ca.MX, full: _Terms, x0: FloatArray, config: PlacementConfig) -> tuple[FloatArray, float, float]:
    """IPOPT from ``x0`` against the footprints near it, grown until the solution clears them all
    (``PlacementConfig.active_radius``); returns the solution, its cost and its violation of ``full``."""
    B = problem.bases
    full_violation = _violation_of(x, full)
    free = np.tile(problem.base_free, B)
    fixed = np.tile(problem.base_fixed, B)
    lbx = np.where(free, -np.inf, fixed)
    ubx = np.where(free, np.inf, fixed)
    near = [x0[3 * b : 3 * b + 3][None, :] for b in range(B)]
    start = x0
    for round_ in range(config.active_rounds + 1):
        last = round_ == config.active_rounds
        solution, cost, violation = _ipopt(x, full if last else _assemble(problem, x, config, near), start, lbx, ubx, config)
        if violation > config.violation_tolerance or last:
            break  # the footprints left out only add constraints: the full problem is no more feasible here
        violation = full_violation(solution)
        if violation <= config.violation_tolerance:
            break
        near = [np.vstack([near[b], solution[3 * b : 3 * b + 3]]) for b in range(B)]
        start = solution
    return solution, cost, violation


def place_base(problem: PlacementProblem, config: PlacementConfig = PlacementConfig()) -> BasePlacement:
    """Optimise the base poses of a handle path.

    Each pose starts from the best point of a grid around its targets' centroid (the problem has one
    basin per side of the furniture), then all poses are refined together by IPOPT, first against the
    footprints near the guess (``PlacementConfig.active_radius``), grown until the solution clears them all;
    with stops to move between, first from the conservative placement (``PlacementProblem.stretch_sweep``).

    Raises:
        PlanningError: IPOPT finds no pose that satisfies the reach and clearance constraints; the message
            gives the remaining violation and the closest target distances.
    """
    B = problem.bases
    x = ca.MX.sym("x", 3 * B)
    full = _assemble(problem, x, config, None)
    solution, cost, violation = np.zeros(3 * B), np.inf, np.inf
    if problem.passing and problem.stretch_sweep:
        # First the conservative placement: each stop clear of the part over its stretch and the next, whatever the
        # base does on its way (where IPOPT found the placements of the scenes tuned on), then from there the
        # placement itself. Started from the guesses with the base's way checked at once, IPOPT stuck in the door's
        # sweep where the conservative placement is a placement (TIAGo, dark_rev_fridge_00_r1: 2 stops).
        stretched = replace(problem, sweep=problem.stretch_sweep, passing=())
        conservative = _refine(stretched, x, _assemble(stretched, x, config, None), _initial_guess(stretched, config), config)
        if conservative[2] <= config.violation_tolerance:
            # Kept as it is where it also clears the base's way between stops (the placements tuned on stay where
            # they were), else refined from there.
            solution, violation = conservative[0], _violation_of(x, full)(conservative[0])
            cost = float(ca.Function("f", [x], [full.cost])(solution))
            if violation > config.violation_tolerance:
                solution, cost, violation = _refine(problem, x, full, conservative[0], config)
    if violation > config.violation_tolerance:
        # Each stop clear of the part only while the base stands there (a fridge door swinging towards a side wall
        # leaves the conservative placement no room), the base's way between stops checked.
        solution, cost, violation = _refine(problem, x, full, _initial_guess(problem, config), config)
    poses_out = solution.reshape(B, 3)
    poses_out[:, 2] = np.where(problem.base_free[2], np.angle(np.exp(1j * poses_out[:, 2])), poses_out[:, 2])
    distances = _distances(problem, poses_out)
    if violation > config.violation_tolerance:
        r_min, r_max, _ = problem.window(config)
        raise PlacementError(
            f"base placement: no pose of {B} base stop(s) keeps the handle path within reach and the base clear "
            f"(constraint violation {violation:.3g}; wrist distances {distances.min():.2f}-{distances.max():.2f} m "
            f"for a reach window [{r_min:.2f}, {r_max:.2f}] m; clearance {exact_clearance(poses_out, problem):.3f} m)"
        )
    log.debug("base placement %s cost %.4f", np.round(poses_out, 3).tolist(), cost)
    return BasePlacement(
        poses=poses_out,
        cost=cost,
        clearance=exact_clearance(poses_out, problem),
        distances=distances,
    )


def _distances(problem: PlacementProblem, poses: FloatArray) -> FloatArray:
    out = np.empty(len(problem.wrist_world))
    for k, (w, b) in enumerate(zip(problem.wrist_world, problem.stretch)):
        c, s = np.cos(poses[b, 2]), np.sin(poses[b, 2])
        shoulder = np.array([
            poses[b, 0] + c * problem.p_base_shoulder[0] - s * problem.p_base_shoulder[1],
            poses[b, 1] + s * problem.p_base_shoulder[0] + c * problem.p_base_shoulder[1],
            problem.p_base_shoulder[2],
        ])
        out[k] = np.linalg.norm(w - shoulder)
    return out


__all__ = ["BasePlacement", "PlacementConfig", "PlacementError", "PlacementProblem", "exact_clearance", "place_base"]
