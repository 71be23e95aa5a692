"""The provider and the metadata of every algorithm (what the toolbox and qgis_process show)."""
import configparser

from conftest import ROOT


def test_every_algorithm_is_documented(qgis_processing):
    from qgis.core import QgsApplication

    from urban_synthesis.processing_algorithms.common import GROUPS

    provider = QgsApplication.processingRegistry().providerById("urbansynth")
    algs = provider.algorithms()
    assert {a.name() for a in algs} >= {
        "extractroadhierarchy", "extractblocks", "buildfragmentdatabase", "buildblockdatabase",
        "layoutmetrics", "growroads", "subdivideparcels", "synthesizeroadsfromfragments"}
    for alg in algs:
        assert alg.id() == f"urbansynth:{alg.name()}"
        assert alg.group() in GROUPS.values()
        assert len(alg.shortHelpString()) > 100, alg.name()
        assert not alg.icon().isNull(), alg.name()
        for p in alg.parameterDefinitions():
            # a model's outputs are named '<step id>:<OUTPUT NAME>'
            name = p.name().split(":")[-1]
            assert name == name.upper(), (alg.name(), p.name())
            assert p.help() and len(p.help()) > 15, (alg.name(), p.name())


def test_metadata_is_complete():
    meta = configparser.ConfigParser()
    meta.read(ROOT / "metadata.txt")
    general = meta["general"]
    for key in ("name", "qgisMinimumVersion", "description", "about", "version", "author",
                "email", "repository", "tracker", "tags", "icon", "hasProcessingProvider"):
        assert general.get(key), key
    assert general["hasProcessingProvider"] == "yes"
    assert (ROOT / general["icon"]).exists()
