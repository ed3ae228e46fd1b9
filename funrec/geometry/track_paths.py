"""Statistics of point-track paths: spike filtering, jitter, pairwise rigidity, and how well a
joint explains a track; pure functions on (F, N, 3) track arrays with (F, N) visibility."""

from __future__ import annotations

import numpy as np

from funrec.typed import BoolArray, FloatArray, IntArray


def first_visible(p: FloatArray, vis: BoolArray) -> FloatArray:
    """(N, 3) each track's first visible position (p (F, N, 3), vis (F, N))."""
    return p[np.argmax(vis, axis=0), np.arange(p.shape[1])]


def track_samples(p: FloatArray, vis: BoolArray) -> tuple[IntArray, IntArray, FloatArray]:
    """Visible samples in track-major order: (M,) track, (M,) frame, (M, 3) position; the samples
    of one track are consecutive and in time order."""
    track, frame = np.nonzero(vis.T)
    return track, frame, p[frame, track]


def despike(p: FloatArray, vis: BoolArray) -> FloatArray:
    """(F, N, 3) each visible sample replaced by the median of itself and its visible neighbours
    in time (one before, one after), NaN elsewhere: removes single-frame depth spikes while keeping
    a motion of any speed (of three samples along a monotone path the median is the middle one)."""
    track, frame, q = track_samples(p, vis)
    prev, nxt = q.copy(), q.copy()
    same = track[1:] == track[:-1]
    prev[1:][same] = q[:-1][same]
    nxt[:-1][same] = q[1:][same]
    out = np.full(p.shape, np.nan)
    out[frame, track] = np.median(np.stack([prev, q, nxt]), axis=0)
    return out


def jitter(p: FloatArray, vis: BoolArray) -> FloatArray:
    """(N,) median |p[k+1] - 2 p[k] + p[k-1]| / sqrt(3) over consecutive visible samples: the
    frame-to-frame noise for white noise (a second difference has three times the variance of a
    first difference), blind to smooth motion. 0 for tracks with fewer than three samples."""
    track, _, q = track_samples(p, vis)
    same = track[2:] == track[:-2]
    second = np.linalg.norm(q[2:] - 2.0 * q[1:-1] + q[:-2], axis=1)[same] / np.sqrt(3.0)
    owner = track[2:][same]
    out = np.zeros(vis.shape[1])
    if len(owner):
        # per-track medians: sort by (track, value) and pick each run's middle element
        order = np.lexsort((second, owner))
        owner, second = owner[order], second[order]
        starts = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])
        stops = np.r_[starts[1:], len(owner)]
        lo, hi = starts + (stops - starts - 1) // 2, starts + (stops - starts) // 2
        out[owner[starts]] = 0.5 * (second[lo] + second[hi])
    return out


def distance_spread(p: FloatArray, vis: BoolArray) -> FloatArray:
    """(N, N) standard deviation over shared frames of the distance between two tracks: noise
    level for points of one rigid part, centimetres or more across parts or for the hand."""
    N = p.shape[1]
    s1, s2, n = np.zeros((N, N)), np.zeros((N, N)), np.zeros((N, N))
    for p_f, v_f in zip(p, vis, strict=True):
        q = np.where(v_f[:, None], p_f, 0.0)
        sq = (q**2).sum(1)
        d = np.sqrt(np.maximum(sq[:, None] + sq[None, :] - 2.0 * q @ q.T, 0.0))
        w = np.outer(v_f, v_f)
        s1 += w * d
        s2 += w * d**2
        n += w
    mean = s1 / np.maximum(n, 1)
    return np.where(n >= 2, np.sqrt(np.maximum(s2 / np.maximum(n, 1) - mean**2, 0.0)), np.inf)


def unwrap_per_track(track: IntArray, angle: FloatArray) -> FloatArray:
    """Unwrap angles (M,) along each track's consecutive samples (track-major order)."""
    step = np.diff(angle)
    step = np.where(track[1:] == track[:-1], (step + np.pi) % (2 * np.pi) - np.pi, 0.0)
    out = np.concatenate([[0.0], np.cumsum(step)])
    start = np.r_[True, track[1:] != track[:-1]]
    base = angle[start] - out[start]
    return out + np.repeat(base, np.diff(np.r_[np.flatnonzero(start), len(track)]))


def joint_consistency(p: FloatArray, vis: BoolArray, joint: dict) -> tuple[FloatArray, FloatArray, FloatArray]:
    """How well the joint explains each track's path, and how far the joint moved it.

    A revolute joint keeps a point's distance to the axis and its height along it and changes
    its angle about the axis by the joint state; a prismatic joint keeps its position orthogonal
    to the axis and moves it along the axis by the state. The error is the mean spread of the
    kept coordinates plus, in frames where the part's states are known, the mean deviation of
    the moving coordinate from them (up to the track's own offset; arc length for a revolute
    joint). Tracks seen only where no state is known (the inside of a door after it turned
    edge-on to the camera) are judged by the kept coordinates alone.

    Returns:
        error: (N,) metres (inf for tracks without observations);
        swept: (N,) distance moved by the joint, metres (arc length or travel);
        witnessed: (N,) distance the part's states moved the track while it was seen, metres
            (0 when no state is known in its frames).
    """
    axis = joint["axis"]
    track, frame, q = track_samples(p, vis)
    N = vis.shape[1]
    if joint["joint_type"] == "revolute":
        v = q - joint["pivot"]
        height = v @ axis
        w = v - np.outer(height, axis)
        radius = np.linalg.norm(w, axis=1)
        e1 = np.linalg.svd(np.eye(3) - np.outer(axis, axis))[0][:, 0]
        angle = np.arctan2(np.cross(e1, w) @ axis, w @ e1)
        kept = np.stack([height, radius], 1)
        moving = unwrap_per_track(track, angle)
    else:
        kept = q - np.outer(q @ axis, axis)
        moving = q @ axis
    count = np.bincount(track, minlength=N)
    mean_kept = np.stack([np.bincount(track, kept[:, k], N) for k in range(kept.shape[1])], 1) / np.maximum(count, 1)[:, None]
    spread = np.bincount(track, np.linalg.norm(kept - mean_kept[track], axis=1), N) / np.maximum(count, 1)
    scale = mean_kept[:, 1] if joint["joint_type"] == "revolute" else np.ones(N)
    lo = np.full(N, np.inf)
    hi = np.full(N, -np.inf)
    np.minimum.at(lo, track, moving)
    np.maximum.at(hi, track, moving)
    swept = np.where(count > 0, (hi - lo) * scale, 0.0)
    known = joint["have"] & ~joint["interpolated"]
    at_known = known[frame]
    d = moving - np.nan_to_num(joint["states"])[frame]
    n_known = np.bincount(track[at_known], minlength=N)
    offset = np.zeros(N)
    if at_known.any():
        # per-track median of d: sort by (track, d) and take each run's middle element
        t_k, d_k = track[at_known], d[at_known]
        order = np.lexsort((d_k, t_k))
        t_k, d_k = t_k[order], d_k[order]
        starts = np.flatnonzero(np.r_[True, t_k[1:] != t_k[:-1]])
        stops = np.r_[starts[1:], len(t_k)]
        offset[t_k[starts]] = 0.5 * (d_k[starts + (stops - starts - 1) // 2] + d_k[starts + (stops - starts) // 2])
    # RMS, not mean: a static track seen for 70 frames deviates only in the 8 frames the door
    # moved, and a mean would dilute that to a few millimetres.
    deviation = np.sqrt(np.bincount(track[at_known], (d[at_known] - offset[track[at_known]]) ** 2, N) / np.maximum(n_known, 1))
    error = spread + np.where(n_known >= 2, deviation * scale, 0.0)
    # how far the part moved while the track watched it: the evidence that the track is on it
    s_known = np.nan_to_num(joint["states"])[frame[at_known]]
    lo_s = np.full(N, np.inf)
    hi_s = np.full(N, -np.inf)
    np.minimum.at(lo_s, track[at_known], s_known)
    np.maximum.at(hi_s, track[at_known], s_known)
    witnessed = np.where(n_known > 0, (hi_s - lo_s) * scale, 0.0)
    return np.where(count > 0, error, np.inf), swept, witnessed


__all__ = ["despike", "distance_spread", "first_visible", "jitter", "joint_consistency", "track_samples", "unwrap_per_track"]
