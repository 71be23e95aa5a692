"""The identifier rule: a layer's own ids are kept when they are a unique whole number per
feature (block_id of blocks, parcel_id of parcels, a chosen block id field); otherwise
features are numbered 1..n in layer order. One rule for every algorithm and the Dask
runner, so that a block keeps its id from 'Extract city blocks' through parcels,
databases and footprints.

Examples
--------
>>> whole_ids([3, 1, 2]).tolist()
[3, 1, 2]
>>> whole_ids(["7", 8.0]).tolist()
[7, 8]
>>> whole_ids([1.5, 2]) is None, whole_ids([1, 1]) is None, whole_ids([1, None]) is None
(True, True, True)
>>> ids_or_numbers([1, 1]).tolist()
[1, 2]
"""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
import pandas as pd

__all__ = ["as_numbers", "whole_ids", "ids_or_numbers"]


def as_numbers(values: Sequence) -> np.ndarray:
    """Field values as floats; empty, NULL and non-numeric values are NaN."""
    return pd.to_numeric(pd.Series(np.asarray(values, dtype=object)),
                         errors="coerce").to_numpy(dtype=np.float64, na_value=np.nan)


def whole_ids(values: Sequence) -> Optional[np.ndarray]:
    """The values as int64 ids when every one is a whole number and no two are equal, else
    None (never truncated: 1.5 is not an id)."""
    numbers = as_numbers(values)
    if len(numbers) == 0 or not np.isfinite(numbers).all():
        return None
    if (numbers != np.round(numbers)).any() or np.abs(numbers).max() >= 2 ** 53:
        return None
    if len(np.unique(numbers)) != len(numbers):
        return None
    return numbers.astype(np.int64)


def ids_or_numbers(values: Optional[Sequence], n: Optional[int] = None) -> np.ndarray:
    """:func:`whole_ids` of the values, else 1..n (n: the number of features, by default
    the number of values)."""
    ids = None if values is None else whole_ids(values)
    if ids is not None:
        return ids
    return np.arange(1, (len(values) if n is None else n) + 1, dtype=np.int64)
