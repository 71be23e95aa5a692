"""Processing provider 'urbansynth': lists every algorithm explicitly."""
from pathlib import Path

from qgis.core import QgsProcessingProvider
from qgis.PyQt.QtGui import QIcon

ICON = Path(__file__).resolve().parent.parent / "resources" / "icons" / "urbansynth.svg"


class UrbanSynthesisProvider(QgsProcessingProvider):
    def id(self):
        return "urbansynth"

    def name(self):
        return "Urban Synthesis"

    def longName(self):  # noqa: N802
        return "Urban Synthesis (example-based urban layout synthesis)"

    def icon(self):
        return QIcon(str(ICON))

    def loadAlgorithms(self):  # noqa: N802
        from ..processing_algorithms.extract_road_hierarchy import ExtractRoadHierarchy
        from ..processing_algorithms.extract_blocks import ExtractBlocks
        from ..processing_algorithms.build_block_database import BuildBlockDatabase
        from ..processing_algorithms.build_fragment_database import BuildFragmentDatabase
        from ..processing_algorithms.layout_metrics import LayoutMetrics
        from ..processing_algorithms.grow_roads import GrowRoads
        from ..processing_algorithms.subdivide_parcels import SubdivideParcels
        from ..processing_algorithms.synthesize_roads_from_fragments import (
            SynthesizeRoadsFromFragments,
        )

        for alg in (ExtractRoadHierarchy(), ExtractBlocks(), BuildBlockDatabase(),
                    BuildFragmentDatabase(), LayoutMetrics(), GrowRoads(), SubdivideParcels(),
                    SynthesizeRoadsFromFragments()):
            self.addAlgorithm(alg)
