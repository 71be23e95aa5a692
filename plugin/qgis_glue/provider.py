"""Processing provider 'urbansynth': lists every algorithm explicitly."""
import importlib

from qgis.core import (
    Qgis,
    QgsApplication,
    QgsMessageLog,
    QgsProcessingAlgorithm,
    QgsProcessingException,
    QgsProcessingModelAlgorithm,
    QgsProcessingMultiStepFeedback,
    QgsProcessingProvider,
)
from qgis.PyQt.QtGui import QIcon

from ..core.paths import RESOURCES
from . import dependencies, outputs
from .toolbox import ALGORITHMS, DEPRECATED, GROUPS, TAGS, algorithm_id, help_url

ICON = RESOURCES / "icons" / "urbansynth.svg"

#: Processing models shipped with the provider (made by scripts/make_models.py).
MODELS = RESOURCES / "models"


class ShippedModel(QgsProcessingModelAlgorithm):
    """A model of resources/models: shown under its display name (help content key
    DISPLAY_NAME) in the provider's own group of that name (a .model3 file keeps the group
    name only), and run with the plugin's output rule (:mod:`outputs`): its outputs appear
    only when every step succeeded, and a cancel is reported as one. Like every tool, it
    says which packages it needs while the engine's are missing."""

    missing = ()  # the engine's packages missing when the provider loaded it

    def displayName(self):  # noqa: N802
        name = self.helpContent().get("DISPLAY_NAME") or self.name()
        return f"{name} (needs {', '.join(self.missing)})" if self.missing else name

    def groupId(self):  # noqa: N802
        return self.group().lower()

    def createInstance(self):  # noqa: N802 - QGIS runs a copy: it must be a ShippedModel too
        clone = ShippedModel()
        clone.loadVariant(self.toVariant())
        clone.setSourceFilePath(self.sourceFilePath())
        clone.missing = self.missing
        return clone

    def checkParameterValues(self, parameters, context):  # noqa: N802
        # its steps stand in as UnavailableAlgorithm when packages are missing: say so here,
        # before the run (which would stop on an import error)
        missing = dependencies.missing_packages()
        if missing:
            return False, dependencies.missing_message(missing)
        message = self.empty_input_error(parameters, context)
        if message:
            return False, message
        return super().checkParameterValues(parameters, context)

    def empty_input_error(self, parameters, context):
        """The message when a mandatory input layer of the model holds no feature, else
        None. Its steps run an empty optional input as one not given, so the step that
        needed it would fail far from it ('Example block database: Buildings is needed')."""
        from qgis.core import QgsProcessingParameterDefinition, QgsProcessingParameterFeatureSource

        from . import qgis_io

        for definition in self.parameterDefinitions():
            if not isinstance(definition, QgsProcessingParameterFeatureSource) or \
                    definition.flags() & QgsProcessingParameterDefinition.Flag.FlagOptional:
                continue
            try:
                source = self.parameterAsSource(parameters, definition.name(), context)
            except Exception:  # noqa: BLE001 - an unreadable layer is reported by its step
                continue
            # featureCount() is -1 where the provider does not know (an .osm.pbf)
            if source is not None and source.featureCount() == 0:
                return (f"Layer {qgis_io.layer_name(self, parameters, definition.name(), context)}"
                        f" is empty: {definition.description()} ({definition.name()}) needs "
                        "features.")
        return None

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        missing = dependencies.missing_packages()  # models in models: no parameter check
        if missing:
            raise QgsProcessingException(dependencies.missing_message(missing))
        from . import qgis_io  # the engine's packages: not needed to list the provider

        message = self.empty_input_error(parameters, context)  # models in models: no check
        if message:
            raise QgsProcessingException(message)
        for warning in qgis_io.unknown_parameters(self, parameters):
            feedback.pushWarning(warning)
        staging = outputs.OutputStaging(self, parameters, context)
        staged = staging.prepare()
        recorder = _StepErrors(feedback)
        try:
            results = super().processAlgorithm(staged, context, recorder)
            # QGIS ends a canceled model between steps without an error: nothing is kept
            qgis_io.stop_if_canceled(feedback)
            return staging.commit(results)
        except BaseException as exc:
            staging.discard()
            # exactly a QgsProcessingException: QGIS prints any other type with a traceback
            if feedback is not None and feedback.isCanceled():
                raise QgsProcessingException(
                    "Canceled by the user: the model stopped and wrote no output.") from exc
            if isinstance(exc, QgsProcessingException):
                # QGIS says only which step failed: add the step's own message
                step = recorder.errors[-1] if recorder.errors else ""
                raise QgsProcessingException(f"{exc}: {step}" if step else str(exc)) from exc
            raise


class _StepErrors(QgsProcessingMultiStepFeedback):
    """The model's feedback, keeping the errors its steps report (QGIS's model throws
    'Error encountered while running <step>' without the step's message)."""

    def __init__(self, feedback):
        super().__init__(1, feedback)
        self.errors = []

    def reportError(self, error, fatalError=False):  # noqa: N802,N803 (QGIS API)
        self.errors.append(error)
        super().reportError(error, fatalError)


class UnavailableAlgorithm(QgsProcessingAlgorithm):
    """Stands in the toolbox for an algorithm whose Python packages are missing: listed
    under its own name, it fails its parameter check with what to install and how."""

    def __init__(self, module: str, display_name: str, group_id: str, missing):
        super().__init__()
        self._module, self._display, self._group_id = module, display_name, group_id
        self._missing = list(missing)

    def name(self):
        return algorithm_id(self._module)

    def displayName(self):  # noqa: N802
        return f"{self._display} (needs {', '.join(self._missing)})"

    def group(self):
        return GROUPS[self._group_id]

    def groupId(self):  # noqa: N802
        return self._group_id

    def icon(self):
        return QIcon(str(ICON))

    def flags(self):
        if self.name() in DEPRECATED:  # hidden as the algorithm itself is
            return super().flags() | QgsProcessingAlgorithm.Flag.FlagDeprecated
        return super().flags()

    def shortHelpString(self):  # noqa: N802
        return dependencies.missing_message(self._missing)

    def helpUrl(self):  # noqa: N802
        return help_url(self.name())

    def tags(self):
        return list(TAGS.get(self.name(), ()))

    def createInstance(self):  # noqa: N802
        return UnavailableAlgorithm(self._module, self._display, self._group_id, self._missing)

    def initAlgorithm(self, config=None):  # noqa: N802
        pass

    def checkParameterValues(self, parameters, context):  # noqa: N802
        return False, dependencies.missing_message(self._missing)

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        from qgis.core import QgsProcessingException

        raise QgsProcessingException(dependencies.missing_message(self._missing))


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
        # An algorithm whose packages are missing stays listed and says what to install.
        dependencies.activate()
        missing = dependencies.missing_packages()
        if missing:
            QgsMessageLog.logMessage(dependencies.missing_message(missing), "Urban Synthesis",
                                     Qgis.MessageLevel.Warning)
        package = __package__.split(".")[0] + ".processing_algorithms"
        for module_name, class_name, display_name, group_id in ALGORITHMS:
            try:
                module = importlib.import_module(f"{package}.{module_name}")
                self.addAlgorithm(getattr(module, class_name)())
            except ImportError as error:
                self.addAlgorithm(UnavailableAlgorithm(module_name, display_name, group_id,
                                                       missing or [error.name or str(error)]))
            except Exception as error:  # noqa: BLE001 (any other failure is reported)
                QgsMessageLog.logMessage(
                    f"Urban Synthesis: algorithm {module_name} not loaded: {error!r}",
                    "Processing", Qgis.MessageLevel.Critical)
        # A model's steps are looked up in the registry, where this provider's algorithms
        # are only once it is registered: the models are loaded by a refresh right after.
        registry = QgsApplication.processingRegistry()
        if registry.providerById(self.id()) is not None:
            self._load_models(missing)
        elif not getattr(self, "_refresh_when_added", False):
            self._refresh_when_added = True
            registry.providerAdded.connect(self._provider_added)

    def _provider_added(self, provider_id):
        if provider_id == self.id():
            QgsApplication.processingRegistry().providerAdded.disconnect(self._provider_added)
            self.refreshAlgorithms()

    def _load_models(self, missing=()):
        for path in sorted(MODELS.glob("*.model3")):
            model = ShippedModel()
            model.missing = tuple(missing)
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
                                         "Processing", Qgis.MessageLevel.Critical)
