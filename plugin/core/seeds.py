"""The seed rule: a random seed is a whole number 0 .. 2^31 - 1 (QGIS reads a seed with
parameterAsInt, a 32-bit int: larger values would wrap silently; numpy refuses negative
seeds). One rule for the QGIS algorithms (``AlgorithmBase.add_seed``) and the command line.

>>> check_seed(7)
7
>>> try:
...     check_seed(-1)
... except InputError as exc:
...     print(exc)
--seed must be a whole number from 0 to 2147483647, not -1
"""
from __future__ import annotations

from .progress import InputError

__all__ = ["MAX_SEED", "check_seed"]

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
