"""Per-item work in threads, results handed out in order.

For stages whose work on one item (a frame, a joint hypothesis) is made of whole-array numpy and
OpenCV operations: those release the GIL, so a second core shares the work, and since every item
is worked on by the same code and its results are used in order, nothing depends on the number
of threads.
"""

from __future__ import annotations

import ctypes
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
    try:
        with ThreadPoolExecutor(max_workers=threads, thread_name_prefix=name) as pool:
            pending: deque[Future[R]] = deque()
            for item in items:
                pending.append(pool.submit(work, item))
                if len(pending) > threads:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
    finally:
        _trim_heaps()


def _trim_heaps() -> None:
    """Hand the memory the worker threads freed back to the system. glibc gives each thread a heap
    of its own and keeps what was freed there; the whole-image temporaries of a few threads kept
    so raised a run's peak resident memory by 130-140 MB (plain_rev_cabinet_right_00,
    plain_pri_drawer_00). Elsewhere (no glibc): nothing to do."""
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


def _glibc() -> ctypes.CDLL | None:
    try:
        libc = ctypes.CDLL("libc.so.6")
        return libc if hasattr(libc, "malloc_trim") else None
    except OSError:
        return None


_LIBC = _glibc()


__all__ = ["in_order"]
