"""The command line of the Dask runner (plugin.scale.cli) as a user gets it wrong: outputs
onto inputs, outputs that are no GeoPackage or cannot be written, an existing output file,
a stop half-way, seeds out of range, a scheduler that is not there, --help, progress.

Small inputs built here (a target square and a road near Helsinki); the StreetGAN
subcommand is the fast one, so most runs use it. Runs go through ``cli.main`` in this
process (the exit status is its return value).
"""
import hashlib

import numpy as np
import pyogrio
import pytest
import shapely

from urban_synthesis.plugin.scale import cli, distributed


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    import geopandas as gpd

    tmp = tmp_path_factory.mktemp("cli")
    src = tmp / "inputs.gpkg"
    area = shapely.box(385000, 6671500, 385600, 6672000)
    gpd.GeoDataFrame({"block_id": [1]}, geometry=[area], crs=32635).to_file(
        src, layer="area", driver="GPKG", engine="pyogrio")
    gpd.GeoDataFrame({"highway": ["residential"]},
                     geometry=[shapely.LineString([(385000, 6671700), (385600, 6671700)])],
                     crs=32635).to_file(src, layer="roads", driver="GPKG", engine="pyogrio")
    db = tmp / "db.gpkg"               # any file: refused before it is read
    db.write_bytes(src.read_bytes())
    return dict(src=src, db=db, tmp=tmp)


def _md5(path):
    return hashlib.md5(path.read_bytes()).hexdigest()


def _gan(target, out, *more):
    return ["gan", "--target", str(target), "--tile", "6", "--out", str(out), *more]


def test_out_onto_an_input_is_refused(inputs, capsys):
    """--out naming an input layer, a file read whole (--db) or the first layer of a bare
    GeoPackage path was written anyway: the input layer replaced, or a layer added to the
    block database (exit 0). Now refused before any work, naming option and file."""
    src, db = inputs["src"], inputs["db"]
    before = {p: _md5(p) for p in (src, db)}
    cases = [
        (_gan(f"{src}:area", f"{src}:area"), "overwrite layer 'area' of the input --target"),
        (_gan(str(src), f"{src}:area"), "overwrite layer 'area' of the input --target"),
        (_gan(f"{src}|layername=area", f"{src}|layername=area"), "layer 'area'"),
        (["footprints", "--blocks", f"{src}:area", "--db", str(db), "--out", str(db)],
         "into the input --db"),
        (["footprints", "--blocks", f"{src}:area", "--roads", f"{src}:roads", "--db",
          str(db), "--out", f"{src}:roads"], "overwrite layer 'roads' of the input --roads"),
        (["attributes", "--footprints", f"{src}:area", "--examples", f"{src}:area",
          "--out", f"{src}:area"], "overwrite layer 'area' of the input --footprints"),
    ]
    for argv, message in cases:
        assert cli.main(argv) == 2, argv
        err = capsys.readouterr().err
        assert message in err and ".gpkg)" in err and "never modified" in err, err
    assert {p: _md5(p) for p in (src, db)} == before
    assert pyogrio.list_layers(db)[:, 0].tolist() == ["area", "roads"]


def test_out_is_a_writable_geopackage(inputs, tmp_path, capsys):
    """--out x.shp was written as a GeoPackage named .shp; --out file.gpkg:layer made a
    file literally named 'file.gpkg:layer'; a folder under a file gave a traceback."""
    src = inputs["src"]
    assert cli.main(_gan(f"{src}:area", tmp_path / "roads.shp")) == 2
    assert "does not end in .gpkg" in capsys.readouterr().err
    assert not (tmp_path / "roads.shp").exists()
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    assert cli.main(_gan(f"{src}:area", blocker / "sub" / "roads.gpkg")) == 2
    assert "cannot be written" in capsys.readouterr().err
    # a layer of its own name, in a folder that did not exist
    out = tmp_path / "new" / "deeper" / "out.gpkg"
    assert cli.main(_gan(f"{src}:area", f"{out}:gan_roads", "--quiet")) == 0
    assert pyogrio.list_layers(out)[:, 0].tolist() == ["gan_roads"]
    assert not list(tmp_path.glob("new/deeper/*:*"))
    # same layer name again with another seed: replaced, the other layers kept
    assert cli.main(_gan(f"{src}:area", out, "--quiet")) == 0
    n1 = len(pyogrio.read_dataframe(out, layer="roads"))
    assert cli.main(_gan(f"{src}:area", out, "--quiet", "--seed", "2")) == 0
    assert sorted(pyogrio.list_layers(out)[:, 0].tolist()) == ["gan_roads", "roads"]
    assert len(pyogrio.read_dataframe(out, layer="roads")) > 0 and n1 > 0
    assert [p.name for p in out.parent.iterdir()] == ["out.gpkg"]     # no staging left


def test_an_interrupted_write_leaves_the_output_as_it_was(inputs, tmp_path, monkeypatch,
                                                          capsys):
    """Ctrl-C (or any failure) while the GeoPackage is written left a half-written file in
    place and a traceback; now the file is written under a temporary name and moved into
    place when complete: the existing output is untouched, nothing is left behind, and the
    run ends with one line and exit status 130."""
    import geopandas as gpd

    src = inputs["src"]
    out = tmp_path / "out.gpkg"
    assert cli.main(_gan(f"{src}:area", out, "--quiet")) == 0
    before = _md5(out)
    real = gpd.GeoDataFrame.to_file

    def write_then_interrupt(self, path, *args, **kwargs):
        real(self, path, *args, **kwargs)      # the layer is written ... then Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(gpd.GeoDataFrame, "to_file", write_then_interrupt)
    try:
        rc = cli.main(_gan(f"{src}:area", out, "--seed", "5", "--quiet"))
    except KeyboardInterrupt:
        rc = "KeyboardInterrupt traceback"
    assert rc == 130
    err = capsys.readouterr().err
    assert "interrupted: nothing was written" in err and "Traceback" not in err
    assert _md5(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["out.gpkg"]
    # a new output in a new folder: neither the file nor the folder stays
    fresh = tmp_path / "made" / "fresh.gpkg"
    try:
        rc = cli.main(_gan(f"{src}:area", fresh, "--quiet"))
    except KeyboardInterrupt:
        rc = "KeyboardInterrupt traceback"
    assert rc == 130 and not (tmp_path / "made").exists()


def test_interrupt_during_the_run(inputs, tmp_path, monkeypatch, capsys):
    """Ctrl-C during the computation: exit 130 with one line, no traceback, no output."""
    from urban_synthesis.plugin.roads import streetgan

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(streetgan, "synthesize", interrupted)
    out = tmp_path / "never.gpkg"
    try:
        rc = cli.main(_gan(f"{inputs['src']}:area", out))
    except KeyboardInterrupt:
        rc = "KeyboardInterrupt traceback"
    assert rc == 130 and not out.exists()
    assert "interrupted" in capsys.readouterr().err


@pytest.mark.parametrize("seed", ["-1", "2147483648"])
def test_seed_out_of_range_is_refused(inputs, tmp_path, capsys, seed):
    """--seed -1 ended in numpy's traceback (exit 1); 2^31 was taken, though the QGIS tools
    refuse it (one rule: core.seeds)."""
    out = tmp_path / "x.gpkg"
    assert cli.main(_gan(f"{inputs['src']}:area", out, "--seed", seed)) == 2
    assert f"--seed must be a whole number from 0 to 2147483647, not {seed}" in \
        capsys.readouterr().err
    assert not out.exists()
    assert cli.main(["footprints", "--blocks", f"{inputs['src']}:area", "--db",
                     str(inputs["db"]), "--out", str(out), "--partitions", "0"]) == 2
    assert "--partitions must be at least 1" in capsys.readouterr().err


def test_unreachable_scheduler_is_a_clear_error(inputs, tmp_path, capsys):
    """A --scheduler nobody listens on ended in distributed's OSError traceback."""
    import dask
    import distributed as _  # noqa: F401 - its config defaults in place before the set

    out = tmp_path / "x.gpkg"
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        rc = cli.main(_gan(f"{inputs['src']}:area", out, "--scheduler", "tcp://127.0.0.1:1"))
    assert rc == 2
    assert "--scheduler tcp://127.0.0.1:1: cannot connect" in capsys.readouterr().err
    assert not out.exists()


def test_progress_on_stderr(inputs, tmp_path, capsys):
    """Runs of minutes said nothing until the end; now stderr has steps of 10 %."""
    assert cli.main(_gan(f"{inputs['src']}:area", tmp_path / "a.gpkg")) == 0
    captured = capsys.readouterr()
    steps = [line for line in captured.err.splitlines() if line.startswith("gan: ")]
    assert steps[-1] == "gan: 100 %" and len(steps) >= 3
    assert captured.out.count("\n") == 1                 # the JSON summary only
    assert cli.main(_gan(f"{inputs['src']}:area", tmp_path / "b.gpkg", "--quiet")) == 0
    captured = capsys.readouterr()
    assert "%" not in captured.err and captured.out == ""


def test_help_names_units_and_defaults():
    """Every option says what it does, and an option with a default says the default."""
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for name, p in sub.choices.items():
        for action in p._actions:
            if action.dest == "help":
                continue
            assert action.help, f"{name} {action.option_strings} has no help"
            if action.default not in (None, False) and action.__class__.__name__ != \
                    "_StoreTrueAction":
                assert "default" in action.help, f"{name} {action.option_strings}"
    setback = next(a for a in sub.choices["footprints"]._actions if a.dest == "setback")
    assert "in m" in setback.help


def test_parse_output():
    assert distributed.parse_output("a/b.gpkg", "roads") == distributed.Source("a/b.gpkg",
                                                                                "roads")
    assert distributed.parse_output("a/b.GPKG:x", "roads") == distributed.Source("a/b.GPKG",
                                                                                  "x")
    with pytest.raises(distributed.InputError, match="GeoPackage"):
        distributed.parse_output("PG:dbname=x", "roads")


def test_footprints_without_geometry_are_named(tmp_path):
    """A footprint layer with a NULL geometry was refused as 'footprints must be polygons
    (found Polygon, none)': polygons were found; the message now says which features
    have no geometry."""
    import geopandas as gpd

    src = tmp_path / "fp.gpkg"
    squares = [shapely.box(385000 + 20 * i, 6671500, 385010 + 20 * i, 6671510) for i in range(4)]
    squares[2] = None
    gpd.GeoDataFrame({"n": range(4)}, geometry=squares, crs=32635).to_file(
        src, layer="fp", driver="GPKG", engine="pyogrio")
    with pytest.raises(distributed.InputError,
                       match=r"fp.gpkg:fp: 1 footprint\(s\) have no geometry \(feature id 3\)"):
        distributed.read_footprints(distributed.Source(str(src), "fp"))


def test_a_relative_source_is_found_by_workers_in_another_folder(tmp_path, monkeypatch):
    """Workers of a --scheduler cluster run in a folder of their own; the tasks re-read
    their partition by the path the driver was given, so '--blocks demo.gpkg:blocks' ran
    on the driver and failed on the workers ('demo.gpkg: no such file')."""
    import geopandas as gpd
    import pandas as pd
    from distributed import Client, LocalCluster

    from urban_synthesis.plugin.buildings import attributes as building_attributes

    xy = [(385000 + 25 * (i % 6), 6671500 + 25 * (i // 6)) for i in range(24)]
    geoms = [shapely.box(x, y, x + 10 + i % 4, y + 12) for i, (x, y) in enumerate(xy)]
    gpd.GeoDataFrame({"n": range(24)}, geometry=geoms, crs=32635).to_file(
        tmp_path / "fp.gpkg", layer="fp", driver="GPKG", engine="pyogrio")
    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                           dashboard_address=None)   # its worker stays in this folder
    client = Client(cluster)
    try:
        monkeypatch.chdir(tmp_path)
        fp = distributed.read_footprints(distributed.Source("fp.gpkg", "fp"))
        attrs = building_attributes.building_attributes(
            24, height=[float(5 + i) for i in range(24)])
        job = distributed.AttributeJob(np.array(geoms, dtype=object), attrs, k=3)
        serial = distributed.attributes_serial(fp, job)
        dist = distributed.attributes_distributed(client, fp, job, n_partitions=2)
        pd.testing.assert_frame_equal(serial.table, dist.table, check_exact=True)
    finally:
        client.close()
        cluster.close()
    assert distributed.for_workers(distributed.Source("PG:dbname=x", "t")).path == \
        "PG:dbname=x"
