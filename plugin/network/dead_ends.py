"""Steering the dead-end share of a synthesised network towards the example's.

The fidelity issue asks every road synthesis to keep the dead-end share (dead ends among the
nodes of degree != 2, :func:`invariants.dead_end_share`) within ±30 % of the example's. A
method that adds streets one by one cannot aim at that number while it builds, so it ends
with one more pass: while the share, counted as it will be measured, is above the
example's, close dead ends; while it is below, open new ones. This module is the one home of
that rule; each method says what closing and opening are for its streets (the random walk:
one more step from a stub, or a new street from an unreached dead-end point onto the nearest
street; the fragment synthesis: a short link from a dead end onto the nearest street, or
the stem of a T cut short into a cul-de-sac).

References
----------
docs/ARCHITECTURE.md, "Quality measures"; issue 15 (the dead-end share within ±30 % of the
example's). Not in the papers: their syntheses leave the share where the streets put it.
"""
from __future__ import annotations

from typing import Callable, Iterable, Tuple

__all__ = ["steer_share"]


def steer_share(share_now: Callable[[], float], target: float,
                close: Callable[[object], bool], close_candidates: Callable[[], Iterable],
                open_: Callable[[object], bool], open_candidates: Callable[[], Iterable],
                tolerance: float = 0.0) -> Tuple[int, int]:
    """Close dead ends while the share is above ``target``, then open while it is below
    (beyond ``tolerance``, relative: 0 steers to the target itself).

    Parameters
    ----------
    share_now : () -> float, the share as it will be measured, after the changes so far
    target : float, the example's share
    close : candidate -> bool, close one dead end (True when it did)
    close_candidates : () -> iterable, the dead ends to try, in order (called once, before
        the first is closed, even when none needs closing: a method that draws the order
        from its random generator draws it at the same point of its sequence every time)
    open_ : candidate -> bool, open one dead end (True when it did)
    open_candidates : () -> iterable, where to try, in order (called once, after closing)
    tolerance : float, relative: closing stops at ``target * (1 + tolerance)``, opening at
        ``target * (1 - tolerance)`` (a method that changes its streets as little as the
        rule allows steers into the band, with a margin, rather than onto its middle)

    Returns
    -------
    (n_closed, n_opened)

    Examples
    --------
    >>> state = {"dead": 1, "nodes": 10}
    >>> def share():
    ...     return state["dead"] / state["nodes"]
    >>> def open_one(_):
    ...     state["dead"] += 1
    ...     return True
    >>> steer_share(share, 0.3, lambda c: False, lambda: [], open_one, lambda: range(5))
    (0, 2)
    """
    high, low = target * (1 + tolerance), target * (1 - tolerance)
    n_closed = 0
    for c in close_candidates():
        if share_now() <= high:
            break
        n_closed += bool(close(c))
    n_opened = 0
    for c in open_candidates():
        if share_now() >= low:
            break
        n_opened += bool(open_(c))
    return n_closed, n_opened
