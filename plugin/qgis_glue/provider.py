"""Processing provider 'urbansynth': lists every algorithm explicitly."""
import importlib

from qgis.core import (
    Qgis,
    QgsApplication,
    QgsMessageLog,
    QgsProcessingModelAlgorithm,
    QgsProcessingProvider,
)
from qgis.PyQt.QtGui import QIcon

from ..core.paths import RESOURCES

ICON = RESOURCES / "icons" / "urbansynth.svg"

#: (module in processing_algorithms, class) of every algorithm, in toolbox order.
ALGORITHMS = (
    ("extract_road_hierarchy", "ExtractRoadHierarchy"),
    ("extract_blocks", "ExtractBlocks"),
    ("build_block_database", "BuildBlockDatabase"),
    ("build_fragment_database", "BuildFragmentDatabase"),
    ("layout_metrics", "LayoutMetrics"),
    ("grow_roads", "GrowRoads"),
    ("subdivide_parcels", "SubdivideParcels"),
    ("synthesize_roads_from_fragments", "SynthesizeRoadsFromFragments"),
    ("tessellate_streets", "TessellateStreets"),
    ("synthesize_roads_gan", "SynthesizeRoadsGan"),
    ("raster_roads_to_vector", "RasterRoadsToVector"),
    ("synthesize_buildings", "SynthesizeBuildings"),
    ("synthesize_roads_random_walk", "SynthesizeRoadsRandomWalk"),
    ("synthesize_footprints", "SynthesizeFootprints"),
    ("split_domain", "SplitDomain"),
    ("synthesize_roads", "SynthesizeRoads"),
    ("synthesize_aerial_image", "SynthesizeAerialImage"),
)

#: Processing models shipped with the provider (made by scripts/make_models.py).
MODELS = RESOURCES / "models"


class ShippedModel(QgsProcessingModelAlgorithm):
    """A model of resources/models: shown under its display name (help content key
    DISPLAY_NAME) in the provider's own group of that name (a .model3 file keeps the group
    name only)."""

    def displayName(self):  # noqa: N802
        return self.helpContent().get("DISPLAY_NAME") or self.name()

    def groupId(self):  # noqa: N802
        return self.group().lower()


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
        # One algorithm that fails to import (e.g. a missing optional library) must not hide
        # the others: it is reported in the message log and left out of the toolbox.
        package = __package__.split(".")[0] + ".processing_algorithms"
        for module_name, class_name in ALGORITHMS:
            try:
                module = importlib.import_module(f"{package}.{module_name}")
                self.addAlgorithm(getattr(module, class_name)())
            except Exception as error:  # noqa: BLE001 (any import failure is reported)
                QgsMessageLog.logMessage(
                    f"Urban Synthesis: algorithm {module_name} not loaded: {error!r}",
                    "Processing", Qgis.Critical)
        # A model's steps are looked up in the registry, where this provider's algorithms
        # are only once it is registered: the models are loaded by a refresh right after.
        registry = QgsApplication.processingRegistry()
        if registry.providerById(self.id()) is not None:
            self._load_models()
        elif not getattr(self, "_refresh_when_added", False):
            self._refresh_when_added = True
            registry.providerAdded.connect(self._provider_added)

    def _provider_added(self, provider_id):
        if provider_id == self.id():
            QgsApplication.processingRegistry().providerAdded.disconnect(self._provider_added)
            self.refreshAlgorithms()

    def _load_models(self):
        for path in sorted(MODELS.glob("*.model3")):
            model = ShippedModel()
            if model.fromFile(str(path)):
                model.updateDestinationParameters()
                # parameter help is kept in the model's help content (see make_models.py)
                help_content = model.helpContent()
                for definition in model.parameterDefinitions():
                    if not definition.help() and help_content.get(definition.name()):
                        definition.setHelp(help_content[definition.name()])
                self.addAlgorithm(model)
            else:
                QgsMessageLog.logMessage(f"Urban Synthesis: model {path.name} could not be read",
                                         "Processing", Qgis.Critical)
