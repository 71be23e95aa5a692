"""Write the Processing models shipped with the provider (resources/models/*.model3).

The .model3 files are committed; this script documents how they are made and regenerates
them (run with the venv's python: `QT_HASH_SEED=0 QT_QPA_PLATFORM=offscreen .venv/bin/python
scripts/make_models.py`; the fixed hash seed keeps Qt's XML attribute order, so that the
diff of a regenerated model shows only what changed). A model made here opens in the QGIS
model designer like any other.
"""
import os
import sys
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
# a fixed hash seed: Qt writes XML attributes in hash order, so the file changes only when
# the model does
os.environ.setdefault("QT_HASH_SEED", "0")
from qgis.core import (  # noqa: E402
    QgsApplication, QgsProcessing, QgsProcessingModelAlgorithm, QgsProcessingModelChildAlgorithm,
    QgsProcessingModelChildParameterSource as Source, QgsProcessingModelOutput,
    QgsProcessingModelParameter, QgsProcessingParameterEnum, QgsProcessingParameterFeatureSource,
    QgsProcessingParameterDefinition, QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
)
from qgis.PyQt.QtCore import QPointF  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "resources" / "models"

DISTRICT_HELP = (
    "Synthesizes a whole district in the style of an example city, in one run.\n\n"
    "From the example's roads and buildings it extracts the road hierarchy, the blocks with "
    "their buildings and a block database. Then, inside the ARTERIALS sketch (and BOUNDARY), "
    "it synthesizes the streets with the method chosen by ROAD_METHOD, makes the blocks "
    "(the district's outline closing the faces the streets leave open), "
    "turns the streets into surface and junction polygons (widths by road class; draped on "
    "the DEM when one is given), fills the blocks with footprints from the example's blocks "
    "(FOOTPRINT_METHOD transfer or resynthesis) clear of the street surfaces, subdivides "
    "the blocks into parcels with street access up to the street surfaces and around the "
    "footprints, gives the footprints heights, levels and types like the example's "
    "buildings, and writes a metrics report that compares the new district with the "
    "example.\n\n"
    "Parcels merge where a building stands on several lots, so some are larger than the "
    "maximum parcel area. Every step is a Processing tool of its own (Urban Synthesis's, "
    "and QGIS's 'Merge vector layers' for the street area): open this model in the model designer "
    "to change their options.")


def _param(model, definition, help_text, x, y):
    # QGIS 3.22 does not save a parameter's help in the .model3 file: the help goes into the
    # model's help content under the parameter name, where the provider reads it back
    definition.setHelp(help_text)
    model.setHelpContent(dict(model.helpContent(), **{definition.name(): help_text}))
    component = QgsProcessingModelParameter(definition.name())
    component.setPosition(QPointF(x, y))
    model.addModelParameter(definition, component)


def _child(model, child_id, alg_id, description, sources, outputs=(), x=0.0, y=0.0):
    """A step: sources = {parameter: Source or list of Source}; outputs = ((child output, model output name,
    description),). The model's output parameters are named '<child id>:<model output name>'
    (e.g. roads:ROADS on the qgis_process command line)."""
    child = QgsProcessingModelChildAlgorithm(alg_id)
    child.setChildId(child_id)
    child.setDescription(description)
    child.setPosition(QPointF(x, y))
    # QGIS's model check (QgsProcessingModelAlgorithm.validate) wants a source for every
    # mandatory parameter, defaults included: a parameter left out gets its default, stated
    definition = QgsApplication.processingRegistry().algorithmById(alg_id)
    if definition is None:
        sys.exit(f"{alg_id} is not registered: is the provider loaded?")
    for param in definition.parameterDefinitions():
        if param.name() in sources or param.isDestination():
            continue
        if not (param.flags() & QgsProcessingParameterDefinition.Flag.FlagOptional):
            sources[param.name()] = Source.fromStaticValue(param.defaultValue())
    for name, source in sources.items():
        child.addParameterSources(name, source if isinstance(source, list) else [source])
    model_outputs = {}
    for child_output, model_name, text in outputs:
        out = QgsProcessingModelOutput(model_name)
        out.setChildId(child_id)
        out.setChildOutputName(child_output)
        out.setDescription(text)
        model_outputs[model_name] = out
    child.setModelOutputs(model_outputs)
    model.addChildAlgorithm(child)


def district_model() -> QgsProcessingModelAlgorithm:
    model = QgsProcessingModelAlgorithm("synthesizedistrict", "Synthesis", "synthesis")
    model.setHelpContent({"ALG_DESC": DISTRICT_HELP, "ALG_CREATOR": "Urban Synthesis",
                          "ALG_VERSION": "1",
                          # the toolbox name (plugin/qgis_glue/provider.py ShippedModel)
                          "DISPLAY_NAME": "Synthesize a district like an example"})
    p = Source.fromModelParameter
    out = Source.fromChildOutput
    fixed = Source.fromStaticValue
    _param(model, QgsProcessingParameterFeatureSource(
        "EXAMPLE_ROADS", "Example roads", [QgsProcessing.SourceType.TypeVectorLine]),
        "The example city's road lines (OSM lines with highway, or any road layer).", 0, 0)
    _param(model, QgsProcessingParameterFeatureSource(
        "EXAMPLE_BUILDINGS", "Example buildings", [QgsProcessing.SourceType.TypeVectorPolygon]),
        "The example city's building footprints (OSM multipolygons with building, or a "
        "cadastre layer).", 0, 80)
    _param(model, QgsProcessingParameterFeatureSource(
        "ARTERIALS", "Arterial roads of the new district", [QgsProcessing.SourceType.TypeVectorLine]),
        "A sketch of the new district's main roads (they are kept; the streets fill them).",
        0, 160)
    _param(model, QgsProcessingParameterFeatureSource(
        "BOUNDARY", "District boundary", [QgsProcessing.SourceType.TypeVectorPolygon], optional=True),
        "Polygon the district fills (every road method; fragments close the faces the "
        "arterials leave open with it); default the arterials' hull.",
        0, 240)
    _param(model, QgsProcessingParameterRasterLayer("DEM", "Terrain (DEM)", optional=True),
           "Optional terrain: steers the road synthesis (fragments and growth; StreetGAN does "
           "not use it) and drapes the street surfaces.", 0, 320)
    _param(model, QgsProcessingParameterEnum(
        "ROAD_METHOD", "Road synthesis method",
        options=["Fragments of the example (thesis ch. 4.1)",
                 "Procedural growth (Scharl 2010)",
                 "StreetGAN trained on real towns (thesis ch. 4.2)"], defaultValue=0),
        "How the streets are made (see 'Synthesize roads (choose the method)').", 0, 400)
    _param(model, QgsProcessingParameterEnum(
        "FOOTPRINT_METHOD", "Footprint method",
        options=["Transfer of the most similar example block (thesis ch. 5.1)",
                 "Guided re-synthesis (thesis ch. 5.2)"], defaultValue=0),
        "How the blocks are filled with building footprints.", 0, 480)
    from urban_synthesis.plugin.parcels import subdivision as parcels
    from urban_synthesis.processing_algorithms.common import fill_quantile_parameter

    # subdivideparcels' METHOD enum, in its order (new methods are appended to it)
    methods = list(parcels.method_names())
    parcel_method = QgsProcessingParameterEnum(
        "PARCEL_METHOD", "Parcel method", options=[parcels.METHODS[k].label for k in methods],
        defaultValue=methods.index("skeleton"))
    parcel_method.setFlags(parcel_method.flags()
                           | QgsProcessingParameterDefinition.Flag.FlagAdvanced)
    _param(model, parcel_method, "How the blocks are cut into parcels (see 'Subdivide blocks "
           "into parcels'). Skeleton (Vanegas et al. 2012, the default) gives every parcel a "
           "street frontage; Voronoi along the OBB axis (Aliaga et al. 2008) gives a tenth more "
           "parcels, a little more regular (the demo's district, seed 1: 406 parcels, 46 % "
           "undesirable by Yang's test, against the skeleton's 368 and 50 %).", 0, 500)

    fill = fill_quantile_parameter()
    fill.setFlags(fill.flags() | QgsProcessingParameterDefinition.Flag.FlagAdvanced)
    _param(model, fill, "Fragments: faces larger than this quantile of the example's block "
           "areas get streets. An example whose largest blocks are parks or yards (central "
           "Helsinki) keeps them with a higher value (98).", 0, 520)
    _param(model, QgsProcessingParameterNumber(
        "SEED", "Random seed", QgsProcessingParameterNumber.Type.Integer, defaultValue=1,
        minValue=0, maxValue=2 ** 31 - 1),
        "The same seed and inputs give the same district.", 0, 560)

    _child(model, "hierarchy", "urbansynth:extractroadhierarchy", "Example road hierarchy",
           {"INPUT": p("EXAMPLE_ROADS")}, x=300, y=0)
    _child(model, "example_blocks", "urbansynth:extractblocks", "Example blocks and buildings",
           {"ROADS": out("hierarchy", "OUTPUT"), "BUILDINGS": p("EXAMPLE_BUILDINGS")},
           x=300, y=100)
    _child(model, "block_db", "urbansynth:buildblockdatabase", "Example block database",
           {"BLOCKS": out("example_blocks", "OUTPUT"),
            "BUILDINGS": out("example_blocks", "OUTPUT_BUILDINGS")}, x=300, y=200)
    _child(model, "roads", "urbansynth:synthesizeroads", "Synthesize the streets",
           {"METHOD": p("ROAD_METHOD"), "EXAMPLE_ROADS": out("hierarchy", "OUTPUT"),
            "ARTERIALS": p("ARTERIALS"), "BOUNDARY": p("BOUNDARY"), "DEM": p("DEM"),
            "SEED": p("SEED"), "FILL_QUANTILE": p("FILL_QUANTILE")},
           outputs=(("OUTPUT", "ROADS", "Roads"),), x=600, y=0)
    # the district's outline closes the faces the streets leave open (an open sketch):
    # those blocks get parcels fronting their streets and footprints too
    _child(model, "blocks", "urbansynth:extractblocks", "Blocks of the new district",
           {"ROADS": out("roads", "OUTPUT"), "BOUNDARY": out("roads", "OUTPUT_BOUNDARY")},
           outputs=(("OUTPUT", "BLOCKS", "Blocks"),), x=600, y=100)
    # parcels and footprints keep clear of the street surfaces as tessellated (widths by
    # class, dead ends inside blocks too): the same surfaces the district's outputs show
    _child(model, "street_area", "native:mergevectorlayers", "Street surfaces and junctions",
           {"LAYERS": [out("streets", "OUTPUT_SURFACES"), out("streets", "OUTPUT_JUNCTIONS")]},
           x=900, y=100)
    # the parcels are cut around the footprints (a footprint stands on one parcel where
    # the lots allow): they come after the footprints
    _child(model, "parcels", "urbansynth:subdivideparcels", "Parcels",
           {"BLOCKS": out("blocks", "OUTPUT"), "METHOD": p("PARCEL_METHOD"), "SEED": p("SEED"),
            "STREET_WIDTH": fixed(0.0), "KEEP_CLEAR": out("street_area", "OUTPUT"),
            "BUILDINGS": out("footprints", "OUTPUT"),
            "BOUNDARY": out("roads", "OUTPUT_BOUNDARY")},
           outputs=(("OUTPUT", "PARCELS", "Parcels"),), x=600, y=200)
    _child(model, "footprints", "urbansynth:synthesizefootprints", "Building footprints",
           {"BLOCKS": out("blocks", "OUTPUT"), "BLOCK_DB": out("block_db", "OUTPUT"),
            "METHOD": p("FOOTPRINT_METHOD"), "KEEP_CLEAR": out("street_area", "OUTPUT"),
            "SEED": p("SEED")}, x=600, y=300)
    _child(model, "buildings", "urbansynth:synthesizebuildingattributes", "Building attributes",
           {"FOOTPRINTS": out("footprints", "OUTPUT"),
            "EXAMPLE_BUILDINGS": out("example_blocks", "OUTPUT_BUILDINGS"),
            "ROADS": out("roads", "OUTPUT"), "EXAMPLE_ROADS": out("hierarchy", "OUTPUT"),
            "SEED": p("SEED")},
           outputs=(("OUTPUT", "BUILDINGS", "Buildings"),), x=600, y=400)
    _child(model, "streets", "urbansynth:tessellatestreets", "Street surfaces and junctions",
           {"ROADS": out("roads", "OUTPUT"), "DEM": p("DEM")},
           outputs=(("OUTPUT_SURFACES", "STREET_SURFACES", "Street surfaces"),
                    ("OUTPUT_JUNCTIONS", "JUNCTIONS", "Junctions")),
           x=900, y=0)
    _child(model, "metrics", "urbansynth:layoutmetrics", "Metrics against the example",
           {"ROADS": out("roads", "OUTPUT"), "GIVEN_ROADS": p("ARTERIALS"),
            "BLOCKS": out("blocks", "OUTPUT"),
            "PARCELS": out("parcels", "OUTPUT"), "BUILDINGS": out("buildings", "OUTPUT"),
            "EXAMPLE_ROADS": out("hierarchy", "OUTPUT"),
            "EXAMPLE_BLOCKS": out("example_blocks", "OUTPUT"),
            "EXAMPLE_BUILDINGS": out("example_blocks", "OUTPUT_BUILDINGS")},
           outputs=(("OUTPUT", "METRICS", "Metrics"),
                    ("OUTPUT_HTML", "REPORT", "Metrics report")), x=900, y=200)
    return model


def main():
    app = QgsApplication([], False)
    app.initQgis()
    sys.path.insert(0, str(ROOT / "build" / "plugins"))
    from urban_synthesis.plugin.qgis_glue.provider import UrbanSynthesisProvider

    from qgis.analysis import QgsNativeAlgorithms

    # the model uses one QGIS tool (native:mergevectorlayers) beside the provider's own
    QgsApplication.processingRegistry().addProvider(QgsNativeAlgorithms())
    provider = UrbanSynthesisProvider()
    QgsApplication.processingRegistry().addProvider(provider)
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / "synthesize_district.model3"
    model = district_model()
    ok, problems = model.validate()
    if not ok:
        sys.exit("the model does not validate:\n" + "\n".join(problems))
    if not model.toFile(str(path)):
        sys.exit(f"could not write {path}")
    print(path)


if __name__ == "__main__":
    main()
