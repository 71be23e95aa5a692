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

__all__ = ["STAGING_PREFIX", "Input", "same_file", "overwrite_error", "geopackage_layers",
           "replaced_layers_error", "make_folders", "remove_empty_folders"]

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


def geopackage_layers(path: Path) -> Optional[List[str]]:
    """The layers (``gpkg_contents`` tables) of the GeoPackage ``path``; None when it is no
    GeoPackage that can be read."""
    import sqlite3

    try:
        with open(path, "rb") as fh:
            if not fh.read(16).startswith(b"SQLite format 3\x00"):
                return None
        # immutable: a reader of a GeoPackage in WAL mode would leave -wal / -shm files
        con = sqlite3.connect(Path(path).resolve().as_uri() + "?mode=ro&immutable=1",
                              uri=True)
        try:
            return [r[0] for r in con.execute("SELECT table_name FROM gpkg_contents")]
        finally:
            con.close()
    except (OSError, sqlite3.DatabaseError):
        return None


def replaced_layers_error(label: str, path: Path, table: Optional[str],
                          writes: Iterable[str], as_layer_hint: bool = True) -> Optional[str]:
    """The message when the output ``label`` would replace the existing GeoPackage ``path``
    whole (``table`` None) and with it layers the output does not write itself, else None.

    ``writes`` are the layers the output makes (those an earlier run of it left may be
    replaced: a run again into the same file); the styles table is the outputs' own.
    QGIS replaces a GeoPackage named without a layer whole: a project GeoPackage given as
    an output lost every other layer in it.

    >>> import sqlite3, tempfile
    >>> gpkg = Path(tempfile.mkdtemp()) / "project.gpkg"
    >>> con = sqlite3.connect(gpkg); _ = con.execute("CREATE TABLE gpkg_contents "
    ...     "(table_name TEXT)"); _ = con.executemany("INSERT INTO gpkg_contents VALUES (?)",
    ...     [("wells",), ("project",)]); con.commit(); con.close()
    >>> replaced_layers_error("Output", gpkg, None, ["project"], False)
    "Output would replace the GeoPackage ... whole, and with it its layer 'wells': nothing is written; choose another file."
    >>> replaced_layers_error("Output", gpkg, "blocks", [], False) is None
    True
    """
    path = Path(path)
    if table is not None or path.suffix.lower() != ".gpkg" or not path.is_file():
        return None
    other = sorted(set(geopackage_layers(path) or ()) - set(writes) - {"layer_styles"})
    if not other:
        return None
    shown = ", ".join(f"'{name}'" for name in other[:5]) + \
        (f" and {len(other) - 5} more" if len(other) > 5 else "")
    return (f"{label} would replace the GeoPackage {path} whole, and with it its "
            f"{'layer' if len(other) == 1 else 'layers'} {shown}: nothing is written; choose "
            "another file" + (", or a new layer of this one for the output "
                              "(ogr:dbname='...' table=\"...\", or 'Save to GeoPackage' in the "
                              "dialog)." if as_layer_hint else "."))


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
