"""Render the top of an HTML report (layoutmetrics, the district's) to a PNG, headless.

    python scripts/render_report.py out/demo_metrics.html docs/metrics_report.png

The README's picture of the layoutmetrics report is this, after ``make demo``. QtWebKit
(Debian's python3-pyqt5.qtwebkit; QGIS 4 has no QtWebKit) draws it; no browser is needed.
"""
import os
import sys

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
from qgis.PyQt.QtCore import QEventLoop, QSize, QUrl  # noqa: E402
from qgis.PyQt.QtGui import QImage, QPainter  # noqa: E402
from qgis.PyQt.QtWebKitWidgets import QWebPage  # noqa: E402
from qgis.PyQt.QtWidgets import QApplication  # noqa: E402

WIDTH, HEIGHT = 1200, 2150   # the report's header, road measures and first four histograms


def render(html: str, png: str, width: int = WIDTH, height: int = HEIGHT) -> None:
    app = QApplication.instance() or QApplication(sys.argv[:1])  # noqa: F841 (kept alive)
    page = QWebPage()
    page.setViewportSize(QSize(width, height))
    loop = QEventLoop()
    page.mainFrame().loadFinished.connect(lambda ok: loop.quit())
    page.mainFrame().load(QUrl.fromLocalFile(os.path.abspath(html)))
    loop.exec()
    image = QImage(QSize(width, height), QImage.Format.Format_ARGB32)
    image.fill(0xFFFFFFFF)
    painter = QPainter(image)
    page.mainFrame().render(painter)
    painter.end()
    if not image.save(png):
        raise SystemExit(f"could not write {png}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    render(sys.argv[1], sys.argv[2])
