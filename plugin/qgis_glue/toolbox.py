"""What the toolbox lists: the provider's groups and algorithms, in toolbox order.

Kept apart from the algorithm classes so that the provider can list every algorithm even
when the engine's packages are missing (each then shows as unavailable, saying which package
to install); tests/test_provider.py checks that this table and the classes agree.
"""

#: Toolbox groups: id -> name.
GROUPS = {"analysis": "Analysis", "databases": "Example databases", "synthesis": "Synthesis",
          "setup": "Setup"}

#: (module in processing_algorithms, class, display name, group id) of every algorithm.
ALGORITHMS = (
    ("extract_road_hierarchy", "ExtractRoadHierarchy", "Extract road hierarchy", "analysis"),
    ("extract_blocks", "ExtractBlocks", "Extract city blocks", "analysis"),
    ("build_block_database", "BuildBlockDatabase", "Build block database", "databases"),
    ("build_fragment_database", "BuildFragmentDatabase", "Build fragment database", "databases"),
    ("layout_metrics", "LayoutMetrics", "Layout metrics", "analysis"),
    ("grow_roads", "GrowRoads", "Grow roads (procedural patterns)", "synthesis"),
    ("subdivide_parcels", "SubdivideParcels", "Subdivide blocks into parcels", "synthesis"),
    ("synthesize_roads_from_fragments", "SynthesizeRoadsFromFragments",
     "Synthesize roads from fragments", "synthesis"),
    ("tessellate_streets", "TessellateStreets", "Tessellate streets (surfaces and junctions)",
     "synthesis"),
    ("synthesize_roads_gan", "SynthesizeRoadsGan", "Synthesize roads (StreetGAN)", "synthesis"),
    ("raster_roads_to_vector", "RasterRoadsToVector", "Road raster to vector graph", "analysis"),
    ("synthesize_building_attributes", "SynthesizeBuildingAttributes",
     "Synthesize building attributes (by example)", "synthesis"),
    ("place_library_buildings", "PlaceLibraryBuildings",
     "Place library buildings on parcels (best fit)", "synthesis"),
    ("synthesize_part_buildings", "SynthesizePartBuildings", "Synthesize buildings from parts",
     "synthesis"),
    # deprecated (hidden in the toolbox): the three above behind one METHOD, for old models
    ("synthesize_buildings", "SynthesizeBuildings",
     "Synthesize buildings (deprecated: choose the method)", "synthesis"),
    ("synthesize_roads_random_walk", "SynthesizeRoadsRandomWalk",
     "Synthesize roads by random walks (intersection points)", "synthesis"),
    ("synthesize_footprints", "SynthesizeFootprints", "Synthesize building footprints",
     "synthesis"),
    ("split_domain", "SplitDomain", "Split domain into streets and parcels (Yang 2013)",
     "synthesis"),
    ("synthesize_roads", "SynthesizeRoads", "Synthesize roads (choose the method)", "synthesis"),
    ("synthesize_aerial_image", "SynthesizeAerialImage",
     "Synthesize aerial image of parcels (Aliaga et al. 2008)", "synthesis"),
    ("install_dependencies", "InstallDependencies", "Install Python dependencies", "setup"),
)


#: Deprecated algorithms: they run (old models, command lines) but are not listed, also while
#: their packages are missing.
DEPRECATED = frozenset({"synthesizebuildings"})


def algorithm_id(module: str) -> str:
    """The algorithm id of a module: its name without underscores (docs/ARCHITECTURE.md,
    "The toolbox contract")."""
    return module.replace("_", "")


#: Search words of every algorithm (the toolbox's search matches them besides the name).
TAGS = {
    "extractroadhierarchy": ("roads", "streets", "hierarchy", "arterials", "osm",
                             "intersections", "network"),
    "extractblocks": ("blocks", "city blocks", "faces", "buildings", "parcels", "polygonize"),
    "buildblockdatabase": ("example", "database", "blocks", "footprints", "buildings"),
    "buildfragmentdatabase": ("example", "database", "roads", "fragments", "streets"),
    "layoutmetrics": ("metrics", "statistics", "compare", "report", "fidelity", "validation"),
    "growroads": ("roads", "procedural", "grid", "organic", "radial", "growth", "streets"),
    "subdivideparcels": ("parcels", "lots", "plots", "subdivision", "cadastre", "blocks"),
    "synthesizeroadsfromfragments": ("roads", "streets", "example", "fragments", "synthesis"),
    "tessellatestreets": ("streets", "surfaces", "junctions", "3d", "mesh", "polygons"),
    "synthesizeroadsgan": ("roads", "streets", "gan", "neural network", "generator", "synthesis"),
    "rasterroadstovector": ("raster", "roads", "vectorize", "skeleton", "graph"),
    "synthesizebuildingattributes": ("buildings", "height", "levels", "floors", "roof",
                                     "attributes", "far", "example"),
    "placelibrarybuildings": ("buildings", "library", "best fit", "parcels", "placement"),
    "synthesizepartbuildings": ("buildings", "parts", "skeleton", "facade", "floor area"),
    "synthesizebuildings": ("buildings", "attributes", "parts", "deprecated"),
    "synthesizeroadsrandomwalk": ("roads", "streets", "random walk", "intersections",
                                  "example", "expand"),
    "synthesizefootprints": ("buildings", "footprints", "example", "blocks", "synthesis"),
    "splitdomain": ("planned", "layout", "streets", "parcels", "templates", "district"),
    "synthesizeroads": ("roads", "streets", "synthesis", "district"),
    "synthesizeaerialimage": ("aerial", "image", "imagery", "orthophoto", "raster", "parcels"),
    "installdependencies": ("install", "pip", "packages", "dependencies", "setup"),
}

#: The README's address; each algorithm's help opens its section of the toolbox reference
#: (``#alg-<name>``, written by scripts/make_toolbox_reference.py).
HOMEPAGE = "https://github.com/urbansynth/urban_synthesis"


def help_url(name: str) -> str:
    return f"{HOMEPAGE}#alg-{name}"
