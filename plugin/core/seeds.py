"""The seed rule: a random seed is a whole number 0 .. 2^31 - 1 (QGIS reads a seed with
parameterAsInt, a 32-bit int: larger values would wrap silently; numpy refuses negative
seeds). One rule for the QGIS algorithms (``AlgorithmBase.add_seed``) and the command line.

A block's own random numbers come from the seed and where the block lies
(:func:`place_key`), not from its position in the layer: the same block gets the same lots
and footprints whichever other blocks are selected with it, in whatever order.

>>> check_seed(7)
7
>>> try:
...     check_seed(-1)
... except InputError as exc:
...     print(exc)
--seed must be a whole number from 0 to 2147483647, not -1
"""
from __future__ import annotations

import math

from .progress import InputError

__all__ = ["MAX_SEED", "check_seed", "place_key"]

#: Seeds are 32-bit integers in QGIS (parameterAsInt): larger values would wrap silently.
MAX_SEED = 2 ** 31 - 1


def check_seed(seed, name: str = "--seed") -> int:
    """``seed`` as an int when it is a whole number 0 .. MAX_SEED, else InputError naming
    ``name``."""
    try:
        whole = int(seed) == seed
    except (TypeError, ValueError, OverflowError):
        whole = False
    if not whole or not 0 <= int(seed) <= MAX_SEED:
        raise InputError(f"{name} must be a whole number from 0 to {MAX_SEED}, not {seed}")
    return int(seed)


def place_key(geometry) -> list:
    """Four whole numbers that name where ``geometry`` lies: its bounds floored to the metre
    (exact whichever way its rings run or where they start; a centroid is not), for
    ``numpy.random.default_rng([seed, *place_key(block)])``.

    >>> import shapely
    >>> place_key(shapely.box(-0.5, 10.2, 30, 40.9))
    [4294967295, 10, 30, 40]
    """
    if geometry is None or geometry.is_empty:
        return [0, 0, 0, 0]
    return [int(math.floor(v)) % 2 ** 32 for v in geometry.bounds]
