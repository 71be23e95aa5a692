"""Triangulated 3D street mesh: street and junction surfaces as triangles, with side faces
where a street leaves the terrain (Scharl 2010, ch. 5.2).

Scharl tessellates every street between its two connecting lines into a regularly
subdivided strip that is "displaced according to the terrain height to nestle against the
underlying terrain surface", lifts it "by a configurable offset to avoid z-fighting", and
"adds side faces to the geometry that intersect with the underlying terrain" so that the
street does not appear to float (Fig. 5.6); a junction is its *street heads*, triangles
from the junction's centre point to the two corner points of each street (Fig. 5.2),
rotated into the terrain's tangent plane (Fig. 5.3).

:func:`street_mesh` builds exactly that from a :class:`street_surfaces.Tessellation`:

* **streets**: stations every ``spacing`` metres along each surface's centre line, from
  connecting line to connecting line, and at each of its bends; the left and right edge
  points are the station offset by half the width along the normal (the end stations are
  the ends of the junction's connecting line, to the last bit: street and junction share
  that edge), at a bend the surface's inner corner and a fan over its round outer side
  (:func:`_stations`); each pair of stations makes two triangles, cut back where a
  street's strip folds over itself (hairpins: :func:`_without_folds`) or over a street or
  junction that trimmed its surface; z is the draped height of the surface (terrain
  blended into the junction planes) plus ``z_offset``;
* **junctions**: the fan of triangles from the centre point over the junction ring (the
  street heads and the corner fills between them), z in the junction's tangent plane plus
  ``z_offset``; a ring that is not star-shaped around its centre (cut where streets
  overlapped) is ear-clipped instead (hand-written: shapely 2.0 has no constrained
  triangulation and no other library here does it; rings are a few dozen vertices);
* **side faces**: along both street edges where they are the paved area's outline (not
  inside a hairpin or under the street beside: :func:`_on_outline`; an edge that is so in
  part split where it leaves it: :func:`_walls`), across a dead end's
  last cross-section, and
  along the junction rings' outer edges (the
  corner fills between the street heads; not the connecting lines a street continues
  from), wherever the edge lies more than ``min_gap`` above the terrain, a quad (two
  triangles) from the edge down to ``skirt`` metres below the terrain. A junction lies in
  the terrain's tangent plane, which meets the terrain only at its centre: on a convex
  slope its corners float without them.

Without a DEM the mesh is flat (z = 0) and has no side faces.

**Texture coordinates** (Scharl 5.3, Fig. 5.7): Scharl textures every street with one
road texture, u across the street (0 on one edge, 1 on the other: the lines of the hard
shoulders near 0 and 1, the double line between the two lanes at 0.5) and one row of the
texture for the streets, another for the junctions, so that the lanes' double line is not
drawn on a junction. Here every vertex gets (u, v): on a street u = 0 on its left edge and
1 on its right, v the street row (:data:`TEXTURE_ROWS`); on a junction u = 0.5 (plain
asphalt: no line) in the junction row; a side face u = 0 at its top edge and 1 at its foot
in the kerb row. GeoPackage has no place for them: :func:`write_obj` writes the mesh as
a Wavefront OBJ with its texture coordinates, a material file and the road texture
(:func:`road_texture`).

Output: one MultiPolygon Z of triangles per street surface or junction (QGIS 3.22 renders
it in its 3D view and cannot hold a TIN geometry), and the same triangles as TIN Z
geometries in a GeoPackage written with GDAL/OGR (:func:`write_tin_geopackage`; QGIS 3.22
reads a TIN layer as MultiPolygon Z).

Everything is vectorised with numpy / shapely over stations and triangles; the only
Python loop is the ear clipping of the rare non-star junction rings.

References
----------
Scharl, S. (2010). Artist-controlled urban modeling (thesis), ch. 5.1-5.2, Fig. 5.2-5.6.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd
import shapely
from scipy.spatial import cKDTree

from ..core.geometry import end_sections
from ..core.progress import InputError, require

__all__ = ["MESH_FIELDS", "TEXTURE_ROWS", "StreetMesh", "street_mesh", "tin_wkb",
           "write_tin_geopackage", "road_texture", "write_obj"]

#: v of the texture row of each kind of face (Scharl 5.3: one row for the streets, one for
#: the junctions; a third here for the side faces), the middle of its third of the image.
TEXTURE_ROWS = {"street": 5 / 6, "junction": 1 / 2, "side": 1 / 6}
#: m²: triangles no larger than this are left out of the mesh (degenerate slivers)
MIN_TRIANGLE_AREA = 1e-6

#: Attributes of a mesh feature.
MESH_FIELDS = [("mesh_id", "int"), ("kind", "str"), ("source_id", "int"),
               ("triangles", "int"), ("side_triangles", "int"), ("z_min", "float"),
               ("z_max", "float")]

_WKB_TIN_Z = 1016
_WKB_TRIANGLE_Z = 1017


@dataclass
class StreetMesh:
    """Triangles of a street network.

    Attributes
    ----------
    triangles : ndarray (t, 3, 3)
        Vertices (x, y, z) of every triangle, counter-clockwise seen from outside.
    owner : ndarray (t,)
        Feature (row of ``table``) of every triangle.
    side : ndarray (t,) of bool
        Side face (True) or top face.
    table : DataFrame (:data:`MESH_FIELDS`)
    uv : ndarray (t, 3, 2)
        Texture coordinates of every triangle's vertices (see the module doc).
    """

    triangles: np.ndarray
    owner: np.ndarray
    side: np.ndarray
    table: pd.DataFrame
    uv: np.ndarray = None

    def geometries(self) -> np.ndarray:
        """One MultiPolygon Z of triangles per feature."""
        n = len(self.table)
        if len(self.triangles) == 0:
            return np.array([shapely.MultiPolygon()] * n, dtype=object)
        ring = np.concatenate([self.triangles, self.triangles[:, :1]], axis=1)  # (t, 4, 3)
        idx = np.repeat(np.arange(len(ring)), 4)
        polys = shapely.polygons(shapely.linearrings(ring.reshape(-1, 3), indices=idx))
        return shapely.multipolygons(polys, indices=self.owner)


def _unit(v):
    n = np.hypot(v[:, 0], v[:, 1])
    return v / np.where(n > 0, n, 1.0)[:, None]


def _tri_area2(a, b, c):
    """Twice the signed area of 2D triangles (n, 2) each."""
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


def _ear_clip(xy: np.ndarray) -> np.ndarray:
    """Triangles (k, 3) of vertex indices of a simple counter-clockwise ring (no closing
    vertex), by ear clipping."""
    idx = list(range(len(xy)))
    out = []
    guard = 0
    while len(idx) > 3 and guard < 10 * len(xy):
        guard += 1
        m = len(idx)
        for k in range(m):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % m]
            a, b, c = xy[i0], xy[i1], xy[i2]
            if _tri_area2(a[None], b[None], c[None])[0] <= 1e-12:
                continue
            others = np.array([j for j in idx if j not in (i0, i1, i2)])
            if len(others):
                p = xy[others]
                d1 = _tri_area2(np.repeat(a[None], len(p), 0), np.repeat(b[None], len(p), 0), p)
                d2 = _tri_area2(np.repeat(b[None], len(p), 0), np.repeat(c[None], len(p), 0), p)
                d3 = _tri_area2(np.repeat(c[None], len(p), 0), np.repeat(a[None], len(p), 0), p)
                if ((d1 >= 0) & (d2 >= 0) & (d3 >= 0)).any():
                    continue
            out.append((i0, i1, i2))
            del idx[k]
            break
        else:
            break  # no ear (a degenerate ring): stop with what was cut
    if len(idx) == 3:
        out.append(tuple(idx))
    return np.asarray(out, dtype=np.int64).reshape(-1, 3)


def _junction_rings(polys: np.ndarray):
    """The junction polygons' outer rings, counter-clockwise: (vertices (n, 2) without the
    closing ones, index of each vertex's successor on its ring, ring of each vertex, the
    polygon of each ring, the parts, each ring's first vertex and end)."""
    parts, part_owner = shapely.get_parts(polys, return_index=True)
    # normalize() gives clockwise exteriors: reversed, they run counter-clockwise
    rings = shapely.reverse(shapely.get_exterior_ring(shapely.normalize(parts)))
    xy, ring_idx = shapely.get_coordinates(rings, return_index=True)
    last = np.r_[ring_idx[1:] != ring_idx[:-1], True]
    xy, ring_idx = xy[~last], ring_idx[~last]            # drop each closing vertex
    nxt = np.arange(len(xy)) + 1
    first = np.r_[True, ring_idx[1:] != ring_idx[:-1]]
    starts = np.flatnonzero(first)
    ends = np.r_[starts[1:], len(xy)]
    nxt[ends - 1] = starts
    return xy, nxt, ring_idx, part_owner, parts, starts, ends


def _junction_triangles(polys: np.ndarray, centres: np.ndarray):
    """2D triangles (k, 3, 2) of junction polygons and their polygon index: the fan from
    the centre where the ring is star-shaped around it, else ear clipping."""
    xy, nxt, ring_idx, part_owner, parts, starts, ends = _junction_rings(polys)
    c = centres[part_owner[ring_idx]]
    area = _tri_area2(c, xy, xy[nxt])
    ok_ring = np.ones(len(parts), dtype=bool)
    np.logical_and.at(ok_ring, ring_idx, area > 1e-9)
    inside = shapely.contains_xy(parts, centres[part_owner, 0], centres[part_owner, 1])
    ok_ring &= inside
    fan = ok_ring[ring_idx]
    tris = [np.stack([c[fan], xy[fan], xy[nxt][fan]], axis=1)]
    owner = [part_owner[ring_idx[fan]]]
    for r in np.flatnonzero(~ok_ring):
        ring = xy[starts[r]:ends[r]]
        if len(ring) < 3:
            continue
        t = _ear_clip(ring)
        if len(t):
            tris.append(ring[t])
            owner.append(np.full(len(t), part_owner[r]))
    return np.concatenate(tris), np.concatenate(owner)


def _trimmed(area: np.ndarray, owner: np.ndarray, surfaces: np.ndarray) -> np.ndarray:
    """Per street, whether its strip's triangles (of ``area``) cover more than its surface:
    the surface was trimmed where it overlapped another street or a junction."""
    strip = np.bincount(owner, weights=area, minlength=len(surfaces))
    return strip > shapely.area(surfaces) * (1 + 1e-6) + 1e-6


def _clipped_to_surfaces(tris: np.ndarray, owner: np.ndarray, uv: np.ndarray, surfaces,
                         z_of=None, u_of=None):
    """Street top triangles (n, 3, 3) cut back to their own surface polygons where those
    were trimmed (streets overlapping each other or a junction: the strips between the
    connecting lines ignore the trim). A triangle partly outside becomes the ear-clipped
    pieces of its part inside (:func:`_replaced`). Returns (tris, owner, uv)."""
    area = np.abs(_tri_area2(tris[:, 0, :2], tris[:, 1, :2], tris[:, 2, :2])) / 2
    sel = np.flatnonzero(_trimmed(area, owner, surfaces)[owner])
    if not len(sel):
        return tris, owner, uv
    # polygons of the triangles of trimmed streets only (most streets are not)
    t2 = shapely.polygons(tris[sel][:, [0, 1, 2, 0], :2])
    with np.errstate(invalid="ignore"):   # GEOS flags some slivers' cuts; the result is right
        inside = shapely.intersection(t2, surfaces[owner[sel]])
    # a triangle out by round-off (under a millionth of it: the fans of a bend follow the
    # surface's arc to the last digit) stays whole
    whole = shapely.area(inside) >= area[sel] * (1 - 1e-6)
    cut = sel[~whole]
    return _replaced(tris, owner, uv, cut, inside[~whole], z_of, u_of)


def _without_folds(tris: np.ndarray, owner: np.ndarray, uv: np.ndarray, may_fold, z_of=None,
                   u_of=None):
    """Street top triangles with no two of one street over each other: a triangle that
    overlaps earlier ones of its street (where a street bends back on itself -- a hairpin,
    a bend whose inner corner lies beyond the next bend or the street's end -- its strip
    folds, the surface does not) keeps only its part outside them. Only the streets
    ``may_fold`` (bool per street) are looked at. Returns (tris, owner, uv)."""
    sel = np.flatnonzero(may_fold[owner])
    t2 = shapely.polygons(tris[sel][:, [0, 1, 2, 0], :2])
    a, b = shapely.STRtree(t2).query(t2)
    pair = (owner[sel[a]] == owner[sel[b]]) & (b < a)          # a later triangle, an earlier
    a, b = a[pair], b[pair]
    if not len(a):
        return tris, owner, uv
    with np.errstate(invalid="ignore"):              # degenerate fan triangles
        overlap = shapely.area(shapely.intersection(t2[a], t2[b]))
    fold = overlap > MIN_TRIANGLE_AREA
    a, b = a[fold], b[fold]
    if not len(a):
        return tris, owner, uv
    order = np.argsort(a, kind="stable")
    a, b = a[order], b[order]
    later, start = np.unique(a, return_index=True)
    earlier = np.array([shapely.union_all(group) for group in np.split(t2[b], start[1:])],
                       dtype=object)
    with np.errstate(invalid="ignore"):
        rest = shapely.difference(t2[later], earlier)
    return _replaced(tris, owner, uv, sel[later], rest, z_of, u_of)


def _replaced(tris, owner, uv, which, shapes, z_of=None, u_of=None):
    """The triangles ``which`` replaced by the ear-clipped parts of ``shapes`` (their parts
    to keep, polygons within them), with (u, v) interpolated in each triangle's plane and z
    too, or z from ``z_of(owner, xy)`` (the drape) and u from ``u_of(owner, xy)`` when
    given: a triangle of a bend's fan reaches to the bend's inner corner, beyond the
    surface on a hairpin (kilometres on one of 179.9°), and z interpolated from there was
    metres off the drape, u up to the street's width off. Returns (tris, owner, uv)."""
    keep = np.ones(len(tris), dtype=bool)
    keep[which] = False
    pieces, parent = shapely.get_parts(shapes, return_index=True)
    new_xy, new_z, new_o, new_uv = [], [], [], []
    for piece, i in zip(pieces, which[parent]):
        if shapely.get_type_id(piece) != 3 or piece.area < MIN_TRIANGLE_AREA:
            continue
        ring = np.asarray(shapely.geometry.polygon.orient(piece, 1.0).exterior.coords)[:-1, :2]
        ears = _ear_clip(ring)
        if not len(ears):
            continue
        # barycentric coordinates of the ring's vertices in the parent triangle
        a, b, c = tris[i, 0, :2], tris[i, 1, :2], tris[i, 2, :2]
        m = np.array([[b[0] - a[0], c[0] - a[0]], [b[1] - a[1], c[1] - a[1]]])
        st = np.linalg.solve(m, (ring - a).T).T
        w = np.column_stack([1 - st.sum(1), st])
        new_xy.append(ring[ears])
        new_z.append((w @ tris[i, :, 2])[ears])
        new_uv.append((w @ uv[i])[ears])
        new_o.append(np.full(len(ears), owner[i]))
    tris, owner, uv = tris[keep], owner[keep], uv[keep]
    if new_xy:
        xy, own = np.concatenate(new_xy), np.concatenate(new_o)
        z = np.concatenate(new_z) if z_of is None else \
            z_of(np.repeat(own, 3), xy.reshape(-1, 2)).reshape(-1, 3)
        tris = np.concatenate([tris, np.concatenate([xy, z[:, :, None]], axis=2)])
        owner = np.concatenate([owner, own])
        new_uv = np.concatenate(new_uv)
        if u_of is not None:
            new_uv[:, :, 0] = u_of(np.repeat(own, 3), xy.reshape(-1, 2)).reshape(-1, 3)
        uv = np.concatenate([uv, new_uv])
    return tris, owner, uv


def _paved(tess):
    """The street surfaces then the junctions, 2D and prepared, with their STRtree: what
    :func:`_on_outline` tests every side face's edge against (built once per mesh)."""
    paved = shapely.force_2d(np.r_[np.asarray(tess.surfaces, dtype=object),
                                   np.asarray(tess.junctions, dtype=object)])
    shapely.prepare(paved)
    return paved, shapely.STRtree(paved)


def _on_outline(a: np.ndarray, b: np.ndarray, own: np.ndarray, paved) -> np.ndarray:
    """Whether each edge a -> b of a street or junction (``own``: its index in the
    polygons of ``paved``, :func:`_paved`) is an outer edge of the paved area: its middle
    lies on its own surface's outline (within a centimetre of it, not inside it) and
    within a centimetre of no other surface. Otherwise the side face would stand inside
    the pavement -- on a hairpin's inner edge, which its other leg covers; between two
    streets or a street and a junction that abut (a connecting line, a surface trimmed
    where it overlapped the other) -- or off it: an edge to a hairpin's inner corner,
    which lies beyond its legs (a side face 9 km long on a 179.95° hairpin)."""
    mid = 0.5 * (a + b)
    # a centimetre box round each middle: intersects and contains on prepared polygons are
    # much cheaper than distances (0.6 M side faces on the benchmark's DEM grid)
    box = shapely.box(mid[:, 0] - 0.01, mid[:, 1] - 0.01, mid[:, 0] + 0.01, mid[:, 1] + 0.01)
    polygons, tree = paved
    i, p = tree.query(box, predicate="intersects")
    mine = p == own[i]
    on_own = np.zeros(len(mid), dtype=bool)
    on_own[i[mine][~shapely.contains_properly(polygons[p[mine]], box[i[mine]])]] = True
    return on_own & ~np.isin(np.arange(len(mid)), i[~mine])


def _walls(top, ground, a, b, own, paved, terrain_z, skirt):
    """Side faces (:func:`_side_faces`) under the top edges a -> b of feature ``own`` where
    they are the paved area's outline (:func:`_on_outline`). An edge whose middle and
    vertices disagree on that is split where it crosses the outline of its own or another
    polygon and each piece is tested alone: tested whole, it got its wall whole or lost
    it whole. Returns (the faces' two triangle arrays, the owner of each quad)."""
    pa, pb = top[a, :2], top[b, :2]
    length = np.hypot(*(pb - pa).T)
    mid = _on_outline(pa, pb, own, paved)
    # the vertices (most are two edges'), with their feature
    vtx, inv = np.unique(np.r_[a, b], return_inverse=True)
    v_own = np.empty(len(vtx), dtype=np.int64)
    v_own[inv] = np.r_[own, own]
    at = _on_outline(top[vtx, :2], top[vtx, :2], v_own, paved)[inv].reshape(2, -1)
    part = (at[0] != mid) | (at[1] != mid)
    whole = mid & ~part
    faces = _side_faces(top, ground, a[whole], b[whole], skirt)
    owner = own[whole]
    if part.any():
        e = np.flatnonzero(part)
        seg = shapely.linestrings(np.stack([pa[e], pb[e]], axis=1))
        i, q = paved[1].query(seg, predicate="intersects")
        cross = shapely.intersection(seg[i], shapely.boundary(paved[0][q]))
        xy, w = shapely.get_coordinates(cross, return_index=True)
        d = pb[e] - pa[e]
        t = ((xy - pa[e][i[w]]) * d[i[w]]).sum(1) / (d[i[w]] ** 2).sum(1)
        t = np.r_[t, np.zeros(len(e)), np.ones(len(e))]              # and both ends
        g = np.r_[i[w], np.arange(len(e)), np.arange(len(e))]
        order = np.lexsort((t, g))
        t, g = np.clip(t[order], 0.0, 1.0), g[order]
        piece = np.flatnonzero((g[1:] == g[:-1]) & (np.diff(t) * length[e][g[1:]] > 1e-6))
        t0, t1, g = t[piece], t[piece + 1], g[piece]
        ta, tb = top[a[e][g]], top[b[e][g]]       # t = 1 is the vertex b itself
        ta, tb = ta + t0[:, None] * (tb - ta), \
            np.where(t1[:, None] < 1, ta + t1[:, None] * (tb - ta), tb)
        on = _on_outline(ta[:, :2], tb[:, :2], own[e][g], paved)
        n = int(on.sum())
        pts = np.vstack([ta[on], tb[on]])
        faces = [np.concatenate(x) for x in zip(faces, _side_faces(
            pts, terrain_z(pts[:, :2]), np.arange(n), np.arange(n) + n, skirt))]
        owner = np.r_[owner, own[e][g][on]]
    return faces, owner


def _side_faces(top: np.ndarray, ground: np.ndarray, a: np.ndarray, b: np.ndarray,
                skirt: float) -> list:
    """The two triangles of each vertical face from the top edges a -> b (the outside on
    their right) down to ``skirt`` below the terrain (``ground``, NaN: the top's height)."""
    lo_a = np.column_stack([top[a, :2], np.nan_to_num(ground[a], nan=top[a, 2]) - skirt])
    lo_b = np.column_stack([top[b, :2], np.nan_to_num(ground[b], nan=top[b, 2]) - skirt])
    return [np.stack([top[a], lo_a, lo_b], axis=1), np.stack([top[a], lo_b, top[b]], axis=1)]


#: A street's vertex this near a junction's (m, in 3D) is that vertex.
VERTEX_SNAP = 1e-6


def _onto_junction_vertices(triangles: np.ndarray, junction: np.ndarray,
                            street: np.ndarray) -> np.ndarray:
    """Triangles (n, 3, 3) with the vertices of the ``street`` ones (bool per triangle: the
    streets' top faces) that lie within :data:`VERTEX_SNAP` of a vertex of a ``junction``
    one moved onto it: the corner of a street surface trimmed by GEOS where it meets a
    junction's edge comes out a micrometre off the junction's own vertex (Helsinki: 96
    street vertices), a crack for a mesh joined by its vertices. (The side faces stand on
    the stations, which the junctions share exactly.)"""
    if not junction.any() or not street.any():
        return triangles
    target = np.unique(triangles[junction].reshape(-1, 3), axis=0)
    out = triangles.copy()
    moved = out[street].reshape(-1, 3)
    d, near = cKDTree(target).query(moved, distance_upper_bound=VERTEX_SNAP)
    hit = np.isfinite(d) & (d > 0)
    moved[hit] = target[near[hit]]
    out[street] = moved.reshape(-1, 3, 3)
    return out


def _across(centres: np.ndarray, widths: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """u of points (n, 2) on streets of centre lines ``centres`` and ``widths`` (one per
    point): 0.5 on the centre line, 0 at its width's half to the left, 1 to the right (as
    the stations give their edges), by the distance to the line, on the side of its
    direction there (a bend's outer arc is that far from the bend's vertex)."""
    pts = shapely.points(xy)
    along = shapely.line_locate_point(centres, pts)
    p0 = shapely.get_coordinates(shapely.line_interpolate_point(
        centres, np.maximum(along - 0.01, 0.0)))    # (a negative distance: from the end)
    p1 = shapely.get_coordinates(shapely.line_interpolate_point(centres, along + 0.01))
    d, r = p1 - p0, xy - 0.5 * (p0 + p1)
    side = np.sign(d[:, 0] * r[:, 1] - d[:, 1] * r[:, 0])
    offset = side * shapely.distance(centres, pts)
    return np.clip(0.5 - offset / np.maximum(widths, 1e-9), 0.0, 1.0)


def _quad_uv(n: int, kind: str) -> list:
    """Texture coordinates of the two triangles of each of ``n`` quads in the row of
    ``kind``, u 0 on one edge and 1 on the other (the vertex order of a street's quads:
    left i, right i, right j / left i, right j, left j; and of :func:`_side_faces`: top
    a, foot a, foot b / top a, foot b, top b)."""
    row = TEXTURE_ROWS[kind]
    return [np.tile([[0.0, row], [1.0, row], [1.0, row]], (n, 1, 1)),
            np.tile([[0.0, row], [1.0, row], [0.0, row]], (n, 1, 1))]


#: radians of arc per fan triangle at a bend's outer side: the buffer's 8 segments per
#: quarter circle (street_surfaces._QUAD_SEGS), so the mesh follows the surface's round join
_ARC_STEP = np.pi / 16


def _rotated(v: np.ndarray, angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]])


def _stations(centres: np.ndarray, half: np.ndarray, spacing: float):
    """Cross-sections of the streets: (street index, left edge xy, right edge xy) per
    station, in order along each street, and per street whether its strip may fold.

    Stations lie every ``spacing`` metres from end to end, and at every bend of a centre
    line (a vertex where it turns), where the surface -- the line buffered by half its
    width, round joins -- has a corner on the inner side (the mitre point, w / 2 / cos(turn /
    2) from the vertex) and an arc on the outer side: the bend's stations share the mitre
    point and fan out over the arc in steps of :data:`_ARC_STEP`. An evenly spaced station
    closer to a bend than the mitre point reaches along the street (w / 2 * tan(turn / 2))
    is left out, its inner edge point would lie past the corner: with stations only every
    few metres, the strip folded over itself on the inner side of a bend and left the
    outer side open (Vaduz: 655 m² of folds and 1,445 m² of gaps). Where a bend's corner
    lies beyond the street's end or the next bend's (a hairpin, a bend just past a
    junction), the strip may still fold: those streets are flagged for
    :func:`_without_folds`."""
    n_s = len(centres)
    length = shapely.length(centres)
    count = np.maximum(np.ceil(length / spacing).astype(np.int64), 1) + 1
    k = np.repeat(np.arange(n_s), count)
    start = np.cumsum(count) - count
    step = np.arange(len(k)) - start[k]
    pos = step / (count[k] - 1) * length[k]
    geom = centres[k]
    p = shapely.get_coordinates(shapely.line_interpolate_point(geom, pos))
    eps = np.minimum(0.01, 0.25 * length[k])
    ahead = shapely.get_coordinates(shapely.line_interpolate_point(
        geom, np.minimum(pos + eps, length[k])))
    behind = shapely.get_coordinates(shapely.line_interpolate_point(
        geom, np.maximum(pos - eps, 0.0)))
    d = _unit(ahead - behind)
    nrm = np.column_stack([-d[:, 1], d[:, 0]])
    left, right = p + half[k][:, None] * nrm, p - half[k][:, None] * nrm
    # the end stations: the surface's and the junction's edge, to the last bit
    ends = np.r_[start, start + count - 1]
    end_left, end_right = end_sections(centres, half)
    left[ends], right[ends] = end_left.transpose(1, 0, 2).reshape(-1, 2), \
        end_right.transpose(1, 0, 2).reshape(-1, 2)

    # the bends: interior vertices where the line turns
    xy, line = shapely.get_coordinates(centres, return_index=True)
    seg = xy[1:] - xy[:-1]
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    same = line[1:] == line[:-1]
    along = np.cumsum(np.r_[0.0, np.where(same, seg_len, 0.0)])
    along -= along[np.searchsorted(line, line)]          # distance from the line's start
    v = np.flatnonzero(np.r_[False, same[:-1] & same[1:], False])
    with np.errstate(invalid="ignore", divide="ignore"):
        d_in = seg[v - 1] / seg_len[v - 1, None]
        d_out = seg[v] / seg_len[v, None]
    turn = np.nan_to_num(np.arctan2(d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0],
                                    (d_in * d_out).sum(1)))
    bend = np.abs(turn) > 1e-6
    v, d_in, turn = v[bend], d_in[bend], turn[bend]
    lv, sv, hv = line[v], along[v], half[line[v]]
    if not len(v):
        return k, left, right, np.zeros(n_s, dtype=bool)
    # evenly spaced stations in a bend's shadow go (the street's two end stations stay)
    reach = hv * np.tan(np.abs(turn) / 2)
    # a shadow past an end or over the next bend's: the strip may fold there
    folds = np.zeros(n_s, dtype=bool)
    nxt = np.r_[lv[1:] == lv[:-1], False]
    folds[lv[(sv - reach < 0) | (sv + reach > length[lv])]] = True
    folds[lv[:-1][nxt[:-1] & (sv[1:] - reach[1:] < sv[:-1] + reach[:-1])]] = True
    offset = np.cumsum(length + 1.0) - (length + 1.0)    # lines laid end to end, 1 m apart
    at = offset[k] + pos
    lo = np.searchsorted(at, offset[lv] + np.maximum(sv - reach, 0.0), side="left")
    hi = np.searchsorted(at, offset[lv] + np.minimum(sv + reach, length[lv]), side="right")
    cover = np.zeros(len(k) + 1, dtype=np.int64)
    np.add.at(cover, lo, 1)
    np.add.at(cover, hi, -1)
    keep = (np.cumsum(cover)[:-1] == 0) | (step == 0) | (step == count[k] - 1)
    # the bends' fans: the mitre point inside, the arc outside
    # as many arc segments as GEOS's round join gives the surface (rounded to nearest)
    fan = np.maximum((np.abs(turn) / _ARC_STEP + 0.5).astype(np.int64), 1) + 1
    b = np.repeat(np.arange(len(v)), fan)
    t = (np.arange(len(b)) - (np.cumsum(fan) - fan)[b]) / (fan[b] - 1)
    n_in = np.column_stack([-d_in[:, 1], d_in[:, 0]])
    arc = _rotated(n_in[b], t * turn[b])
    mitre = _rotated(n_in, turn / 2) / np.cos(turn / 2)[:, None]
    centre = xy[v][b]
    inner = centre + (hv * np.sign(turn))[b][:, None] * mitre[b]   # left of a left turn
    outer = centre - (hv * np.sign(turn))[b][:, None] * arc
    left_turn = (turn > 0)[b][:, None]
    f_left = np.where(left_turn, inner, outer)
    f_right = np.where(left_turn, outer, inner)
    # every station in order along its street: by street, distance, then along the fan
    k_all = np.r_[k[keep], lv[b]]
    key = np.lexsort((np.r_[np.zeros(keep.sum()), t],
                      np.r_[pos[keep], sv[b]], k_all))
    return (k_all[key], np.vstack([left[keep], f_left])[key],
            np.vstack([right[keep], f_right])[key], folds)


def street_mesh(tess, spacing: float = 5.0, z_offset: float = 0.1, skirt: float = 0.5,
                min_gap: float = 0.01) -> StreetMesh:
    """Triangulated 3D mesh of a tessellated street network (see module doc).

    Parameters
    ----------
    tess : street_surfaces.Tessellation
        With ``surface_z`` / ``junction_z`` / ``terrain_z`` when it was draped on a DEM.
    spacing : float
        Station spacing along the streets (m).
    z_offset : float
        Lift of the street above its draped height (Scharl: against z-fighting), m.
    skirt : float
        Side faces reach this far below the terrain (m).
    min_gap : float
        A street edge more than this above the terrain gets a side face (m).

    Returns
    -------
    StreetMesh
        Features: every surface (kind 'street', source_id = segment_id), then every
        junction (kind 'junction', source_id = junction_id).
    """
    if not np.isfinite(spacing) or spacing <= 0:
        raise InputError(f"the mesh spacing must be positive (got {spacing})")
    if tess.centres is None:
        raise InputError("the tessellation has no centre lines to mesh")
    draped = tess.surface_z is not None
    centres = np.asarray(tess.centres, dtype=object)
    n_s = len(centres)
    widths = tess.widths[tess.surface_edge] if n_s else np.zeros(0)
    tris, owner, side, uv = [], [], [], []
    paved = _paved(tess) if draped else None     # the side faces' outline test
    if n_s:
        k, left, right, may_fold = _stations(centres, widths / 2.0, spacing)
        if draped:
            zl = tess.surface_z(k, left) + z_offset
            zr = tess.surface_z(k, right) + z_offset
        else:
            zl = np.zeros(len(k))
            zr = np.zeros(len(k))
        L3 = np.column_stack([left, zl])
        R3 = np.column_stack([right, zr])
        i = np.flatnonzero(k[1:] == k[:-1])            # station i and i + 1 on one street
        j = i + 1
        # the two triangles of each quad, quad after quad along the street
        top = np.stack([np.stack([L3[i], R3[i], R3[j]], axis=1),
                        np.stack([L3[i], R3[j], L3[j]], axis=1)], axis=1).reshape(-1, 3, 3)
        top_uv = np.stack(_quad_uv(len(i), "street"), axis=1).reshape(-1, 3, 2)  # u: 0 left
        flat_surfaces = shapely.force_2d(np.asarray(tess.surfaces))
        drape = (lambda own, xy: tess.surface_z(own, xy) + z_offset) if draped else None

        def across(own, xy):
            return _across(centres[own], widths[own], xy)

        top, top_owner, top_uv = _without_folds(top, np.repeat(k[i], 2), top_uv, may_fold,
                                                drape, across)
        top, top_owner, top_uv = _clipped_to_surfaces(top, top_owner, top_uv, flat_surfaces,
                                                      drape, across)
        tris.append(top)
        owner.append(top_owner)
        side.append(np.zeros(len(top), dtype=bool))
        uv.append(top_uv)
        if draped:
            tl = tess.terrain_z(left)
            tr = tess.terrain_z(right)
            # a dead end's last cross-section is an outer edge too (its street ends there)
            edge = tess.surface_edge
            dead = tess.graph.degree == 1
            first = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
            last = np.flatnonzero(np.r_[k[1:] != k[:-1], True])
            at_u = first[dead[tess.graph.u[edge]]]
            at_v = last[dead[tess.graph.v[edge]]]
            both = np.vstack([L3, R3])
            ground = np.r_[tl, tr]
            n_st = len(L3)
            for top, ground_, a, b in ((L3, tl, j, i), (R3, tr, i, j),
                                       # outward: behind the start, ahead of the end
                                       (both, ground, at_u, n_st + at_u),
                                       (both, ground, n_st + at_v, at_v)):
                # outward: the left edge runs backwards, the right edge forwards
                gap = np.nan_to_num(top[:, 2] - ground_, nan=0.0)
                up = (gap[a] > min_gap) | (gap[b] > min_gap)
                faces, own = _walls(top, ground_, a[up], b[up], k[a[up] % n_st], paved,
                                    tess.terrain_z, skirt)
                tris += faces
                owner += [own, own]
                side += [np.ones(2 * len(own), dtype=bool)]
                uv += _quad_uv(len(own), "side")
    n_j = len(tess.junctions)
    if n_j:
        nodes = tess.graph.nodes[tess.junction_node]
        t2, jo = _junction_triangles(shapely.force_2d(tess.junctions), nodes)
        flat = t2.reshape(-1, 2)
        node_of = np.repeat(tess.junction_node[jo], 3)
        z = (tess.junction_z(node_of, flat) + z_offset) if draped else np.zeros(len(flat))
        tris.append(np.column_stack([flat, z]).reshape(-1, 3, 3))
        owner.append(n_s + jo)
        side.append(np.zeros(len(jo), dtype=bool))
        uv.append(np.tile([0.5, TEXTURE_ROWS["junction"]], (len(jo), 3, 1)))
        if draped:
            xy, nxt, ring_idx, part_owner, _, _, _ = _junction_rings(
                shapely.force_2d(tess.junctions))
            jr = part_owner[ring_idx]
            node = tess.junction_node[jr]
            top = np.column_stack([xy, tess.junction_z(node, xy) + z_offset])
            gap = np.nan_to_num(top[:, 2] - tess.terrain_z(xy), nan=0.0)
            # (not an edge a street continues from: its connecting line)
            a = np.flatnonzero((gap > min_gap) | (gap[nxt] > min_gap))   # outside: right
            faces, own = _walls(top, tess.terrain_z(xy), a, nxt[a], n_s + jr[a], paved,
                                tess.terrain_z, skirt)
            tris += faces
            owner += [own, own]
            side += [np.ones(2 * len(own), dtype=bool)]
            uv += _quad_uv(len(own), "side")
    triangles = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
    owner = np.concatenate(owner).astype(np.int64) if owner else np.zeros(0, np.int64)
    side = np.concatenate(side) if side else np.zeros(0, bool)
    uv = np.concatenate(uv) if uv else np.zeros((0, 3, 2))
    triangles = _onto_junction_vertices(triangles, ~side & (owner >= n_s), ~side & (owner < n_s))
    # degenerate triangles (two corners within a millimetre: stations where a junction's
    # connecting line meets a fan, round-off of the clipping) are no faces: an OBJ with a
    # repeated vertex in a face trips 3D software
    area3 = 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0],
                                          triangles[:, 2] - triangles[:, 0]), axis=1)
    ok = area3 > MIN_TRIANGLE_AREA
    triangles, owner, side, uv = triangles[ok], owner[ok], side[ok], uv[ok]
    order = np.argsort(owner, kind="stable")
    triangles, owner, side, uv = triangles[order], owner[order], side[order], uv[order]
    n = n_s + n_j
    zs = triangles[:, :, 2]
    z_min = np.full(n, np.nan)
    z_max = np.full(n, np.nan)
    if len(triangles):
        np.fmin.at(z_min, owner, zs.min(1))
        np.fmax.at(z_max, owner, zs.max(1))
    table = pd.DataFrame({
        "mesh_id": np.arange(1, n + 1),
        "kind": np.r_[np.full(n_s, "street", dtype=object), np.full(n_j, "junction", dtype=object)],
        "source_id": np.r_[tess.surface_table["segment_id"].to_numpy()[:n_s] if n_s else [],
                           tess.junction_table["junction_id"].to_numpy()[:n_j] if n_j else []
                           ].astype(np.int64),
        "triangles": np.bincount(owner, minlength=n),
        "side_triangles": np.bincount(owner, weights=side, minlength=n).astype(np.int64),
        "z_min": z_min, "z_max": z_max})
    return StreetMesh(triangles, owner, side, table, uv)


def tin_wkb(multipolygons: Sequence) -> list:
    """ISO WKB of TIN Z geometries from MultiPolygon Z geometries of triangles.

    The two encodings differ only in their type codes (MultiPolygon Z 1006 / Polygon Z
    1003 against TIN Z 1016 / Triangle Z 1017), so the codes are rewritten in place.
    """
    out = []
    for wkb in shapely.to_wkb(np.asarray(multipolygons, dtype=object), flavor="iso",
                              output_dimension=3, byte_order=1):
        b = bytearray(wkb)
        n = struct.unpack_from("<I", b, 5)[0]
        struct.pack_into("<I", b, 1, _WKB_TIN_Z)
        offset = 9
        for _ in range(n):
            struct.pack_into("<I", b, offset + 1, _WKB_TRIANGLE_Z)
            rings = struct.unpack_from("<I", b, offset + 5)[0]
            offset += 9
            for _ in range(rings):
                pts = struct.unpack_from("<I", b, offset)[0]
                offset += 4 + 24 * pts
        out.append(bytes(b))
    return out


def write_tin_geopackage(path: str, layer: str, multipolygons: Sequence,
                         table: pd.DataFrame, fields: Sequence, crs_wkt: str) -> int:
    """Write the triangles as TIN Z features to a GeoPackage layer with GDAL/OGR (the
    layer is replaced if it exists). Returns the number of features written."""
    from osgeo import ogr, osr

    ogr.UseExceptions()
    drv = ogr.GetDriverByName("GPKG")
    import os
    ds = drv.Open(path, 1) if os.path.exists(path) else drv.CreateDataSource(path)
    if ds is None:
        raise InputError(f"cannot write the GeoPackage {path}")
    for i in range(ds.GetLayerCount()):
        if ds.GetLayerByIndex(i).GetName() == layer:
            ds.DeleteLayer(i)
            break
    srs = None
    if crs_wkt:
        srs = osr.SpatialReference()
        srs.ImportFromWkt(crs_wkt)
        srs.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
    lyr = ds.CreateLayer(layer, srs, ogr.wkbTINZ)
    kinds = {"int": ogr.OFTInteger64, "float": ogr.OFTReal, "str": ogr.OFTString}
    for name, typ in fields:
        lyr.CreateField(ogr.FieldDefn(name, kinds.get(typ, ogr.OFTString)))
    defn = lyr.GetLayerDefn()
    lyr.StartTransaction()
    for row, wkb in zip(table.itertuples(index=False), tin_wkb(multipolygons)):
        f = ogr.Feature(defn)
        for name, typ in fields:
            v = getattr(row, name)
            if v is None or (isinstance(v, float) and not np.isfinite(v)):
                continue
            f.SetField(name, int(v) if typ == "int" else float(v) if typ == "float" else str(v))
        f.SetGeometry(ogr.CreateGeometryFromWkb(wkb))
        lyr.CreateFeature(f)
    lyr.CommitTransaction()
    count = lyr.GetFeatureCount()
    ds = None
    return int(count)


def road_texture(size: int = 256) -> np.ndarray:
    """The road texture of :data:`TEXTURE_ROWS` (Scharl Fig. 5.7), a ``size`` x ``size``
    BGR image: in the street row (top third) asphalt with the hard shoulders' lines near
    u = 0 and 1 and the double line between the two lanes at u = 0.5; in the junction row
    (middle) plain asphalt; in the side faces' row (bottom) concrete."""
    img = np.full((size, size, 3), 70, dtype=np.uint8)
    u = (np.arange(size) + 0.5) / size
    street = slice(0, size // 3)
    lines = ((u > 0.06) & (u < 0.09)) | ((u > 0.91) & (u < 0.94)) | \
        ((u > 0.465) & (u < 0.485)) | ((u > 0.515) & (u < 0.535))
    img[street, lines] = 235
    img[size - size // 3:] = 150
    return img


def write_obj(path: str, mesh: StreetMesh, crs_name: str = "") -> dict:
    """Write the mesh as a Wavefront OBJ with texture coordinates, its material file
    (``<name>.mtl``) and the road texture (``<name>_texture.png``) beside it.

    OBJ has no coordinate reference system: x and y are written minus an origin (the
    mesh's south-west corner, whole metres; named with the CRS in the file's first lines)
    so that a millimetre survives single-precision readers. Vertices and texture
    coordinates are shared by the triangles that use them; faces are grouped as streets,
    junctions and side faces. Returns the paths written and the origin."""
    cv2 = require("cv2", "opencv-contrib-python-headless", "OpenCV")  # only this writer needs it

    path = Path(path)
    mtl = path.with_suffix(".mtl")
    png = path.with_name(path.stem + "_texture.png")
    xyz = mesh.triangles.reshape(-1, 3)
    origin = np.floor(xyz[:, :2].min(axis=0)) if len(xyz) else np.zeros(2)
    local = np.round(xyz - np.r_[origin, 0.0], 3)
    verts, vi = np.unique(local, axis=0, return_inverse=True)
    coords, ti = np.unique(mesh.uv.reshape(-1, 2), axis=0, return_inverse=True)
    vi, ti = vi.reshape(-1, 3) + 1, ti.reshape(-1, 3) + 1
    kind = np.asarray(mesh.table["kind"], dtype=object)[mesh.owner] if len(mesh.owner) \
        else np.zeros(0, dtype=object)
    group = np.where(mesh.side, "side_faces", kind + "s")
    if not cv2.imwrite(str(png), road_texture()):
        raise InputError(f"cannot write the texture {png}")
    mtl.write_text(f"newmtl road\nKa 1 1 1\nKd 1 1 1\nmap_Kd {png.name}\n")
    with open(path, "w") as f:
        f.write("# Urban Synthesis street mesh (Scharl 2010, ch. 5.2-5.3)\n"
                f"# x, y: {crs_name or 'the working CRS'} minus the origin "
                f"{origin[0]:.0f} {origin[1]:.0f}; z: metres\n"
                f"mtllib {mtl.name}\n")
        np.savetxt(f, verts, fmt="v %.3f %.3f %.3f")
        np.savetxt(f, coords, fmt="vt %.6f %.6f")
        f.write("usemtl road\n")
        for name in ("streets", "junctions", "side_faces"):
            sel = group == name
            if not sel.any():
                continue
            f.write(f"g {name}\n")
            face = np.stack([vi[sel], ti[sel]], axis=2).reshape(-1, 6)
            np.savetxt(f, face, fmt="f %d/%d %d/%d %d/%d")
    return {"obj": str(path), "mtl": str(mtl), "texture": str(png),
            "origin": (float(origin[0]), float(origin[1]))}
