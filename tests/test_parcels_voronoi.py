"""The voronoi-obb parcel method (Aliaga et al. 2008, sec. 3.1.2) in the engine and in QGIS."""
import numpy as np
import pytest
import shapely

from conftest import bubenec_layer
from helpers import bubenec, layer_features
from urban_synthesis.plugin.network import blocks
from urban_synthesis.plugin.measure import metrics
from urban_synthesis.plugin.parcels import subdivision as parcels
from urban_synthesis.plugin.parcels import voronoi as parcels_voronoi
from urban_synthesis.plugin.core.progress import InputError

S = parcels.SubdivisionSettings


def _lots(block, **options):
    return parcels_voronoi.split_voronoi_obb(block, S(options=options),
                                             np.random.default_rng(0))


def test_registered_last_in_the_method_enum():
    assert parcels.method_names()[:2] == ("recursive", "skeleton")
    assert parcels.method_names()[-1] == "voronoi-obb"
    assert parcels.METHODS["voronoi-obb"].street_access


def test_one_row_of_strips_across_a_narrow_block():
    """A 120 x 30 m block, 360 m² parcels: 10 strips across, each with street on both
    long sides (one row: access front and back)."""
    block = shapely.box(0, 0, 120, 30)
    lots = _lots(block, mean_area=360.0, area_sd=0.0)
    assert len(lots) == 10
    assert shapely.is_valid(lots).all()
    assert shapely.area(shapely.union_all(lots)) == pytest.approx(block.area)
    np.testing.assert_allclose(shapely.area(lots), 360.0, rtol=1e-6)
    for lot in lots:  # every strip reaches both long sides
        assert lot.intersection(shapely.LineString([(0, 0), (120, 0)])).length > 5
        assert lot.intersection(shapely.LineString([(0, 30), (120, 30)])).length > 5


def test_two_rows_split_along_the_axis_with_jitter():
    """A 200 x 80 m block, 400 m² parcels (depth 24.5 m): two rows split on the OBB axis,
    every parcel on the street on one side; Gaussian jitter varies the widths."""
    block = shapely.box(0, 0, 200, 80)
    lots = _lots(block, mean_area=400.0, area_sd=120.0)
    assert 36 <= len(lots) <= 44
    assert shapely.is_valid(lots).all()
    assert shapely.area(shapely.union_all(lots)) == pytest.approx(block.area)
    axis = shapely.LineString([(0, 40), (200, 40)])
    assert all(lot.intersection(axis).length > 1 for lot in lots)  # every lot on the axis
    widths = np.array([lot.bounds[2] - lot.bounds[0] for lot in lots])
    assert widths.std() > 1.0
    ring = block.exterior
    assert all(lot.intersection(ring).length > 3 for lot in lots)


def test_parcel_size_from_example_areas_and_defaults():
    assert parcels_voronoi.parcel_size(S(options={"parcel_areas": [100, 300]})) == (200.0, 100.0)
    mean, sd = parcels_voronoi.parcel_size(S(lot_width=18.0, irregularity=0.2))
    assert mean == pytest.approx(18 * 18 * 1.5) and sd == pytest.approx(0.1 * mean)
    with pytest.raises(InputError, match="positive"):
        parcels_voronoi.parcel_size(S(options={"parcel_areas": [0, -1]}))


def test_bubenec_against_its_cadastre():
    """Sec. 3.1.2 on Bubeneč's 7 blocks with the cadastre's parcel areas: every parcel
    valid, inside its shrunk block, with street access; the area distribution is close to
    the cadastre's and the parcels are more regular (Yang's p_angle / p_area)."""
    streets = bubenec("streets").geometry.values
    plots = bubenec("plots").geometry.values
    extraction = blocks.extract_blocks(streets, parcels=plots)
    real = plots[extraction.parcels.in_block.to_numpy()]  # the cadastre parcels in the blocks
    res = parcels.subdivide_blocks(extraction.geometry, "voronoi-obb",
                                   S(options={"parcel_areas": shapely.area(real)}), seed=1,
                                   roads=streets)
    lots = res.geometry
    assert shapely.is_valid(lots).all()
    owner = res.table.block_id.to_numpy() - 1
    assert shapely.within(lots, shapely.buffer(res.blocks[owner], 1e-6)).all()
    assert res.table.has_street_access.all()
    assert 0.8 * len(real) < len(lots) < 1.3 * len(real)
    d = metrics.two_sample(shapely.area(lots), shapely.area(real))
    assert d["wasserstein_norm"] < 0.5 and d["ks_stat"] < 0.3
    m = metrics.parcel_metrics(lots)
    m_real = metrics.parcel_metrics(real)
    assert m.scalar("parcels", "p_angle") < m_real.scalar("parcels", "p_angle")
    assert m.scalar("parcels", "p_area") < m_real.scalar("parcels", "p_area")


def test_subdivideparcels_method_voronoi_obb(qgis_processing):
    index = list(parcels.method_names()).index("voronoi-obb")
    out = qgis_processing.run("urbansynth:subdivideparcels", {
        "ROADS": bubenec_layer("streets"), "METHOD": index, "SEED": 2, "OUTPUT": "memory:"})
    rows, geoms = layer_features(out["OUTPUT"])
    assert 60 < len(rows) < 250
    assert {r["method"] for r in rows} == {"voronoi-obb"}
    assert shapely.is_valid(geoms).all()
    assert all(r["has_street_access"] for r in rows)
