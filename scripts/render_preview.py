"""Render a PNG preview of a demo GeoPackage with the shipped QML styles (PyQGIS, headless)."""
import os
import sys
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
from qgis.core import (  # noqa: E402
    QgsApplication, QgsMapRendererCustomPainterJob, QgsMapSettings, QgsVectorLayer,
)
from qgis.PyQt.QtCore import QSize, Qt  # noqa: E402
from qgis.PyQt.QtGui import QColor, QFont, QImage, QPainter  # noqa: E402

STYLES = Path(__file__).resolve().parent.parent / "resources" / "styles"
# bottom to top
LAYERS = [("blocks", "blocks.qml"), ("buildings", "buildings_by_height.qml"),
          ("roads", "roads_by_level.qml")]
SYNTHESIS_LAYERS = [("synthesized_roads", "roads_by_level.qml")]
DISTRICT_LAYERS = [("blocks", "blocks.qml"), ("parcels", "parcels_by_quality.qml"),
                   ("street_surfaces", "street_surfaces.qml"), ("junctions", "junctions.qml"),
                   ("buildings", "buildings_by_height.qml")]
PARCEL_LAYERS = [("parcels", "parcels_by_quality.qml"), ("roads", "roads_by_level.qml")]


def render(gpkg: str, png: str, title: str = "Helsinki: road hierarchy, blocks and buildings",
           size: int = 1400, layer_styles=LAYERS, extent_layer: str = "roads",
           footer: str = "Roads coloured by level (red = arterial), buildings by height.") -> None:
    layers = []
    for name, qml in layer_styles:
        layer = QgsVectorLayer(f"{gpkg}|layername={name}", name, "ogr")
        if not layer.isValid():
            continue
        layer.loadNamedStyle(str(STYLES / qml))
        layers.append(layer)
    if not layers:
        raise SystemExit(f"no layer to render in {gpkg}")
    roads = next((lyr for lyr in layers if lyr.name() == extent_layer), layers[-1])
    settings = QgsMapSettings()
    settings.setLayers(list(reversed(layers)))  # first is drawn on top
    settings.setDestinationCrs(roads.crs())
    extent = roads.extent()
    extent.scale(1.05)
    settings.setOutputSize(QSize(size, size))
    settings.setExtent(extent)
    settings.setBackgroundColor(QColor("white"))
    settings.setOutputDpi(120)
    image = QImage(QSize(size, size), QImage.Format.Format_ARGB32_Premultiplied)
    image.fill(Qt.GlobalColor.white)
    painter = QPainter(image)
    job = QgsMapRendererCustomPainterJob(settings, painter)
    job.start()
    job.waitForFinished()
    painter.setPen(QColor("#222222"))
    font = QFont("DejaVu Sans", 16)
    painter.setFont(font)
    painter.drawText(20, 36, title)
    font.setPointSize(10)
    painter.setFont(font)
    painter.drawText(20, size - 16, "Map data (c) OpenStreetMap contributors, ODbL. " + footer)
    painter.end()
    image.save(png)


def main():
    app = QgsApplication([], False)
    app.initQgis()
    if sys.argv[1] == "district":  # the synthesizedistrict model's outputs
        render(sys.argv[2], sys.argv[3], "A district synthesised like Helsinki (one model run)",
               layer_styles=DISTRICT_LAYERS, extent_layer="street_surfaces",
               footer="Parcels by quality, street surfaces and junctions, footprints by height.")
        print("wrote", sys.argv[3])
        return
    render(sys.argv[1], sys.argv[2])
    print("wrote", sys.argv[2])
    if len(sys.argv) > 3:  # subdivideparcels on the Helsinki blocks
        render(sys.argv[1], sys.argv[3], "Helsinki blocks subdivided into skeleton parcels",
               layer_styles=PARCEL_LAYERS,
               footer="Parcels: blue = good, red = undesirable (Yang et al. 2013).")
        print("wrote", sys.argv[3])
    if len(sys.argv) > 4:  # synthesizeroadsfromfragments on the Helsinki arterials
        render(sys.argv[1], sys.argv[4], "Helsinki arterials refilled from Helsinki's fragments",
               layer_styles=SYNTHESIS_LAYERS, extent_layer="synthesized_roads",
               footer="Synthesised streets coloured by level (red = the given arterials).")
        print("wrote", sys.argv[4])


if __name__ == "__main__":
    main()
