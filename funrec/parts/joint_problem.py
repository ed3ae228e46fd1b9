"""The joint-constrained pose graph of stage 5: residuals and sparse Jacobian of the paper's
L(T, l, phi) with every part pose a joint transform T_i = J(a, p, s_i), plus track residuals."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares
from scipy.spatial.transform import RigidTransform

from funrec.geometry.joints import closest_point_on_axis_to_origin, joint_transforms
from funrec.geometry.transforms import invert_transform, rotation_about_axis
from funrec.parts.articulation import PartEstimate
from funrec.typed import BoolArray, FloatArray, IntArray

FD_STEP = 1e-6
"""Central-difference step (rad, m) for the per-edge pose-graph Jacobian: truncation ~1e-12,
round-off ~1e-10 relative, far below the solver tolerances."""


@dataclass(frozen=True)
class PoseEdges:
    """Relative part motions measured by RANSAC, with their information."""

    i: IntArray
    """(E,) position of the first frame in the part's frame list."""
    j: IntArray
    """(E,) position of the second frame."""
    loop: BoolArray
    """(E,) loop closure or consecutive."""
    M: FloatArray
    """(E, 4, 4) measured world-frame motion with p_j = M p_i."""
    centre: FloatArray
    """(E, 3) centroid of the inlier points at frame j: the error is expressed there."""
    sqrt_info: FloatArray
    """(E, 6, 6) L with L^T L = Omega, for exp-coordinate order (rotation, translation)."""


def edge_errors(edges: PoseEdges, delta: FloatArray) -> FloatArray:
    """(E, 6) whitened L log(C^-1 Delta M^-1 C): model motion Delta (E, 4, 4) against the
    measurement, in a frame at the inlier centroid. The paper writes log(T_i^-1 T_j T_i->j);
    this is the same error for a world-frame measurement, up to an adjoint absorbed in Omega."""
    E = delta @ invert_transform(edges.M)
    C = np.tile(np.eye(4), (len(E), 1, 1))
    C[:, :3, 3] = edges.centre
    xi = RigidTransform.from_matrix(invert_transform(C) @ E @ C).as_exp_coords()
    return np.einsum("eij,ej->ei", edges.sqrt_info, xi)


class JointProblem:
    """Residuals and sparse Jacobian of L(phi, l) with T_i = J(a(u), q(w), s_i), plus tracks."""

    def __init__(self, part: PartEstimate, edges: PoseEdges, obs: tuple[IntArray, IntArray, FloatArray] | None,
                 sigma_p: float, loop_regulariser: float, track_weight: float) -> None:
        self.revolute = part.joint_type == "revolute"
        self.a0 = part.axis_world / np.linalg.norm(part.axis_world)
        self.B = np.linalg.svd(np.eye(3) - np.outer(self.a0, self.a0))[0][:, :2]
        self.q0 = part.pivot_world if self.revolute else np.zeros(3)
        self.edges, self.loop_regulariser = edges, loop_regulariser
        self.s_init = part.states.copy()
        used = np.zeros(len(part.frames), dtype=bool)
        used[edges.i] = used[edges.j] = True
        if obs is not None:
            used[obs[0]] = True
        used[0] = False  # canonical state fixed at 0
        self.var = np.flatnonzero(used)
        self.col_of_frame = np.full(len(part.frames), -1)
        self.n_joint = 4 if self.revolute else 2
        self.col_of_frame[self.var] = self.n_joint + np.arange(len(self.var))
        self.n_loop = int(edges.loop.sum())
        self.loop_col = np.full(len(edges.i), -1)
        self.loop_col[edges.loop] = self.n_joint + len(self.var) + np.arange(self.n_loop)
        self.obs = obs
        self.n_tracks = 0 if obs is None else int(obs[1].max()) + 1
        self.x_col0 = self.n_joint + len(self.var) + self.n_loop
        self.track_scale = np.sqrt(track_weight) / sigma_p

    def unpack(self, theta: FloatArray) -> tuple[FloatArray, FloatArray | None, FloatArray, FloatArray, FloatArray]:
        a = self.a0 + self.B @ theta[:2]
        a = a / np.linalg.norm(a)
        q = self.q0 + self.B @ theta[2:4] if self.revolute else None
        s = self.s_init.copy()
        s[0] = 0.0
        s[self.var] = theta[self.n_joint : self.n_joint + len(self.var)]
        b = theta[self.n_joint + len(self.var) : self.x_col0]
        x = theta[self.x_col0 :].reshape(-1, 3)
        return a, q, s, b, x

    def initial(self) -> FloatArray:
        theta = np.zeros(self.x_col0)
        theta[self.n_joint : self.n_joint + len(self.var)] = self.s_init[self.var]
        theta[self.n_joint + len(self.var) :] = 1.0
        if self.obs is None:
            return theta
        f, track, tau = self.obs
        T_inv = invert_transform(joint_transforms(_joint_type(self.revolute), self.a0, self.q0, self.s_init))
        back = np.einsum("nij,nj->ni", T_inv[f, :3, :3], tau) + T_inv[f, :3, 3]
        x = np.stack([np.bincount(track, back[:, k], self.n_tracks) for k in range(3)], -1) / np.bincount(track, minlength=self.n_tracks)[:, None]
        return np.concatenate([theta, x.ravel()])

    def edge_errors_at(self, theta_joint: FloatArray, ds: FloatArray) -> FloatArray:
        a = self.a0 + self.B @ theta_joint[:2]
        a = a / np.linalg.norm(a)
        q = self.q0 + self.B @ theta_joint[2:4] if self.revolute else None
        J = joint_transforms(_joint_type(self.revolute), a, q, ds)
        return edge_errors(self.edges, J)

    def residuals(self, theta: FloatArray) -> FloatArray:
        a, q, s, b, x = self.unpack(theta)
        e = joint_transforms(_joint_type(self.revolute), a, q, s[self.edges.j] - s[self.edges.i])
        err = edge_errors(self.edges, e)
        scale = np.ones(len(err))
        scale[self.edges.loop] = b
        parts = [(err * scale[:, None]).ravel(), np.sqrt(self.loop_regulariser) * (b - 1.0)]
        if self.obs is not None:
            f, track, tau = self.obs
            parts.append(self.track_scale * (self._track_points(a, q, s[f], x[track]) - tau).ravel())
        return np.concatenate(parts)

    def _track_points(self, a: FloatArray, q: FloatArray | None, s: FloatArray, x: FloatArray) -> FloatArray:
        if not self.revolute:
            return x + s[:, None] * a
        v = x - q
        c, sn = np.cos(s)[:, None], np.sin(s)[:, None]
        return v * c + np.cross(a, v) * sn + a * (v @ a)[:, None] * (1 - c) + q

    def track_jacobian(self, theta: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Analytic d(track residual)/d(u, w, s_f, x_l): (n, 3, n_joint), (n, 3), (n, 3, 3)."""
        a, q, s_all, _, x = self.unpack(theta)
        f, track, _ = self.obs
        s, xl = s_all[f], x[track]
        raw = self.a0 + self.B @ theta[:2]
        da_du = (np.eye(3) - np.outer(a, a)) @ self.B / np.linalg.norm(raw)
        n = len(f)
        c, sn = np.cos(s), np.sin(s)
        if self.revolute:
            v = xl - q
            R = rotation_about_axis(a, s)
            Rv = np.einsum("nij,nj->ni", R, v)
            d_s = np.cross(a, Rv)
            d_x = R
            skew_v = _skew(v)
            d_a = -skew_v * sn[:, None, None] + (1 - c)[:, None, None] * (a[None, :, None] * v[:, None, :] + (v @ a)[:, None, None] * np.eye(3))
            d_joint = np.concatenate([d_a @ da_du, (np.eye(3) - R) @ self.B], axis=-1)
        else:
            d_s = np.broadcast_to(a, (n, 3))
            d_x = np.broadcast_to(np.eye(3), (n, 3, 3))
            d_joint = s[:, None, None] * np.broadcast_to(da_du, (n, 3, 2))
        k = self.track_scale
        return k * d_joint, k * d_s, k * d_x, f

    def jacobian(self, theta: FloatArray) -> sp.csr_matrix:
        a, q, s, b, _ = self.unpack(theta)
        ed = self.edges
        ds = s[ed.j] - s[ed.i]
        E = len(ds)
        base = self.edge_errors_at(theta[: self.n_joint], ds)
        d_local = np.zeros((E, 6, self.n_joint + 1))
        for k in range(self.n_joint + 1):
            h = np.zeros(self.n_joint + 1)
            h[k] = FD_STEP
            plus = self.edge_errors_at(theta[: self.n_joint] + h[:-1], ds + h[-1])
            minus = self.edge_errors_at(theta[: self.n_joint] - h[:-1], ds - h[-1])
            d_local[:, :, k] = (plus - minus) / (2 * FD_STEP)
        scale = np.ones(E)
        scale[ed.loop] = b
        d_local *= scale[:, None, None]
        rows_e = np.arange(6 * E).reshape(E, 6)
        R, C, V = [], [], []
        for k in range(self.n_joint):
            R.append(rows_e.ravel())
            C.append(np.full(6 * E, k))
            V.append(d_local[:, :, k].ravel())
        for frames, sign in ((ed.j, 1.0), (ed.i, -1.0)):
            col = self.col_of_frame[frames]
            m = col >= 0
            R.append(rows_e[m].ravel())
            C.append(np.repeat(col[m], 6))
            V.append(sign * d_local[m, :, -1].ravel())
        lp = np.flatnonzero(ed.loop)
        R.append(rows_e[lp].ravel())
        C.append(np.repeat(self.loop_col[lp], 6))
        V.append(base[lp].ravel())
        R.append(6 * E + np.arange(self.n_loop))
        C.append(self.loop_col[lp])
        V.append(np.full(self.n_loop, np.sqrt(self.loop_regulariser)))
        n_rows = 6 * E + self.n_loop
        if self.obs is not None:
            d_joint, d_s, d_x, f = self.track_jacobian(theta)
            track = self.obs[1]
            n = len(f)
            rows_t = n_rows + np.arange(3 * n).reshape(n, 3)
            for k in range(self.n_joint):
                R.append(rows_t.ravel())
                C.append(np.full(3 * n, k))
                V.append(d_joint[:, :, k].ravel())
            col = self.col_of_frame[f]
            m = col >= 0
            R.append(rows_t[m].ravel())
            C.append(np.repeat(col[m], 3))
            V.append(d_s[m].ravel())
            R.append(np.repeat(rows_t, 3, axis=1).ravel())
            C.append((self.x_col0 + 3 * track[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1).ravel())
            V.append(d_x.ravel())
            n_rows += 3 * n
        n_cols = self.x_col0 + 3 * self.n_tracks
        return sp.csr_matrix((np.concatenate(V), (np.concatenate(R), np.concatenate(C))), shape=(n_rows, n_cols))


def _skew(v: FloatArray) -> FloatArray:
    """(..., 3, 3) cross-product matrices [v]x."""
    S = np.zeros((*v.shape[:-1], 3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return S - np.swapaxes(S, -1, -2)


def _joint_type(revolute: bool) -> str:
    return "revolute" if revolute else "prismatic"


def solve_joint(part: PartEstimate, edges: PoseEdges, obs: tuple[IntArray, IntArray, FloatArray] | None, sigma_p: float,
                loop_regulariser: float, track_weight: float, max_evaluations: int
                ) -> tuple[FloatArray, FloatArray | None, FloatArray, FloatArray, FloatArray, int]:
    """Minimise L over (a, p, s, l) [and canonical track points] from the stage-3 joint.

    ``obs`` = (frame positions, track indices 0..M-1, (n, 3) observed points) of the track term
    (None: pose graph only); ``loop_regulariser`` is the paper's mu; ``track_weight`` weighs the
    whitened track residuals against the pose-graph terms.

    Returns axis (3,), pivot (3,) or None, states (F_k,), edge confidences (E,), whitened edge
    errors (E, 6) and the number of residual evaluations.
    """
    problem = JointProblem(part, edges, obs, sigma_p, loop_regulariser, track_weight)
    theta0 = problem.initial()
    lb = np.full(len(theta0), -np.inf)
    ub = np.full(len(theta0), np.inf)
    b_slice = slice(problem.n_joint + len(problem.var), problem.x_col0)
    lb[b_slice], ub[b_slice] = 0.0, 1.0
    res = least_squares(problem.residuals, theta0, jac=problem.jacobian, bounds=(lb, ub), method="trf",
                        tr_solver="lsmr", x_scale="jac", max_nfev=max_evaluations)
    axis, q, states, b, _ = problem.unpack(res.x)
    pivot = None if q is None else closest_point_on_axis_to_origin(axis, q)
    confidence = np.ones(len(edges.i))
    confidence[edges.loop] = b**2
    err = edge_errors(edges, joint_transforms(_joint_type(problem.revolute), axis, q, states[edges.j] - states[edges.i]))
    return axis, pivot, states, confidence, err, int(res.nfev)


__all__ = ["FD_STEP", "JointProblem", "PoseEdges", "edge_errors", "solve_joint"]
