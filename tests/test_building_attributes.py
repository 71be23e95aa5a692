"""Engine tests of building attributes normalised from OSM tags and cadastre fields."""
import math

import numpy as np
import pytest

from urban_synthesis.plugin.buildings import attributes as ba
from urban_synthesis.plugin.core.progress import InputError


@pytest.mark.parametrize("text, metres", [
    ("12", 12.0), ("12.5 m", 12.5), ("12.13 m", 12.13), ("12,5", 12.5), ("12m", 12.0),
    ("40'", 12.192), ("40 ft", 12.192), ("12'6\"", 3.81), ("~12", 12.0), ("12-15", 15.0),
    ("12;15", 15.0), ("12 - 15 m", 15.0), ("1200 cm", 12.0), (18, 18.0), (7.5, 7.5),
])
def test_parse_height(text, metres):
    assert ba.parse_height(text) == pytest.approx(metres)


@pytest.mark.parametrize("text", [None, "", "tall", "-5", "0", "5000", "yes", float("nan")])
def test_parse_height_rejects_nonsense(text):
    assert math.isnan(ba.parse_height(text))


@pytest.mark.parametrize("text, levels", [
    ("5", 5.0), ("3.5", 3.5), ("4;6", 6.0), ("5-6", 6.0), ("5+", 5.0), (7, 7.0), ("0", 0.0),
])
def test_parse_levels(text, levels):
    assert ba.parse_levels(text) == levels


@pytest.mark.parametrize("text", [None, "many", "-1", "1000"])
def test_parse_levels_rejects_nonsense(text):
    assert math.isnan(ba.parse_levels(text))


@pytest.mark.parametrize("building, tags, expected", [
    ("apartments", {}, "residential"), ("house", {}, "residential"),
    ("detached", {}, "residential"), ("terrace", {}, "residential"),
    ("retail", {}, "commercial"), ("office", {}, "commercial"),
    ("warehouse", {}, "industrial"), ("church", {}, "religious"),
    ("school", {}, "public"), ("university", {}, "public"),
    ("yes", {}, "unknown"), (None, {}, "unknown"), ("YES ", {}, "unknown"),
    ("roof", {}, "other"), ("shed", {}, "other"),
    ("yes", {"amenity": "place_of_worship"}, "religious"),
    ("yes", {"amenity": "school"}, "public"), ("yes", {"shop": "bakery"}, "commercial"),
    ("yes", {"office": "company"}, "commercial"), ("yes", {"tourism": "hotel"}, "commercial"),
    ("yes", {"building:use": "residential"}, "residential"),
    ("apartments", {"shop": "bakery"}, "residential"),  # the building value decides
])
def test_building_type(building, tags, expected):
    assert ba.building_type(building, tags) == expected
    assert expected in ba.BUILDING_TYPES


def test_heights_and_levels_from_osm_tags():
    df = ba.building_attributes(
        4, building=["apartments", "yes", "church", None],
        other_tags=['"building:levels"=>"5","roof:shape"=>"flat"', '"height"=>"12 m"',
                    '"height"=>"40","building:levels"=>"3"', None],
        tags={"amenity": [None, None, None, "school"]})
    assert df.height_m.tolist()[:3] == [15.0, 12.0, 40.0] and math.isnan(df.height_m[3])
    assert df.height_estimated.tolist() == [True, False, False, pd_na()]
    assert df.levels.tolist()[:3] == [5.0, 4.0, 3.0]
    assert df.levels_estimated.tolist() == [False, True, False, pd_na()]
    assert df.building_type.tolist() == ["residential", "unknown", "religious", "public"]
    assert df.building_tag.tolist() == ["apartments", "yes", "church", None]
    assert df.height_tag.tolist() == [None, "12 m", "40", None]
    assert df.roof_shape.tolist() == ["flat", None, None, None]
    assert [c for c, _ in ba.ATTRIBUTE_FIELDS] == list(df.columns)


def pd_na():
    import pandas as pd

    return pd.NA


def test_cadastre_fields_win_and_storey_height_is_used():
    df = ba.building_attributes(3, other_tags=['"height"=>"30"', None, None],
                                height=[9.0, None, None], levels=[None, 4, "x"],
                                storey_height=2.5)
    assert df.height_m.tolist()[:2] == [9.0, 10.0]
    assert df.levels.tolist()[:2] == [4.0, 4.0]      # round(9 / 2.5) = 4
    assert math.isnan(df.height_m[2]) and math.isnan(df.levels[2])
    assert df.levels_tag.tolist() == [None, "4", "x"]


def test_zero_levels_give_no_height_estimate():
    df = ba.building_attributes(1, building=["roof"], other_tags=['"building:levels"=>"0"'])
    assert df.levels[0] == 0 and math.isnan(df.height_m[0])


def test_bad_storey_height_and_lengths():
    with pytest.raises(InputError, match="storey height"):
        ba.building_attributes(1, storey_height=0)
    with pytest.raises(InputError, match="length"):
        ba.building_attributes(2, building=["yes"])


def test_helsinki_buildings():
    import pyogrio

    from conftest import HELSINKI

    df = pyogrio.read_dataframe(HELSINKI, layer="multipolygons", read_geometry=False)
    df = df[df.building.notna()]
    out = ba.building_attributes(len(df), building=df.building.values,
                                 other_tags=df.other_tags.values,
                                 tags={k: df[k].values for k in ("amenity", "shop", "office")})
    # docs/ARCHITECTURE.md: 165 Helsinki buildings have building:levels, 17 a height
    assert (out.levels_tag.notna()).sum() == 165
    assert (out.height_tag.notna()).sum() == 17
    assert out.height_m.notna().sum() >= 165
    assert (out.height_m.dropna() > 2).all() and (out.height_m.dropna() < 200).all()
    counts = out.building_type.value_counts()
    assert set(counts.index) <= set(ba.BUILDING_TYPES)
    assert counts["unknown"] < 0.8 * len(out)
    assert np.isin(["residential", "public", "commercial", "religious"], counts.index).all()
