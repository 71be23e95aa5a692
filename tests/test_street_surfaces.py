"""Engine tests of plugin.network.street_surfaces (Scharl 2010, ch. 5): plain shapely, no QGIS."""
import numpy as np
import pytest
import shapely

from helpers import helsinki_roads
from urban_synthesis.plugin.network import street_graph as roads
from urban_synthesis.plugin.network import street_surfaces as ss
from urban_synthesis.plugin.core.progress import InputError
from urban_synthesis.plugin.retrieval.shape_context import DemGrid


# --------------------------------------------------------------------------- checks

def overlaps(polys, layers=None):
    """Interior overlap area of every pair of polygons of one layer (STRtree pairs)."""
    polys = np.asarray(polys, dtype=object)
    layers = np.zeros(len(polys), int) if layers is None else np.asarray(layers)
    tree = shapely.STRtree(polys)
    i, j = tree.query(polys, predicate="intersects")
    sel = (i < j) & (layers[i] == layers[j])
    return shapely.area(shapely.intersection(polys[i[sel]], polys[j[sel]]))


def coverage_error(result, graph=None, widths=None):
    """(missing, excess) area of the tessellation against the buffered centre lines,
    as shares of the buffered area."""
    graph = result.graph if graph is None else graph
    widths = result.widths if widths is None else widths
    ref = ss.reference_area(graph, widths)
    union = shapely.union_all(np.concatenate([result.surfaces, result.junctions]))
    with np.errstate(divide="ignore", invalid="ignore"):  # GEOS's empty differences
        return (shapely.area(shapely.difference(ref, union)) / ref.area,
                shapely.area(shapely.difference(union, ref)) / ref.area)


def assert_tessellation(result, max_error=0.01):
    polys = np.concatenate([result.surfaces, result.junctions])
    assert shapely.is_valid(polys).all()
    assert (shapely.area(polys) > 0).all()
    layers = np.r_[result.surface_table.z_layer, result.junction_table.z_layer]
    ov = overlaps(shapely.force_2d(polys), layers)
    assert ov.sum() < 1e-3 and (ov.max() if len(ov) else 0) < 1e-3
    missing, excess = coverage_error(result)
    assert missing < max_error and excess < max_error, (missing, excess)
    return missing, excess


def star(angles_deg, widths, length=60.0, centre=(0.0, 0.0)):
    """Streets from one centre point at the given angles."""
    cx, cy = centre
    a = np.radians(angles_deg)
    lines = [shapely.LineString([(cx, cy), (cx + length * np.cos(t), cy + length * np.sin(t))])
             for t in a]
    return lines, np.asarray(widths, dtype=float)


# --------------------------------------------------------------------------- widths

def test_widths_precedence_and_osm_values():
    assert ss.parse_width("7.5 m") == 7.5 and ss.parse_width("6,5") == 6.5
    assert ss.parse_width(8) == 8.0 and ss.parse_width("7;9") == 7.0
    for bad in ("12'", "wide", None, "-3", "0.1", "500"):
        assert np.isnan(ss.parse_width(bad))
    w, src = ss.road_widths(width=["9", None, "x", None, None, None],
                            road_class=["residential", "primary", "primary_link", None,
                                        "primary", None],
                            level=[None, None, None, 0, None, None],
                            oneway=[None, None, None, None, "yes", None], default_width=5.0)
    np.testing.assert_allclose(w, [9.0, 16.0, 7.0, 16.0, 8.0, 5.0])
    assert list(src) == ["field", "class", "class", "level", "class", "default"]


# --------------------------------------------------------------------------- junctions

@pytest.mark.parametrize("angles, widths", [
    ([0, 90, 180], [8, 12, 8]),                        # T: through road and a wider side road
    ([10, 95, 170, 280], [6, 8, 10, 7]),               # skewed 4-way crossing
    ([0, 60, 150, 200, 290], [8, 8, 14, 6, 8]),        # Scharl Fig. 5.1: five streets
    ([0, 40, 110, 180, 230, 300], [7, 9, 8, 12, 6, 8]),  # six streets
])
def test_junction_of_any_degree(angles, widths):
    lines, w = star(angles, widths)
    res = ss.tessellate_lines(lines, w)
    n = len(angles)
    assert len(res.junctions) == 1 and len(res.surfaces) == n
    assert res.junction_table.degree.tolist() == [n]
    assert_tessellation(res)
    # each street meets the junction along a connecting line of its full width that is
    # perpendicular to the street (Scharl Fig. 5.4)
    junction = res.junctions[0]
    for geom, row in zip(res.surfaces, res.surface_table.itertuples()):
        xy = np.unique(shapely.get_coordinates(geom), axis=0)
        on_junction = xy[shapely.distance(shapely.points(xy), junction.boundary) < 1e-6]
        assert len(on_junction) == 2
        # the surface edge between them runs along the junction's boundary
        mid = shapely.Point(on_junction.mean(0))
        assert shapely.distance(mid, junction.boundary) < 1e-6
        assert shapely.distance(mid, geom.boundary) < 1e-6
        shared = shapely.LineString(on_junction)
        street = res.graph.geometry[row.edge_id - 1]
        d = np.diff(shapely.get_coordinates(street), axis=0)[0]
        c = np.diff(shapely.get_coordinates(shared)[[0, -1]], axis=0)[0]
        assert abs(np.dot(d, c)) / (np.linalg.norm(d) * np.linalg.norm(c)) < 1e-6


def test_acute_and_wide_angles_stay_clean():
    """A 12 degree fork (outlines meet far out) and a 250 degree gap (round fill)."""
    lines, w = star([0, 12, 110], [10, 8, 6], length=80.0)
    res = ss.tessellate_lines(lines, w)
    assert res.junction_table.degree.tolist() == [3]
    assert_tessellation(res)
    # the fork's head is capped (3 x the widest street) instead of reaching 45 m out
    hull = shapely.get_coordinates(res.junctions[0])
    assert np.hypot(*hull.T).max() <= 3 * 10 + 5 + 1e-6


def test_close_centres_merge_into_one_junction():
    """Two T-junctions 2.5 m apart on a through road: one degree-4 junction (Scharl 5.1)."""
    lines = [shapely.LineString([(-80, 0), (80, 0)]), shapely.LineString([(0, 0), (0, 60)]),
             shapely.LineString([(2.5, 0), (2.5, -60)])]
    w = np.array([10.0, 8.0, 8.0])
    merged = ss.tessellate_lines(lines, w, merge_distance=3.0)
    assert merged.junction_table.degree.tolist() == [4]
    assert merged.junction_table.merged_nodes.tolist() == [2]
    assert_tessellation(merged)
    apart = ss.tessellate_lines(lines, w, merge_distance=0.0)
    assert sorted(apart.junction_table.degree.tolist()) == [3, 3]
    assert_tessellation(apart)


def test_heads_that_meet_share_a_connecting_line_or_merge():
    """A 9 m street between two junctions of 12 m streets: by default both junctions keep
    their centres and meet; with Scharl's rule they merge."""
    lines = [shapely.LineString([(-60, 0), (60, 0)]), shapely.LineString([(-60, 9), (60, 9)]),
             shapely.LineString([(0, 0), (0, 9)])]
    w = np.array([12.0, 12.0, 6.0])
    res = ss.tessellate_lines(lines, w)
    assert sorted(res.junction_table.degree.tolist()) == [3, 3]
    assert_tessellation(res)
    scharl = ss.tessellate_lines(lines, w, merge_heads=True)
    assert scharl.junction_table.degree.tolist() == [4]
    assert scharl.stats["merged_away"] == 1


def test_bridge_may_overlap_other_layer_only():
    lines = [shapely.LineString([(-50, 0), (50, 0)]), shapely.LineString([(0, -50), (0, 50)])]
    res = ss.tessellate_lines(lines, np.array([8.0, 8.0]), z_layer=[0, 1])
    assert len(res.junctions) == 0 and len(res.surfaces) == 2
    assert shapely.intersection(*res.surfaces).area == pytest.approx(64.0, rel=1e-6)
    assert sorted(res.surface_table.z_layer) == [0, 1]


def test_bad_widths():
    g = roads.clean_network([shapely.LineString([(0, 0), (10, 0)])])
    with pytest.raises(InputError, match="width"):
        ss.tessellate_network(g, np.array([0.0]))
    with pytest.raises(InputError, match="width"):
        ss.tessellate_network(g, np.array([np.nan]))


# --------------------------------------------------------------------------- terrain

def plane_dem(a, b, c=50.0, extent=(-100, -100, 400, 400), cell=5.0):
    x0, y0, x1, y1 = extent
    cols, rows = int((x1 - x0) / cell), int((y1 - y0) / cell)
    xs = x0 + cell * (np.arange(cols) + 0.5)
    ys = y1 - cell * (np.arange(rows) + 0.5)
    x, y = np.meshgrid(xs, ys)
    return DemGrid(c + a * x + b * y, (x0, cell, 0.0, y1, 0.0, -cell))


def grid_lines(n=3, spacing=100.0):
    out = []
    for k in range(n + 1):
        out.append(shapely.LineString([(0, k * spacing), (n * spacing, k * spacing)]))
        out.append(shapely.LineString([(k * spacing, 0), (k * spacing, n * spacing)]))
    return out


def test_inclined_plane_slopes_and_planar_junctions():
    """z = 50 + 0.05 x + 0.10 y: streets along x climb 5 % and lean 10 % sideways."""
    a, b = 0.05, 0.10
    dem = plane_dem(a, b)
    res = ss.tessellate_lines(grid_lines(), np.full(8, 10.0), dem=dem)
    assert_tessellation(res)
    polys = np.concatenate([res.surfaces, res.junctions])
    assert shapely.has_z(polys).all()
    xyz = shapely.get_coordinates(polys, include_z=True)
    np.testing.assert_allclose(xyz[:, 2], 50 + a * xyz[:, 0] + b * xyz[:, 1], atol=1e-6)
    st = res.surface_table
    # straight pieces only (the grid's corner bends mix both directions)
    straight = np.array([len(shapely.get_coordinates(res.graph.geometry[e - 1])) == 2
                         for e in st.edge_id])
    coords = [shapely.get_coordinates(res.graph.geometry[e - 1]) for e in st.edge_id]
    along_x = straight & np.array([abs(c[-1, 1] - c[0, 1]) < 1e-9 for c in coords])
    along_y = straight & ~along_x
    assert along_x.sum() >= 4 and along_y.sum() >= 4
    np.testing.assert_allclose(st.slope_long_pct[along_x], 5.0, atol=1e-6)
    np.testing.assert_allclose(st.slope_lat_pct[along_x], 10.0, atol=1e-6)
    np.testing.assert_allclose(st.slope_long_pct[along_y], 10.0, atol=1e-6)
    np.testing.assert_allclose(st.slope_lat_pct[along_y], 5.0, atol=1e-6)
    # Scharl's limits: 12 % along, 8 % across
    assert not st.too_steep_long[along_x | along_y].any()
    assert st.too_steep_lat[along_x].all() and not st.too_steep_lat[along_y].any()
    jt = res.junction_table
    np.testing.assert_allclose(jt.slope_pct, 100 * np.hypot(a, b), atol=1e-6)
    np.testing.assert_allclose(jt.slope_long_pct, 10.0, atol=1e-6)


def test_hill_junctions_in_tangent_plane_and_streets_draped():
    """On a curved hill, junctions stay planar (tangent plane at the centre), streets follow
    the terrain away from their ends and meet the junctions without steps."""
    cell = 2.0
    xs = -100 + cell * (np.arange(250) + 0.5)
    ys = 400 - cell * (np.arange(250) + 0.5)
    x, y = np.meshgrid(xs, ys)
    z = 30.0 * np.exp(-((x - 150) ** 2 + (y - 150) ** 2) / (2 * 90.0 ** 2))
    dem = DemGrid(z, (-100, cell, 0.0, 400, 0.0, -cell))
    res = ss.tessellate_lines(grid_lines(), np.full(8, 10.0), dem=dem)
    assert_tessellation(res)
    for j in res.junctions:
        c = shapely.get_coordinates(j, include_z=True)
        A = np.column_stack([c[:, 0], c[:, 1], np.ones(len(c))])
        coef, *_ = np.linalg.lstsq(A, c[:, 2], rcond=None)
        assert np.abs(A @ coef - c[:, 2]).max() < 1e-6      # planar
    # the tangent plane at a centre matches the terrain's gradient there
    centre = res.graph.nodes[res.junction_table.junction_id.to_numpy() - 1]
    gx = -(centre[:, 0] - 150) / 90.0 ** 2 * dem(centre)
    gy = -(centre[:, 1] - 150) / 90.0 ** 2 * dem(centre)
    np.testing.assert_allclose(res.junction_table.slope_pct, 100 * np.hypot(gx, gy), atol=1.5)
    # no steps: a vertex shared by a street and a junction has one height
    jxyz = np.vstack([shapely.get_coordinates(j, include_z=True) for j in res.junctions])
    sxyz = np.vstack([shapely.get_coordinates(s, include_z=True) for s in res.surfaces])
    from scipy.spatial import cKDTree

    d, k = cKDTree(jxyz[:, :2]).query(sxyz[:, :2])
    shared = d < 1e-6
    assert shared.sum() >= 2 * len(res.surfaces)
    np.testing.assert_allclose(sxyz[shared, 2], jxyz[k[shared], 2], atol=1e-6)
    # in the middle of a street, the surface lies on the terrain
    mid = sxyz[(d > 30)]
    np.testing.assert_allclose(mid[:, 2], dem(mid[:, :2]), atol=1e-6)


def test_a_street_that_bends_back_past_its_end_meets_its_junctions_without_a_step():
    """A U-shaped street between two junctions on a hill: measured along its end's
    direction, its far legs lay 'behind' its ends and took the junction planes
    extrapolated (steps of 3-3.6 m at the junctions, metres off the terrain)."""
    cell = 2.0
    x, y = np.meshgrid(-100 + cell * (np.arange(250) + 0.5), 400 - cell * (np.arange(250) + 0.5))
    dem = DemGrid(30.0 * np.exp(-((x - 150) ** 2 + (y - 250) ** 2) / (2 * 90.0 ** 2)),
                  (-100, cell, 0.0, 400, 0.0, -cell))
    lines = [shapely.LineString([(0, 0), (150, 0)]),
             shapely.LineString([(0, 0), (0, 250), (150, 250), (150, 0)]),
             shapely.LineString([(0, 0), (0, -90)]), shapely.LineString([(150, 0), (150, -90)])]
    res = ss.tessellate_lines(lines, np.full(4, 8.0), dem=dem)
    assert_tessellation(res)
    from scipy.spatial import cKDTree

    jxyz = np.vstack([shapely.get_coordinates(j, include_z=True) for j in res.junctions])
    for surface in res.surfaces:
        sxyz = shapely.get_coordinates(surface, include_z=True)
        d, k = cKDTree(jxyz[:, :2]).query(sxyz[:, :2])
        np.testing.assert_allclose(sxyz[d < 1e-6, 2], jxyz[k[d < 1e-6], 2], atol=1e-6)
        far = d > 30
        np.testing.assert_allclose(sxyz[far, 2], dem(sxyz[far, :2]), atol=1e-6)


def test_a_dem_with_a_hole_and_an_edge_inside_the_network():
    """z = 50 + 0.05 x + 0.10 y with a 60 m hole over a street and nothing beyond x = 250:
    no height is NaN, zero or below the terrain's range (they were 0 and -600 m); across
    the hole the plane is interpolated exactly (a plane is harmonic), beyond the edge the
    edge's heights go on; the streets concerned are counted."""
    dem = plane_dem(0.05, 0.10)
    x0, dx, _, y1, _, dy = dem.geotransform
    rows, cols = dem.array.shape
    x, y = np.meshgrid(x0 + dx * (np.arange(cols) + 0.5), y1 + dy * (np.arange(rows) + 0.5))
    holed = dem.array.copy()
    holed[(np.abs(x - 150) < 30) & (np.abs(y - 100) < 30)] = np.nan   # a hole on a junction
    holed[x > 250] = np.nan                                           # the DEM ends there
    res = ss.tessellate_lines(grid_lines(), np.full(8, 10.0),
                              dem=DemGrid(holed, dem.geotransform))
    assert_tessellation(res)
    xyz = shapely.get_coordinates(np.concatenate([res.surfaces, res.junctions]),
                                  include_z=True)
    assert np.isfinite(xyz[:, 2]).all()
    inside = xyz[:, 0] < 240
    np.testing.assert_allclose(xyz[inside, 2], 50 + 0.05 * xyz[inside, 0] + 0.10 * xyz[inside, 1],
                               atol=1e-3)
    beyond = xyz[:, 0] > 260
    assert (xyz[beyond, 2] >= 50 + 0.05 * 245 - 1).all()
    assert res.stats["dem_gap_edges"] >= 5 and res.stats["dem_gap_max_m"] >= 45


# --------------------------------------------------------------------------- real data

def test_helsinki_streets():
    df = helsinki_roads()
    tags = [roads.parse_other_tags(t) for t in df.other_tags]
    w, src = ss.road_widths([t.get("width") for t in tags], df.highway.to_numpy(), n=len(df),
                            oneway=[t.get("oneway") for t in tags])
    graph = roads.clean_network(df.geometry.to_numpy(), df.highway.to_numpy(),
                                z_layer=df.z.to_numpy(), min_dangle_length=0.0)
    res = ss.tessellate_network(graph, w[graph.source])
    missing, excess = assert_tessellation(res)
    # the input graph itself (not a merged one) is what must be covered
    assert coverage_error(res, graph, w[graph.source])[0] < 0.01
    deg = res.junction_table.degree
    assert {3, 4} <= set(deg)
    # a node of degree 2 is a joint where a bridge or tunnel meets its approach
    joint = res.junction_table.junction_id[deg == 2].to_numpy() - 1
    assert (deg >= 2).all() and 0 < len(joint) < 0.2 * len(deg)
    for n in joint:
        assert len(set(graph.z_layer[(graph.u == n) | (graph.v == n)])) == 2
    # every node of degree >= 3 of the cleaned graph has a junction, minus merged ones
    n_nodes = int((graph.degree >= 3).sum())
    assert len(res.junctions) + res.stats["merged_away"] >= n_nodes - 2
    assert len(res.surfaces) >= 0.9 * graph.n_edges
    np.testing.assert_allclose(res.surface_table.area_m2, shapely.area(res.surfaces))
    # the mesh: a street's vertex at a junction is the junction's vertex, not a micrometre
    # off it (GEOS's corners of the trimmed surfaces were, 96 of them: cracks for a mesh
    # joined by its vertices)
    from scipy.spatial import cKDTree

    from urban_synthesis.plugin.network import street_mesh as sm

    m = sm.street_mesh(res)
    junction = ~m.side & (m.owner >= len(res.surfaces))
    corners = np.unique(m.triangles[junction].reshape(-1, 3), axis=0)
    d, _ = cKDTree(corners).query(m.triangles[~junction].reshape(-1, 3))
    assert (d == 0).sum() > 700 and not ((d > 0) & (d < 1e-5)).any()


# --------------------------------------------------------------------------- 3D mesh

def test_mesh_tiles_the_surfaces_and_skirts_the_terrain():
    """Scharl 5.2: the top triangles tile the street and junction polygons (up to the
    curves' chords), lie on the draped heights plus the offset; side faces reach below
    the terrain; no side faces and z = 0 without a DEM; TIN WKB round-trips."""
    from osgeo import ogr

    from urban_synthesis.plugin.network import street_mesh as sm

    arc = shapely.LineString([(0, 0), (40, 5), (80, 20), (110, 45)])   # a curved street
    lines, widths = star([0, 70, 150, 215, 290], [8, 8, 14, 6, 8])
    lines = lines + [shapely.LineString([(60 * np.cos(np.radians(70)),
                                          60 * np.sin(np.radians(70))), (60, 120)])]
    g = roads.clean_network(lines + [shapely.transform(arc, lambda c: c + [200, 0])],
                            min_dangle_length=0.0)
    w = np.r_[widths, 8.0, 10.0][g.source]
    x, y = np.meshgrid(np.arange(-100, 340, 2.0) + 1, 200 - np.arange(260) * 2.0 - 1)
    dem = DemGrid(0.05 * x + 2 * np.sin(y / 20), (-100, 2.0, 0, 200, 0, -2.0))
    for terrain in (None, dem):
        t = ss.tessellate_network(g, w, dem=terrain)
        m = sm.street_mesh(t, spacing=3.0, z_offset=0.1)
        top = m.triangles[~m.side]
        flat = shapely.polygons(np.concatenate([top[:, :, :2], top[:, :1, :2]], axis=1))
        assert (shapely.area(flat) > 0).all()
        union = shapely.union_all(flat)
        polys = shapely.union_all(shapely.force_2d(np.concatenate([t.surfaces, t.junctions])))
        # no two top triangles overlap; they cover the polygons to within the chords
        assert shapely.area(flat).sum() - union.area < 1e-6 * union.area
        assert shapely.symmetric_difference(union, polys).area < 0.01 * polys.area
        assert len(m.table) == len(t.surfaces) + len(t.junctions)
        assert (m.table.triangles > 0).all()
        if terrain is None:
            assert not m.side.any() and np.allclose(m.triangles[:, :, 2], 0.0)
            continue
        # top vertices of the streets: draped height + offset
        s_tri = m.triangles[~m.side & (m.owner < len(t.surfaces))]
        k = np.repeat(m.owner[~m.side & (m.owner < len(t.surfaces))], 3)
        xyz = s_tri.reshape(-1, 3)
        np.testing.assert_allclose(xyz[:, 2], t.surface_z(k, xyz[:, :2]) + 0.1, atol=1e-9)
        side = m.triangles[m.side].reshape(-1, 3)
        ground = t.terrain_z(side[:, :2])
        low = np.isclose(side[:, 2], ground - 0.5, atol=1e-9)
        assert low.any() and (low | (side[:, 2] > ground)).all()
        wkb = sm.tin_wkb(m.geometries()[:3])
        for b, n in zip(wkb, m.table.triangles[:3]):
            geom = ogr.CreateGeometryFromWkb(b)
            assert geom.GetGeometryName() == "TIN" and geom.GetGeometryCount() == n


def test_mesh_of_streets_trimmed_by_each_other_does_not_overlap():
    """Two 8 m streets 4 m apart (a dual carriageway): their surfaces are trimmed where
    they overlap, and so are their top triangles now (1,168 m² lay over each other), with
    z still on the draped height."""
    from urban_synthesis.plugin.network import street_mesh as sm

    lines = [shapely.LineString([(0, 0), (300, 0)]), shapely.LineString([(0, 4), (300, 4)]),
             shapely.LineString([(0, -50), (0, 50)]), shapely.LineString([(300, -50), (300, 50)])]
    dem = plane_dem(0.05, 0.02, extent=(-100, -100, 400, 100))
    for terrain in (None, dem):
        t = ss.tessellate_lines(lines, np.full(4, 8.0), dem=terrain)
        m = sm.street_mesh(t, spacing=5.0, z_offset=0.1)
        top = m.triangles[~m.side]
        flat = shapely.polygons(np.concatenate([top[:, :, :2], top[:, :1, :2]], axis=1))
        union = shapely.union_all(flat)
        assert shapely.area(flat).sum() - union.area < 1e-6 * union.area     # no overlap
        polys = shapely.union_all(shapely.force_2d(np.concatenate([t.surfaces, t.junctions])))
        assert abs(union.area - polys.area) < 1e-6 * polys.area
        if terrain is not None:
            xyz = top.reshape(-1, 3)
            np.testing.assert_allclose(xyz[:, 2], 50 + 0.05 * xyz[:, 0] + 0.02 * xyz[:, 1] + 0.1,
                                       atol=1e-6)
            # no side face between the two carriageways, where one surface abuts the other
            # (each street's inner edge had a wall standing in the pavement)
            walls = m.triangles[m.side]
            mid = shapely.points(walls[:, :, :2].mean(1))
            assert shapely.distance(mid, polys.boundary).max() < 0.01


def test_the_mesh_of_bent_streets_covers_their_surface_once():
    """Stations every few metres ignored the centre line's bends: the strip cut the outer
    side of a bend (the surface's round join) and folded over itself on the inner side,
    most on mountain hairpins (Vaduz: 1,445 m² of gaps and 655 m² of folds). A bend of
    90°, a hairpin whose inner corner lies beyond the next bend and a bend 0.6 m after a
    junction: the top triangles cover the street surfaces exactly, none over another, and
    the side faces stand on the surface's outline only. A junction and a street share
    their connecting line to the last bit, in the polygons and in the mesh: computed apart,
    they differed by round-off, a crack in the paved area beside the street bent 0.6 m
    from its junction."""
    from scipy.spatial import cKDTree
    from urban_synthesis.plugin.network import street_mesh as sm

    lines = [shapely.LineString([(0, 0), (60, 0), (60, 60)]),                  # 90°
             shapely.LineString([(100, 0), (180, 0), (180, 6), (110, 6)]),      # a hairpin
             shapely.LineString([(0, 0), (-0.6, 0), (-40, 30)]),                # bend at a node
             shapely.LineString([(0, 0), (0, -50)])]
    for terrain in (None, plane_dem(0.05, 0.02, extent=(-100, -100, 300, 200))):
        t = ss.tessellate_lines(lines, np.full(len(lines), 8.0), dem=terrain)
        m = sm.street_mesh(t, spacing=5.0, z_offset=0.1)
        top = m.triangles[~m.side]
        flat = shapely.polygons(np.concatenate([top[:, :, :2], top[:, :1, :2]], axis=1))
        union = shapely.union_all(flat)
        polys = shapely.union_all(shapely.force_2d(np.concatenate([t.surfaces, t.junctions])))
        assert shapely.area(flat).sum() - union.area < 1e-6 * union.area       # no fold
        assert shapely.symmetric_difference(union, polys).area < 1e-6 * polys.area
        # no crack: closing the outline by a centimetre leaves it as it is
        closed = polys.buffer(0.01, join_style="mitre").buffer(-0.01, join_style="mitre")
        assert polys.boundary.length == pytest.approx(closed.boundary.length, rel=1e-9)
        # a vertex of a junction within a millimetre of a street's is that vertex
        st = m.table.kind.to_numpy()[m.owner[~m.side]] == "street"
        for street, junction in ((shapely.get_coordinates(t.surfaces),
                                  shapely.get_coordinates(t.junctions)),
                                 (top[st][:, :, :2].reshape(-1, 2),
                                  top[~st][:, :, :2].reshape(-1, 2))):
            d = cKDTree(street).query(junction)[0]
            assert ((d == 0) | (d > 1e-3)).all() and (d == 0).sum() >= 4
        if terrain is not None:
            xyz = top.reshape(-1, 3)
            np.testing.assert_allclose(xyz[:, 2], 50 + 0.05 * xyz[:, 0] + 0.02 * xyz[:, 1] + 0.1,
                                       atol=1e-6)
            # the walls' top edges (their vertices above the ground) run along the outline,
            # all of it
            walls = m.triangles[m.side]
            up = walls[:, :, 2] > 50 + 0.05 * walls[:, :, 0] + 0.02 * walls[:, :, 1]
            edges = walls[up.sum(1) == 2][:, :, :2][up[up.sum(1) == 2]].reshape(-1, 2, 2)
            mid = shapely.points(edges.mean(1))
            assert shapely.distance(mid, polys.boundary).max() < 1e-6
            length = np.linalg.norm(edges[:, 1] - edges[:, 0], axis=1).sum()
            # an edge partly on the outline has its wall on that part only (the hairpin's
            # dead end, 2 m of it under its other leg's surface, had its wall whole)
            assert length == pytest.approx(polys.boundary.length, rel=1e-9)


def test_a_hairpin_turning_back_on_itself_has_no_face_off_its_surface():
    """A street that turns by 179.95° has its bend's inner corner 9 km away: a side face
    ran out to it, and the top faces cut back from it took their heights from there (26 m
    off the drape on a 178° hairpin on a curved slope). Every face of the mesh now lies on
    the street's surface, which the top faces still cover once, at the draped height."""
    from urban_synthesis.plugin.network import street_mesh as sm

    x, y = np.meshgrid(np.arange(-300, 500, 2.0) + 1, 300 - np.arange(600) * 2.0 - 1)
    dem = DemGrid(100 + 0.002 * (x - 50) ** 2 + 5 * np.sin(y / 15), (-300, 2.0, 0, 300, 0, -2.0))
    for degrees in (178.0, 179.95):
        turn = np.radians(180 - degrees)
        line = shapely.LineString([(0, 0), (100, 0),
                                   (100 - 80 * np.cos(turn), 80 * np.sin(turn))])
        t = ss.tessellate_lines([line], np.full(1, 8.0), dem=dem)
        m = sm.street_mesh(t, spacing=5.0, z_offset=0.1)
        surface = shapely.union_all(shapely.force_2d(t.surfaces))
        assert shapely.distance(shapely.points(m.triangles.reshape(-1, 3)[:, :2]),
                                surface).max() < 1e-6
        top = m.triangles[~m.side]
        flat = shapely.polygons(np.concatenate([top[:, :, :2], top[:, :1, :2]], axis=1))
        assert shapely.area(flat).sum() == pytest.approx(surface.area, rel=1e-6)
        xyz = top.reshape(-1, 3)
        drape = t.surface_z(np.zeros(len(xyz), dtype=int), xyz[:, :2]) + 0.1
        np.testing.assert_allclose(xyz[:, 2], drape, atol=1e-3)
        # u by the offset from the centre line (0 at 4 m to its left, 1 to its right), not
        # from the fan's far inner corner: it was up to 0.99 off on the cut-back pieces
        pts = shapely.points(xyz[:, :2])
        along = shapely.line_locate_point(line, pts)
        p0, p1 = (shapely.get_coordinates(shapely.line_interpolate_point(line, a))
                  for a in (np.maximum(along - 0.01, 0.0), along + 0.01))
        d, r = p1 - p0, xyz[:, :2] - 0.5 * (p0 + p1)
        offset = np.sign(d[:, 0] * r[:, 1] - d[:, 1] * r[:, 0]) * shapely.distance(line, pts)
        np.testing.assert_allclose(m.uv[~m.side][:, :, 0].ravel(),
                                   np.clip(0.5 - offset / 8.0, 0, 1), atol=1e-3)


def test_a_dead_end_street_is_closed_by_a_side_face():
    """On a DEM the street floats z_offset above the ground: its left and right edges had
    side faces, its dead end's last cross-section none (an open gap under its end)."""
    from urban_synthesis.plugin.network import street_mesh as sm

    lines = [shapely.LineString([(0, 0), (200, 0)]), shapely.LineString([(100, 0), (100, 80)])]
    t = ss.tessellate_lines(lines, np.full(2, 8.0), dem=plane_dem(0.05, 0.02))
    m = sm.street_mesh(t, spacing=5.0, z_offset=0.1)
    walls = m.triangles[m.side]
    # the three dead ends: (0, 0), (200, 0), (100, 80); a wall across each, 8 m wide
    for fixed, value in ((0, 0.0), (0, 200.0), (1, 80.0)):   # the axis the wall lies on
        at = walls[np.all(np.abs(walls[:, :, fixed] - value) < 1e-6, axis=1)]
        assert len(at) == 2, (fixed, value)
        assert np.ptp(at[:, :, 1 - fixed]) == pytest.approx(8.0)


def test_junction_corners_above_the_terrain_get_side_faces():
    """In a hollow the junction's plane (fitted to the terrain around it) lies above the
    ground at the junction's corners: those outer edges get side faces down to 0.5 m below
    the terrain, facing outwards, and no side face stands on a connecting line, where the
    street continues the junction's surface."""
    from urban_synthesis.plugin.network import street_mesh as sm

    lines, widths = star([0, 70, 150, 215, 290], [8, 8, 14, 6, 8])
    g = roads.clean_network(lines, min_dangle_length=0.0)
    x, y = np.meshgrid(np.arange(-100, 340, 2.0) + 1, 200 - np.arange(260) * 2.0 - 1)
    dem = DemGrid(200 + 0.002 * (x ** 2 + y ** 2), (-100, 2.0, 0, 200, 0, -2.0))  # a hollow
    t = ss.tessellate_network(g, np.asarray(widths)[g.source], dem=dem)
    m = sm.street_mesh(t, spacing=3.0, z_offset=0.1)
    n_s = len(t.surfaces)
    skirt = m.triangles[m.side & (m.owner >= n_s)]
    assert len(skirt) >= 6 and m.table.side_triangles.iloc[n_s:].sum() == len(skirt)
    xyz = skirt.reshape(-1, 3)
    ground = t.terrain_z(xyz[:, :2])
    low = np.isclose(xyz[:, 2], ground - 0.5, atol=1e-9)
    assert low.any() and (low | (xyz[:, 2] > ground)).all()
    # the top edge of each face (its two highest vertices) is no connecting line
    surfaces = shapely.union_all(shapely.force_2d(t.surfaces))
    for tri in skirt:
        hi = tri[np.argsort(tri[:, 2])[-2:], :2]
        edge = shapely.LineString(hi)
        assert shapely.intersection(edge, surfaces).length < 1e-6 * max(edge.length, 1.0)
    # outward: the face's horizontal normal points away from the junction's centre
    centre = t.graph.nodes[t.junction_node[0]]
    a, b, c = skirt[:, 0], skirt[:, 1], skirt[:, 2]
    normal = np.cross(b - a, c - a)[:, :2]
    away = skirt.mean(axis=1)[:, :2] - centre
    assert ((normal * away).sum(axis=1) > 0).all()


def test_texture_coordinates_and_obj(tmp_path):
    """Scharl 5.3 (Fig. 5.7): on a street u is 0 on its left edge and 1 on its right, in
    the street row of the road texture; junctions take the junction row (no lane line),
    side faces the kerb row. The OBJ holds the same triangles (x, y minus its origin),
    each corner with its texture coordinate, and its material names the road texture."""
    import cv2

    from urban_synthesis.plugin.network import street_mesh as sm

    lines, widths = star([0, 70, 150, 215, 290], [8, 8, 14, 6, 8], centre=(500000.0, 6e6))
    g = roads.clean_network(lines, min_dangle_length=0.0)
    x, y = np.meshgrid(np.arange(-100, 340, 2.0) + 1 + 5e5, 6e6 + 200 - np.arange(260) * 2.0 - 1)
    dem = DemGrid(200 + 0.002 * ((x - 5e5) ** 2 + (y - 6e6) ** 2),
                  (5e5 - 100, 2.0, 0, 6e6 + 200, 0, -2.0))                 # a hollow
    t = ss.tessellate_network(g, np.asarray(widths)[g.source], dem=dem)
    m = sm.street_mesh(t, spacing=3.0, z_offset=0.1)
    assert m.uv.shape == (len(m.triangles), 3, 2) and m.side.any()
    n_s = len(t.surfaces)
    street = ~m.side & (m.owner < n_s)
    rows = sm.TEXTURE_ROWS
    np.testing.assert_array_equal(m.uv[street, :, 1], rows["street"])
    assert (m.uv[~m.side & ~street] == [0.5, rows["junction"]]).all()
    np.testing.assert_array_equal(m.uv[m.side, :, 1], rows["side"])
    # u = 0 on the left of the street's centre line, 1 on its right
    k = np.repeat(m.owner[street], 3)
    xy = m.triangles[street][:, :, :2].reshape(-1, 2)
    centre = t.centres[k]
    along = shapely.line_locate_point(centre, shapely.points(xy))
    p0 = shapely.get_coordinates(shapely.line_interpolate_point(
        centre, np.maximum(along - 0.01, 0.0)))        # (a negative distance: from the end)
    p1 = shapely.get_coordinates(shapely.line_interpolate_point(centre, along + 0.01))
    d, r = p1 - p0, xy - 0.5 * (p0 + p1)
    left = d[:, 0] * r[:, 1] - d[:, 1] * r[:, 0] > 0
    np.testing.assert_array_equal(m.uv[street, :, 0].ravel() == 0.0, left)
    # the OBJ: the same triangles and texture coordinates, grouped, with its material
    out = sm.write_obj(tmp_path / "mesh.obj", m, crs_name="EPSG:32635")
    text = (tmp_path / "mesh.obj").read_text().splitlines()
    v = np.array([list(map(float, ln.split()[1:])) for ln in text if ln.startswith("v ")])
    vt = np.array([list(map(float, ln.split()[1:])) for ln in text if ln.startswith("vt ")])
    f = np.array([[int(i) for c in ln.split()[1:] for i in c.split("/")]
                  for ln in text if ln.startswith("f ")]).reshape(-1, 3, 2)
    assert len(f) == len(m.triangles) and len(v) < 3 * len(f)          # shared vertices
    assert {ln for ln in text if ln.startswith("g ")} == {"g streets", "g junctions",
                                                          "g side_faces"}
    # faces in group order (streets, junctions, side faces), each in the mesh's order
    kind = np.asarray(m.table.kind)[m.owner]
    order = np.r_[np.flatnonzero(~m.side & (kind == "street")),
                  np.flatnonzero(~m.side & (kind == "junction")), np.flatnonzero(m.side)]
    xyz = v[f[..., 0] - 1] + np.r_[out["origin"], 0.0]
    np.testing.assert_allclose(xyz, m.triangles[order], atol=6e-4)
    np.testing.assert_allclose(vt[f[..., 1] - 1], m.uv[order], atol=1e-6)
    assert "map_Kd mesh_texture.png" in (tmp_path / "mesh.mtl").read_text()
    img = cv2.imread(out["texture"])
    assert img.shape == (256, 256, 3)
    top = img[10, :, 0]                                    # the street row: lines
    assert top[int(0.075 * 256)] > 200 and top[int(0.25 * 256)] < 100 and \
        top[int(0.475 * 256)] > 200
    assert img[128, 128, 0] < 100                          # the junction row: no line


def test_ear_clipping_of_a_non_star_ring():
    from urban_synthesis.plugin.network import street_mesh as sm

    ring = np.array([(0, 0), (10, 0), (10, 10), (6, 10), (6, 3), (4, 3), (4, 10), (0, 10)],
                    dtype=float)                                  # a U: not star-shaped
    tri = sm._ear_clip(ring)
    assert len(tri) == len(ring) - 2
    polys = shapely.polygons(np.concatenate([ring[tri], ring[tri][:, :1]], axis=1))
    assert abs(shapely.area(polys).sum() - shapely.Polygon(ring).area) < 1e-9
    assert shapely.union_all(polys).equals(shapely.Polygon(ring))


def test_cutting_a_triangle_off_its_surface_makes_no_floating_point_warning():
    """A 0.28 m² fan triangle beside a trimmed street at Liechtenstein's Kreisel Rheindamm:
    GEOS's intersection of the two sets the floating-point 'invalid' flag, and every
    tessellatestreets run with a mesh printed 'RuntimeWarning: invalid value encountered in
    intersection' (to qgis_process's console). The cut is right (nothing of the triangle is
    on the surface); now it is quiet."""
    import warnings

    from urban_synthesis.plugin.network import street_mesh as sm

    tri = shapely.from_wkb(
        "01030000000100000004000000B3B3AAE11D722041BAB103B5ABE95341856F27571A722041E2D31ADDAB"
        "E95341018F11AE1D72204115CBC8A2ABE95341B3B3AAE11D722041BAB103B5ABE95341")
    surface = shapely.from_wkb(
        "01030000000100000007000000CF4D9BE10E722041B1C05767ACE953418F6E849D0F72204171016898AC"
        "E95341C8940FC10F722041ECF99A9FACE95341492D949C187220414A79ADF0ABE95341603B18B1167220"
        "4102D36906ACE95341F7E637CC0E722041384BC95FACE95341CF4D9BE10E722041B1C05767ACE95341")
    x0, y0, x1, y1 = surface.bounds
    big = shapely.Polygon([(x0 - 1, y0 - 1), (x0 - 1, 2 * y1 - y0 + 1), (2 * x1 - x0 + 1, y0 - 1)])
    tris = np.array([np.c_[np.asarray(t.exterior.coords)[:3], np.zeros(3)] for t in (tri, big)])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        out, owner, _ = sm._clipped_to_surfaces(tris, np.zeros(2, dtype=np.int64),
                                                np.zeros((2, 3, 2)), np.array([surface]))
    area = np.abs(sm._tri_area2(out[:, 0, :2], out[:, 1, :2], out[:, 2, :2])).sum() / 2
    assert area == pytest.approx(surface.area, rel=1e-9)
