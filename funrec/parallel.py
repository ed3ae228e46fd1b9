"""Per-item work in threads, results handed out in order.

For stages whose work on one item (a frame, a joint hypothesis) is made of whole-array numpy and
OpenCV operations: those release the GIL, so a second core shares the work, and since every item
is worked on by the same code and its results are used in order, nothing depends on the number
of threads.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")


def in_order(work: Callable[[T], R], items: Iterable[T], threads: int, name: str = "funrec-work") -> Iterator[R]:
    """``work(item)`` of each item, handed out in the items' order, worked on by ``threads``
    threads (named ``name``) at most ``threads`` items ahead of the one handed out, so that what
    the work holds per item stays bounded. One thread (or fewer): here, one item at a time."""
    if threads <= 1:
        yield from map(work, items)
        return
    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix=name) as pool:
        pending: deque[Future[R]] = deque()
        for item in items:
            pending.append(pool.submit(work, item))
            if len(pending) > threads:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()


__all__ = ["in_order"]
