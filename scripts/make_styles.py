"""Regenerate the QML styles in resources/styles with PyQGIS (run with the venv's python).

The QML files are committed; this script documents how they were made.
"""
import os
import sys
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
from qgis.core import (  # noqa: E402
    QgsApplication, QgsCategorizedSymbolRenderer, QgsFillSymbol, QgsLineSymbol, QgsMarkerSymbol, QgsRendererCategory, QgsRuleBasedRenderer, QgsSingleSymbolRenderer,
    QgsVectorLayer,
)

OUT = Path(__file__).resolve().parent.parent / "resources" / "styles"
LEVEL_COLOURS = ["#b2182b", "#ef6548", "#e6ab02", "#1b9e77", "#7570b3", "#999999", "#bdbdbd"]
LEVEL_WIDTHS = [0.9, 0.65, 0.5, 0.4, 0.32, 0.26, 0.22]


def roads_by_level():
    layer = QgsVectorLayer("LineString?field=level:integer", "roads", "memory")
    cats = []
    for lv, (col, w) in enumerate(zip(LEVEL_COLOURS, LEVEL_WIDTHS)):
        sym = QgsLineSymbol.createSimple({"line_color": col, "line_width": str(w),
                                          "capstyle": "round", "joinstyle": "round"})
        cats.append(QgsRendererCategory(lv, sym, f"level {lv}" + (" (arterial)" if lv == 0 else "")))
    other = QgsLineSymbol.createSimple({"line_color": "#bdbdbd", "line_width": "0.3"})
    cats.append(QgsRendererCategory(None, other, "deeper levels"))
    renderer = QgsCategorizedSymbolRenderer("level", cats)
    renderer.setUsingSymbolLevels(True)
    layer.setRenderer(renderer)
    # arterials drawn on top
    for i, cat in enumerate(renderer.categories()):
        for sl in cat.symbol().symbolLayers():
            sl.setRenderingPass(len(cats) - i)
    layer.saveNamedStyle(str(OUT / "roads_by_level.qml"))


def blocks():
    layer = QgsVectorLayer("Polygon?field=area_m2:double", "blocks", "memory")
    sym = QgsFillSymbol.createSimple({"color": "#f2efe9", "outline_color": "#a39e93",
                                      "outline_width": "0.2"})
    layer.setRenderer(QgsSingleSymbolRenderer(sym))
    layer.saveNamedStyle(str(OUT / "blocks.qml"))


def buildings_by_height():
    layer = QgsVectorLayer("Polygon?field=height_m:double", "buildings", "memory")
    breaks = [(0, 6, "#c6dbef"), (6, 12, "#9ecae1"), (12, 20, "#6baed6"), (20, 35, "#3182bd"),
              (35, 1000, "#08519c")]
    root = QgsRuleBasedRenderer.Rule(None)
    for lo, hi, col in breaks:
        sym = QgsFillSymbol.createSimple({"color": col, "outline_color": "#08306b",
                                          "outline_width": "0.1"})
        label = f"{lo} - {hi} m" if hi < 1000 else f"> {lo} m"
        root.appendChild(QgsRuleBasedRenderer.Rule(
            sym, filterExp=f'"height_m" >= {lo} AND "height_m" < {hi}', label=label))
    unknown = QgsFillSymbol.createSimple({"color": "#d9d9d9", "outline_color": "#737373",
                                          "outline_width": "0.1"})
    root.appendChild(QgsRuleBasedRenderer.Rule(unknown, elseRule=True, label="height unknown"))
    layer.setRenderer(QgsRuleBasedRenderer(root))
    layer.setRenderer3D(buildings_3d())
    layer.saveNamedStyle(str(OUT / "buildings_by_height.qml"))


#: building_type -> colour of its walls and roof in QGIS's 3D view
TYPE_COLOURS_3D = {"residential": "#f1d9b5", "commercial": "#a6bddb", "industrial": "#bdbdbd",
                   "public": "#b8e186", "religious": "#cbc9e2"}


def buildings_3d():
    """Buildings extruded by ``height_m`` in QGIS's 3D map view (3 m where the height is
    unknown), coloured by ``building_type``."""
    from qgis._3d import (Qgs3D, QgsPhongMaterialSettings, QgsPolygon3DSymbol,
                          QgsRuleBased3DRenderer)
    from qgis.core import QgsAbstract3DSymbol, QgsProperty
    from qgis.PyQt.QtGui import QColor

    Qgs3D.initialize()

    def symbol(colour):
        sym = QgsPolygon3DSymbol()
        material = QgsPhongMaterialSettings()
        material.setDiffuse(QColor(colour))
        material.setAmbient(QColor(colour).darker(160))
        sym.setMaterial(material)
        props = sym.dataDefinedProperties()
        props.setProperty(QgsAbstract3DSymbol.Property.PropertyExtrusionHeight,
                          QgsProperty.fromExpression('coalesce("height_m", 3)'))
        sym.setDataDefinedProperties(props)
        return sym

    root = QgsRuleBased3DRenderer.Rule(None)
    for building_type, colour in TYPE_COLOURS_3D.items():
        root.appendChild(QgsRuleBased3DRenderer.Rule(
            symbol(colour), f"\"building_type\" = '{building_type}'", building_type))
    known = ", ".join(f"'{t}'" for t in TYPE_COLOURS_3D)
    root.appendChild(QgsRuleBased3DRenderer.Rule(
        symbol("#f7f7f7"), f'"building_type" IS NULL OR "building_type" NOT IN ({known})',
        "other"))
    return QgsRuleBased3DRenderer(root)


def parcels_by_quality():
    """Parcels coloured by Yang et al. 2013's quality (Fig. 12: good blue, undesirable red);
    parcels without street frontage get a dashed outline."""
    layer = QgsVectorLayer("Polygon?field=undesirable:boolean&field=has_street_access:boolean",
                           "parcels", "memory")
    root = QgsRuleBasedRenderer.Rule(None)
    rules = [
        ('"undesirable" AND "has_street_access"', "#ef8a62", "solid",
         "undesirable (p_angle > 15° or p_area > 1.2)"),
        ('NOT "undesirable" AND "has_street_access"', "#67a9cf", "solid", "good"),
        ('"undesirable" AND NOT "has_street_access"', "#ef8a62", "dash",
         "undesirable, no street access"),
        ('NOT "undesirable" AND NOT "has_street_access"', "#67a9cf", "dash",
         "good, no street access"),
    ]
    for expression, colour, outline, label in rules:
        sym = QgsFillSymbol.createSimple({"color": colour, "outline_color": "#252525",
                                          "outline_width": "0.15", "outline_style": outline})
        root.appendChild(QgsRuleBasedRenderer.Rule(sym, filterExp=expression, label=label))
    unknown = QgsFillSymbol.createSimple({"color": "#d9d9d9", "outline_color": "#737373",
                                          "outline_width": "0.15"})
    root.appendChild(QgsRuleBasedRenderer.Rule(unknown, elseRule=True, label="quality unknown"))
    layer.setRenderer(QgsRuleBasedRenderer(root))
    layer.saveNamedStyle(str(OUT / "parcels_by_quality.qml"))


def intersections():
    layer = QgsVectorLayer("Point?field=degree:integer", "intersections", "memory")
    sym = QgsMarkerSymbol.createSimple({"name": "circle", "color": "#252525", "size": "1.2",
                                        "outline_style": "no"})
    layer.setRenderer(QgsSingleSymbolRenderer(sym))
    layer.saveNamedStyle(str(OUT / "intersections.qml"))


def street_surfaces():
    """Street surfaces in asphalt grey; segments over Scharl's slope limits (flags of
    tessellatestreets) in orange."""
    layer = QgsVectorLayer("Polygon?field=too_steep_long:boolean&field=too_steep_lat:boolean",
                           "street surfaces", "memory")
    root = QgsRuleBasedRenderer.Rule(None)
    steep = QgsFillSymbol.createSimple({"color": "#fdae6b", "outline_color": "#a63603",
                                        "outline_width": "0.15"})
    root.appendChild(QgsRuleBasedRenderer.Rule(
        steep, filterExp='"too_steep_long" OR "too_steep_lat"', label="steeper than the limits"))
    normal = QgsFillSymbol.createSimple({"color": "#bdbdbd", "outline_color": "#636363",
                                         "outline_width": "0.1"})
    root.appendChild(QgsRuleBasedRenderer.Rule(normal, elseRule=True, label="street surface"))
    layer.setRenderer(QgsRuleBasedRenderer(root))
    layer.saveNamedStyle(str(OUT / "street_surfaces.qml"))


def junctions():
    """Junctions darker than the streets, so the connecting lines show; steep ones orange."""
    layer = QgsVectorLayer("Polygon?field=degree:integer&field=too_steep_long:boolean"
                           "&field=too_steep_lat:boolean", "junctions", "memory")
    root = QgsRuleBasedRenderer.Rule(None)
    steep = QgsFillSymbol.createSimple({"color": "#e6550d", "outline_color": "#7f2704",
                                        "outline_width": "0.15"})
    root.appendChild(QgsRuleBasedRenderer.Rule(
        steep, filterExp='"too_steep_long" OR "too_steep_lat"', label="steeper than the limits"))
    normal = QgsFillSymbol.createSimple({"color": "#737373", "outline_color": "#252525",
                                         "outline_width": "0.1"})
    root.appendChild(QgsRuleBasedRenderer.Rule(normal, elseRule=True, label="junction"))
    layer.setRenderer(QgsRuleBasedRenderer(root))
    layer.saveNamedStyle(str(OUT / "junctions.qml"))


def street_mesh():
    """The 3D street mesh of tessellatestreets: its street and junction features as the
    surfaces and junctions are drawn (kind 'street' / 'junction')."""
    layer = QgsVectorLayer("Polygon?field=kind:string", "street mesh", "memory")
    cats = [QgsRendererCategory("street", QgsFillSymbol.createSimple(
                {"color": "#bdbdbd", "outline_color": "#636363", "outline_width": "0.1"}),
                "street"),
            QgsRendererCategory("junction", QgsFillSymbol.createSimple(
                {"color": "#737373", "outline_color": "#252525", "outline_width": "0.1"}),
                "junction")]
    layer.setRenderer(QgsCategorizedSymbolRenderer("kind", cats))
    layer.saveNamedStyle(str(OUT / "street_mesh.qml"))


def road_edges():
    """Road centre lines without a hierarchy (rasterroadstovector): one dark line."""
    layer = QgsVectorLayer("LineString?field=length_m:double", "roads", "memory")
    sym = QgsLineSymbol.createSimple({"line_color": "#252525", "line_width": "0.4",
                                      "capstyle": "round", "joinstyle": "round"})
    layer.setRenderer(QgsSingleSymbolRenderer(sym))
    layer.saveNamedStyle(str(OUT / "road_edges.qml"))


if __name__ == "__main__":
    app = QgsApplication([], False)
    app.initQgis()
    OUT.mkdir(parents=True, exist_ok=True)
    roads_by_level()
    blocks()
    buildings_by_height()
    intersections()
    parcels_by_quality()
    street_surfaces()
    junctions()
    street_mesh()
    road_edges()
    print("styles written to", OUT)
    sys.exit(0)
