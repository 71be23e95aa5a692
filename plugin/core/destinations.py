"""The rule that an output never overwrites an input, for every way of running the engine.

Inputs are never modified (README): an output is refused before anything is written when
it would replace an input file, the GeoPackage layer that is an input, or add a layer to
a file that is read whole (a block database, a model). A new layer beside an input layer
of the same GeoPackage is allowed (the input layer is left as it was).

Used by ``qgis_glue.outputs.destination_error`` (every QGIS algorithm) and by the command
line ``plugin.scale.cli`` (``--out``). Pure Python: no QGIS, no GDAL.

Examples
--------
>>> from pathlib import Path
>>> blocks = Input("--blocks", Path("/no/such/d.gpkg"), "blocks")
>>> overwrite_error("--out", Path("/no/such/d.gpkg"), "footprints", [blocks]) is None
True
>>> print(overwrite_error("--out", Path("/no/such/d.gpkg"), "blocks", [blocks]))
--out would overwrite layer 'blocks' of the input --blocks (/no/such/d.gpkg): inputs are never modified; choose another output file.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, List, Optional

__all__ = ["STAGING_PREFIX", "Input", "same_file", "overwrite_error", "make_folders",
           "remove_empty_folders"]

#: Name prefix of the hidden folders outputs are written in before they are moved into
#: place (``qgis_glue.outputs.OutputStaging``, ``scale.distributed.write_layer``).
STAGING_PREFIX = ".urbansynth-run-"


@dataclass
class Input:
    """A file a run reads: its parameter or option name, its path, and the GeoPackage
    layer read from it (None: the file is read whole, or is a file of one layer)."""

    name: str
    path: Path
    layer: Optional[str]


def same_file(a: Path, b: Path) -> bool:
    """The same file (one inode, or the same resolved path when either is missing)."""
    a, b = Path(a), Path(b)
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
        return a.resolve() == b.resolve()
    except OSError:
        return False


def overwrite_error(label: str, path: Path, table: Optional[str],
                    inputs: Iterable[Input]) -> Optional[str]:
    """The message when the output ``label`` (the file ``path``, its GeoPackage layer
    ``table``, None for the whole file) would modify one of ``inputs``, else None."""
    for source in inputs:
        if not same_file(path, source.path):
            continue
        if table is not None and source.layer is not None and table != source.layer:
            continue                     # another layer of the same GeoPackage
        if table is not None and source.layer is None:
            # a file read whole (a database): a new layer in it modifies it too
            return (f"{label} would write layer '{table}' into the input {source.name} "
                    f"({source.path}), a file read whole: inputs are never modified; "
                    "choose another output file.")
        what = f"layer '{table}' of " if table else ""
        return (f"{label} would overwrite {what}the input {source.name} ({source.path}): "
                "inputs are never modified; choose another output file.")
    return None


def make_folders(folder: Path) -> List[Path]:
    """Create ``folder`` with its missing parents; return the folders created, deepest
    first, for :func:`remove_empty_folders` when the run fails (an output in a new folder
    leaves no empty folder behind). Raises OSError (nothing created is left) when one
    cannot be made.

    >>> import tempfile
    >>> base = Path(tempfile.mkdtemp())
    >>> made = make_folders(base / "a" / "b")
    >>> [folder.name for folder in made]
    ['b', 'a']
    >>> remove_empty_folders(made); (base / "a").exists()
    False
    """
    missing = []
    probe = Path(folder)
    while not probe.exists() and probe != probe.parent:
        missing.append(probe)
        probe = probe.parent
    try:
        Path(folder).mkdir(parents=True, exist_ok=True)
    except OSError:
        remove_empty_folders(missing)
        raise
    return missing


def remove_empty_folders(folders: Iterable[Path]) -> None:
    """Remove each folder (deepest first) when it is empty; leave it otherwise."""
    for folder in folders:
        try:
            Path(folder).rmdir()
        except OSError:
            pass
