"""urbansynth:synthesizebuildings (deprecated) - the three building methods behind one METHOD
parameter, kept runnable for models and command lines made before they became tools of
their own: 'Synthesize building attributes (by example)', 'Place library buildings on
parcels (best fit)' and 'Synthesize buildings from parts'."""
from collections import namedtuple

from qgis.core import (
    QgsProcessingAlgorithm,
    QgsProcessingException,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterEnum,
)

from .common import AlgorithmBase
from .place_library_buildings import PlaceLibraryBuildings
from .synthesize_building_attributes import SynthesizeBuildingAttributes
from .synthesize_part_buildings import SynthesizePartBuildings

#: One METHOD value (in enum order): its label, the algorithm that runs it and the
#: parameters that method cannot do without.
Method = namedtuple("Method", "label algorithm needs")
METHODS = (
    Method("Attributes from similar example buildings", SynthesizeBuildingAttributes,
           ("FOOTPRINTS", "EXAMPLE_BUILDINGS")),
    Method("Best-fitting library building per parcel (Scharl)", PlaceLibraryBuildings,
           ("PARCELS", "ROADS")),
    Method("Part-based buildings along skeletons or stacked on sites (thesis)",
           SynthesizePartBuildings, ("SKELETON",)),
)


class SynthesizeBuildings(AlgorithmBase):
    GROUP_ID = "synthesis"
    METHOD = "METHOD"

    def name(self):
        return "synthesizebuildings"

    def displayName(self):  # noqa: N802
        return "Synthesize buildings (deprecated: choose the method)"

    def flags(self):
        return super().flags() | QgsProcessingAlgorithm.Flag.FlagDeprecated

    def shortHelpString(self):  # noqa: N802
        return ("Deprecated: runs one of 'Synthesize building attributes (by example)' "
                "(METHOD 0), 'Place library buildings on parcels (best fit)' (1) or "
                "'Synthesize buildings from parts' (2) with the same parameters. Use those "
                "tools directly; this one stays for models and command lines that use it.")

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterEnum(
            self.METHOD, "Method", options=[m.label for m in METHODS], defaultValue=0),
            "0: attributes (needs Footprints and Example buildings); 1: best fit (needs "
            "Parcels and Roads); 2: parts (needs a Skeleton).")
        # every method's parameters, each name once (declared by the method's own tool);
        # all optional here, since each method needs only its own
        for method in METHODS:
            alg = method.algorithm()
            alg.initAlgorithm()
            for definition in alg.parameterDefinitions():
                if self.parameterDefinition(definition.name()) is not None:
                    continue
                copy = definition.clone()
                if not copy.isDestination():
                    copy.setFlags(copy.flags() | QgsProcessingParameterDefinition.Flag.FlagOptional)
                self.addParameter(copy, createOutput=copy.isDestination())

    def _method(self, parameters, context):
        method = METHODS[self.parameterAsEnum(parameters, self.METHOD, context)]
        missing = [n for n in method.needs if not self.given(parameters, n)]
        if missing:
            names = ", ".join(self.parameterDefinition(n).description() for n in missing)
            return method, f"Method '{method.label}' needs: {names}."
        return method, None

    def input_error(self, parameters, context):
        return self._method(parameters, context)[1]

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        method, message = self._method(parameters, context)
        if message:
            raise QgsProcessingException(message)
        feedback.pushWarning(f"'Synthesize buildings' is deprecated: this runs "
                             f"urbansynth:{method.algorithm().name()}.")
        delegate = method.algorithm()
        delegate.initAlgorithm()
        return delegate.processAlgorithm(parameters, context, feedback)
