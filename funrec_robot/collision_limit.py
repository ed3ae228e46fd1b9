"""mink's collision avoidance limit with a broad phase that knows boxes.

mink culls a geom pair when the two geoms' bounding spheres are further apart than the detection distance.
Furniture is made of boxes whose bounding spheres are large (a counter top's is over a metre), so near a
kitchen nearly every robot-furniture pair reaches the narrow phase (``mj_geomDistance``) at every IK step:
Stretch 3 in front of a cabinet measured about 270 narrow-phase calls per step, more than half of the plan's
time. Here each geom is held in a world-axis box (around its oriented bounding box, MuJoCo's ``geom_aabb``,
cut to the box around its bounding sphere) and a pair is culled when the gap between the two boxes exceeds the
detection distance. That gap is a lower bound of the distance between the geoms, so no pair that mink would
constrain is dropped: the constraint rows are mink's, and only the pairs within the detection distance give
rows to the QP (mink gives one row per pair, most of them empty).
"""

from __future__ import annotations

import mink
import mujoco
import numpy as np
import numpy.typing as npt
from mink.limits.collision_avoidance_limit import compute_contact_normal_jacobian
from mink.limits.limit import Constraint

from funrec.typed import FloatArray


class GeomBoxes:
    """The box broad phase of the pairs of several :class:`BoxedCollisionLimit`: each geom's world-axis box is
    measured once per configuration and every pair's gap at once, whichever limit asks first. The IK's four
    limits (base, arm, gripper, wrist; ``WholeBodyIK``) share most geoms, and each measured them again at every
    step: four gathers of ~100 geoms and four calls' overhead, a tenth of Stretch 3's IK step."""

    def __init__(self, model: mujoco.MjModel, pairs: npt.ArrayLike) -> None:
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        self._geoms, inverse = np.unique(pairs, return_inverse=True)
        self._first, self._second = inverse.reshape(-1, 2).T
        aabb = np.asarray(model.geom_aabb).reshape(-1, 6)[self._geoms]
        self._box_centre, self._box_half = aabb[:, :3], aabb[:, 3:]
        self._rbound = np.asarray(model.geom_rbound)[self._geoms]
        # A plane or a height field has no bounding sphere: such a pair is never culled.
        self._unbounded = (self._rbound[self._first] <= 0.0) | (self._rbound[self._second] <= 0.0)
        self._seen: tuple[int, FloatArray] | None = None  # (id of the data, its qpos) the distances were measured at
        self._distances = np.empty(0)

    def lower_distances(self, data: mujoco.MjData) -> FloatArray:
        """(P,) a lower bound of each pair's distance at the configuration in ``data``, m: the gap between
        world-axis boxes that hold each geom (the box around its bounding sphere cut to the box around its
        oriented bounding box). Measured again only when ``data`` or its joint positions changed."""
        if self._seen is not None and self._seen[0] == id(data) and np.array_equal(self._seen[1], data.qpos):
            return self._distances
        xpos = data.geom_xpos[self._geoms]
        R = data.geom_xmat[self._geoms].reshape(-1, 3, 3)
        centre = xpos + np.einsum("kij,kj->ki", R, self._box_centre)
        half = np.einsum("kij,kj->ki", np.abs(R), self._box_half)
        radius = self._rbound[:, None]
        # Coordinate-major (6, K): each pair's boxes are gathered as contiguous rows, on which the gap's few
        # operations run several times faster than on the column slices of (P, 3) arrays (a step gathers
        # thousands of pairs). The same arithmetic in the same order: the same distances, bit for bit.
        bounds = np.vstack([np.maximum(xpos - radius, centre - half).T, np.minimum(xpos + radius, centre + half).T])
        first = np.take(bounds, self._first, axis=1)
        second = np.take(bounds, self._second, axis=1)
        gap = np.maximum(np.maximum(second[:3] - first[3:], first[:3] - second[3:]), 0.0)
        self._distances = np.where(self._unbounded, -np.inf, np.sqrt(gap[0] * gap[0] + gap[1] * gap[1] + gap[2] * gap[2]))
        self._seen = (id(data), data.qpos.copy())
        return self._distances


class BoxedCollisionLimit(mink.CollisionAvoidanceLimit):
    """:class:`mink.CollisionAvoidanceLimit` (same arguments, same constraint rows) with the box-aware broad phase
    (its own, or one shared with other limits: :func:`shared_boxes`), and its bound in the QP's units: a step
    closes at most ``gain`` of the gap beyond the minimum distance (mink 1.3 allows ``gain / dt`` of it)."""

    def __init__(self, model: mujoco.MjModel, geom_pairs: list, recover: bool = False, **kwargs: float) -> None:
        super().__init__(model, geom_pairs, **kwargs)
        self.use_boxes(GeomBoxes(model, self.geom_id_pairs), 0)
        self.recover = recover
        """A pair closer than its floor (the minimum distance, or less where :meth:`hold_from` found it closer) must
        open up again by ``gain`` of its shortfall per step (mink's bound, 0 there, only stops it closing to first
        order; see :meth:`compute_qp_inequalities`)."""
        self.floors = np.full(len(self.geom_id_pairs), self.minimum_distance_from_collisions)
        """(P,) the distance each pair is held at, m."""

    def _construct_geom_id_pairs(self, geom_pairs: list) -> list[tuple[int, int]]:
        """mink's pairs, in mink's order: every geom of one group with every geom of the other, but geoms of one body
        or weld, of a weld and its parent's, and those the contype-conaffinity test rules out, deduplicated through a
        set. Hand-written from mink's, which tests pair by pair in Python: 40 ms of each Stretch 3 plan for its
        ~5000 pairs. The same pairs inserted into the set in the same order, so the same list (and the same QP rows)."""
        model = self.model
        weld = model.body_weldid
        parent_weld = weld[model.body_parentid[weld]]  # by body: the weld of the parent of its weld
        pairs: list[tuple[int, int]] = []
        for group_a, group_b in self._collision_pairs_to_geom_id_pairs(geom_pairs):
            a = np.repeat(np.asarray(group_a, dtype=np.int64), len(group_b))  # itertools.product's order
            b = np.tile(np.asarray(group_b, dtype=np.int64), len(group_a))
            body_a, body_b = model.geom_bodyid[a], model.geom_bodyid[b]
            parent_child = (weld[body_a] == parent_weld[body_b]) | (weld[body_b] == parent_weld[body_a])
            contacts = ((model.geom_contype[a] & model.geom_conaffinity[b]) != 0) | ((model.geom_contype[b] & model.geom_conaffinity[a]) != 0)
            keep = (weld[body_a] != weld[body_b]) & ~parent_child & contacts
            pairs += zip(np.minimum(a, b)[keep].tolist(), np.maximum(a, b)[keep].tolist())
        return list(set(pairs))

    def hold_from(self, data: mujoco.MjData) -> None:
        """Hold each pair at the minimum distance, or at its distance in ``data`` where that is less: a pair that
        starts a solve closer (Fetch's shoulder lift link lies 2 mm from its torso at home) is not pushed open, only
        kept from closing further."""
        self.floors[:] = self.minimum_distance_from_collisions
        for idx in np.flatnonzero(self.lower_distances(data) < self.minimum_distance_from_collisions):
            geom1, geom2 = self.geom_id_pairs[idx]
            dist = mujoco.mj_geomDistance(self.model, data, geom1, geom2, self.minimum_distance_from_collisions, self._fromto)
            self.floors[idx] = min(self.floors[idx], dist)

    def use_boxes(self, boxes: GeomBoxes, first_pair: int) -> None:
        """Take the broad phase from ``boxes``, whose pairs hold this limit's from row ``first_pair`` on."""
        self._boxes, self._pairs = boxes, slice(first_pair, first_pair + len(self.geom_id_pairs))

    def lower_distances(self, data: mujoco.MjData) -> FloatArray:
        """(P,) a lower bound of each of this limit's pairs' distance at the configuration in ``data``, m
        (:meth:`GeomBoxes.lower_distances`)."""
        return self._boxes.lower_distances(data)[self._pairs]

    def compute_qp_inequalities(self, configuration: mink.Configuration, dt: float) -> Constraint:
        model, data = self.model, configuration.data
        distmax, min_dist = self.collision_detection_distance, self.minimum_distance_from_collisions
        rows, bounds = [], []
        for idx in np.flatnonzero(self.lower_distances(data) <= distmax):
            geom1, geom2 = self.geom_id_pairs[idx]
            dist = mujoco.mj_geomDistance(model, data, geom1, geom2, distmax, self._fromto)
            if abs(dist - distmax) < 1e-12:
                continue
            row = compute_contact_normal_jacobian(model, data, geom1, geom2, self._fromto, self._normal, self._jac1, self._jac2)
            # The QP's variable is the step dq = v dt (``G dq <= h``, as mink's configuration and velocity limits
            # bound it): the bound is a distance, a share of the gap per step. mink's own limit divides it by dt
            # once more, which lets a step close 1 / dt = 50 times the gap's share: Spot's open jaw, 6.8 mm from the
            # cabinet row around pri_drawer_00's drawer (1.5 mm kept), closed 7.8 mm in one step and ended its
            # approach 2.5 mm inside the row; the row held it there (at the kept distance the bound is 0).
            # Held at its bound (0 at the minimum distance), a pair still closes at second order: the first-order row
            # is tangent to the gap. Fetch's shoulder lift link, rotating with the shoulder pan about an axis beside
            # the torso, crept 0.1 mm per IK step along a door's path from the 5 mm kept to 0.8 mm inside the torso's
            # 1 mm contact margin; the pan servo then pushed 18-50 N m (of 33.8) against that contact. With
            # ``recover`` the bound below its floor is negative: the pair opens up again.
            if self.recover:
                floor = min(min_dist, float(self.floors[idx]))
                gap = self.gain * (dist - floor) if dist > min_dist or dist < floor else 0.0
            else:
                gap = self.gain * (dist - min_dist) if dist > min_dist else 0.0
            bounds.append(gap + self.bound_relaxation)
            rows.append((-1.0 if dist >= 0 else 1.0) * row)
        if not rows:
            return Constraint()
        return Constraint(G=np.array(rows), h=np.array(bounds))


def shared_boxes(model: mujoco.MjModel, limits: list[BoxedCollisionLimit]) -> list[BoxedCollisionLimit]:
    """The same limits (same pairs and settings) with one :class:`GeomBoxes` over all their pairs."""
    boxes = GeomBoxes(model, [pair for limit in limits for pair in limit.geom_id_pairs])
    first = np.cumsum([0] + [len(limit.geom_id_pairs) for limit in limits])
    for limit, start in zip(limits, first):
        limit.use_boxes(boxes, int(start))
    return limits


__all__ = ["BoxedCollisionLimit", "GeomBoxes", "shared_boxes"]

