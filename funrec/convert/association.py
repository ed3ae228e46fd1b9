"""Pairing colour and depth frames of unsynchronised streams by nearest timestamp."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from funrec.typed import IntArray


def associate_nearest(t_rgb_s: npt.ArrayLike, t_depth_s: npt.ArrayLike, max_difference_s: float) -> IntArray:
    """Pair each colour frame with at most one depth frame, one-to-one, closest pairs first.

    This is the matching of TUM's ``associate.py`` (greedy on the sorted absolute differences),
    restricted to each colour frame's two temporal neighbours in the depth stream so it runs in
    O(N log N); a farther depth frame is never the closest unused one when its nearer neighbours
    were taken by colour frames even closer to them.

    Args:
        t_rgb_s: (N,) colour timestamps, seconds, increasing.
        t_depth_s: (M,) depth timestamps, seconds, increasing.
        max_difference_s: largest accepted |t_rgb - t_depth|, seconds.

    Returns:
        (N,) index into ``t_depth_s`` of each colour frame's depth frame, -1 where none is within
        ``max_difference_s`` (or the close ones were closer to another colour frame).
    """
    t_rgb = np.asarray(t_rgb_s, dtype=np.float64)
    t_depth = np.asarray(t_depth_s, dtype=np.float64)
    match = np.full(len(t_rgb), -1, dtype=np.int64)
    if len(t_rgb) == 0 or len(t_depth) == 0:
        return match
    right = np.searchsorted(t_depth, t_rgb)
    rgb_idx = np.concatenate([np.arange(len(t_rgb)), np.arange(len(t_rgb))])
    depth_idx = np.concatenate([right - 1, right])
    ok = (depth_idx >= 0) & (depth_idx < len(t_depth))
    rgb_idx, depth_idx = rgb_idx[ok], depth_idx[ok]
    diff = np.abs(t_rgb[rgb_idx] - t_depth[depth_idx])
    keep = diff <= max_difference_s
    rgb_idx, depth_idx, diff = rgb_idx[keep], depth_idx[keep], diff[keep]
    used = np.zeros(len(t_depth), dtype=bool)
    for k in np.argsort(diff, kind="stable"):
        i, j = rgb_idx[k], depth_idx[k]
        if match[i] < 0 and not used[j]:
            match[i] = j
            used[j] = True
    return match


PayloadT = TypeVar("PayloadT")


def stream_pairs(
    items: Iterable[tuple[bool, PayloadT]], match: npt.ArrayLike
) -> Iterator[tuple[int, PayloadT, PayloadT | None]]:
    """Join two interleaved streams into the pairs chosen by :func:`associate_nearest`.

    Only blocks whose partner has not arrived yet are held, so memory stays at the interleaving depth
    of the recording, not its length.

    Args:
        items: ``(is_colour, payload)`` in recording order; colour and depth are counted separately in the
            order of the timestamps passed to :func:`associate_nearest`.
        match: (N,) depth index of each colour item, -1 for none.

    Yields:
        ``(colour index, colour payload, depth payload or None)`` in colour order.
    """
    match = np.asarray(match, dtype=np.int64)
    colour_of_depth = {int(j): i for i, j in enumerate(match) if j >= 0}
    pending_colour: dict[int, PayloadT] = {}
    pending_depth: dict[int, PayloadT] = {}
    counts = [0, 0]
    next_colour = 0
    for is_colour, payload in items:
        index = counts[0 if is_colour else 1]
        counts[0 if is_colour else 1] += 1
        if is_colour:
            pending_colour[index] = payload
        elif index in colour_of_depth:
            pending_depth[colour_of_depth[index]] = payload
        while next_colour in pending_colour and (match[next_colour] < 0 or next_colour in pending_depth):
            yield next_colour, pending_colour.pop(next_colour), pending_depth.pop(next_colour, None)
            next_colour += 1


__all__ = ["associate_nearest", "stream_pairs"]
