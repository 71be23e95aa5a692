"""The shipped QML styles load onto the layers they are made for, in 2D and in 3D."""
import pytest

from urban_synthesis.plugin.core.paths import RESOURCES

LAYERS = {"roads_by_level.qml": "LineString?field=level:integer",
          "blocks.qml": "Polygon?field=area_m2:double",
          "buildings_by_height.qml": "Polygon?field=height_m:double&field=building_type:string",
          "parcels_by_quality.qml": "Polygon?field=undesirable:boolean"
                                    "&field=has_street_access:boolean",
          "intersections.qml": "Point?field=degree:integer",
          "street_surfaces.qml": "Polygon?field=too_steep_long:boolean",
          "junctions.qml": "Polygon?field=degree:integer",
          "street_mesh.qml": "Polygon?field=kind:string",
          "road_edges.qml": "LineString?field=length_m:double"}


@pytest.mark.parametrize("qml", sorted(LAYERS))
def test_style_loads(qgis_app, qml):
    from qgis.core import QgsVectorLayer

    layer = QgsVectorLayer(LAYERS[qml], qml, "memory")
    message, ok = layer.loadNamedStyle(str(RESOURCES / "styles" / qml))
    assert ok, message
    assert layer.renderer() is not None


def test_buildings_extrude_by_height_in_3d(qgis_app):
    """QGIS's 3D view shows buildings as blocks of their height_m, coloured by type, each
    building drawn by exactly one rule (read back from the renderer's own XML: the Python
    bindings of 3.22 give only the abstract renderer class)."""
    import xml.etree.ElementTree as ET

    from qgis._3d import Qgs3D
    from qgis.core import QgsExpression, QgsExpressionContext, QgsFeature, \
        QgsReadWriteContext, QgsVectorLayer
    from qgis.PyQt.QtXml import QDomDocument

    Qgs3D.initialize()  # what the QGIS desktop does at start: 3D renderers can be read
    layer = QgsVectorLayer(LAYERS["buildings_by_height.qml"], "buildings", "memory")
    layer.loadNamedStyle(str(RESOURCES / "styles" / "buildings_by_height.qml"))
    renderer = layer.renderer3D()
    assert renderer is not None and renderer.type() == "rulebased"
    doc = QDomDocument()
    element = doc.createElement("renderer-3d")
    renderer.writeXml(element, QgsReadWriteContext())
    doc.appendChild(element)
    rules = ET.fromstring(doc.toString()).iter("rule")
    filters, heights = [], []
    for rule in rules:
        filters.append(rule.get("filter"))
        heights += [o.get("value") for o in rule.iter("Option") if o.get("name") == "expression"]
    assert len(filters) >= 5 and all(filters)
    assert len(heights) == len(filters) and all('"height_m"' in h for h in heights)
    for building_type in ("residential", "industrial", "castle", None):
        feature = QgsFeature(layer.fields())
        feature["building_type"] = building_type
        context = QgsExpressionContext()
        context.setFeature(feature)
        matching = [f for f in filters if QgsExpression(f).evaluate(context)]
        assert len(matching) == 1, (building_type, matching)
