"""The working-CRS rule: which metric CRS the engine works in for a layer.

Every algorithm works in a local metric CRS and writes its results back in the input CRS
(docs/ARCHITECTURE.md, "Data flow"). A projected CRS in metres is used as it is, except
where its scale at the data is more than :data:`MAX_SCALE_ERROR` off true: Web Mercator
(1.5x at 50 degrees latitude), World Mercator, a plate carrée in metres, a national grid far
outside its country would make every length and area wrong; those, and anything else
(geographic degrees, feet), are replaced by the UTM zone of the data's centre. Both the QGIS
adapter (``qgis_glue.qgis_io``) and the QGIS-free Dask runner (``scale.distributed``) decide
with :func:`working_crs`, each describing its CRS object in the plain terms below and
measuring its scale with its own library (QGIS's ellipsoidal distances, PROJ's factors).

Examples
--------
>>> working_crs("EPSG:4326", projected_in_metres=False, centre_lonlat=(24.94, 60.17))
'EPSG:32635'
>>> working_crs("EPSG:3857", projected_in_metres=True, centre_lonlat=(14.4, 50.1))
'EPSG:32633'
>>> working_crs("EPSG:32633", projected_in_metres=True, centre_lonlat=(14.4, 50.1)) is None
True

World Mercator at Prague stretches every length by 1.56: its scale, measured by the caller,
sends the data to the UTM zone as Web Mercator's does.

>>> working_crs("EPSG:3395", projected_in_metres=True, centre_lonlat=(14.4, 50.1),
...             scale_error=lambda: 0.56)
'EPSG:32633'
>>> utm_zone(-70.6, -33.4)
'EPSG:32719'
"""
from __future__ import annotations

import math
from typing import Callable, Optional, Tuple, Union

from .progress import InputError

__all__ = ["MAX_SCALE_ERROR", "WEB_MERCATOR", "is_web_mercator", "metres_per_unit", "utm_zone",
           "working_crs"]

#: A projected CRS whose point scale at the data is further than this from 1 (a share: 1 %)
#: is not worked in: lengths and areas would be off by as much. UTM within its zone is off
#: by at most 0.1 %, national grids within their country by about as much.
MAX_SCALE_ERROR = 0.01

#: Authority ids of Web Mercator (kept out of the working CRS: its scale error).
WEB_MERCATOR = frozenset({"EPSG:3857", "EPSG:900913", "EPSG:3785", "EPSG:102100",
                          "EPSG:102113", "ESRI:102100", "ESRI:102113"})

LonLat = Tuple[float, float]


def is_web_mercator(authid: Optional[str]) -> bool:
    """Whether an authority id (``'EPSG:3857'``) names Web Mercator."""
    return bool(authid) and str(authid).upper() in WEB_MERCATOR


def utm_zone(lon: float, lat: float) -> str:
    """The authority id of the UTM zone (WGS 84) holding a point given in degrees."""
    if not (math.isfinite(lon) and math.isfinite(lat)):
        raise InputError("cannot find a metric CRS for the data: its extent is not finite")
    zone = int((lon + 180.0) // 6.0) % 60 + 1
    return f"EPSG:{32600 + zone if lat >= 0 else 32700 + zone}"


def working_crs(authid: Optional[str], projected_in_metres: bool,
                centre_lonlat: Union[LonLat, Callable[[], LonLat]],
                scale_error: Optional[Callable[[], float]] = None) -> Optional[str]:
    """The metric CRS the engine works in for data in a CRS.

    Parameters
    ----------
    authid : the CRS's authority id ('EPSG:3857'), or None when it has none
    projected_in_metres : whether the CRS is projected with metre units
    centre_lonlat : the data's centre in degrees (lon, lat), or a function returning it
        (called only when the CRS is replaced)
    scale_error : a function returning how far the CRS's point scale at the data's centre
        is from 1 (the larger of its scales along the meridian and the parallel; a share),
        called for a projected CRS in metres; None: not known (the CRS is taken as true)

    Returns
    -------
    None when the CRS itself is the working CRS, else the authority id of the UTM zone of
    the data's centre.
    """
    if projected_in_metres and not is_web_mercator(authid):
        error = scale_error() if scale_error is not None else 0.0
        if not (math.isfinite(error) and error > MAX_SCALE_ERROR):
            return None
    lon, lat = centre_lonlat() if callable(centre_lonlat) else centre_lonlat
    return utm_zone(float(lon), float(lat))


#: Names of length units as rasters declare them (GDAL's band unit type, a vertical CRS's
#: unit) -> metres per unit; the keys are lower case with runs of spaces, '-' and '_' as one
#: space. The empty name (nothing declared) is metres, as every DEM format defaults to.
_METRES_PER_UNIT = {
    "": 1.0, "m": 1.0, "metre": 1.0, "meter": 1.0, "metres": 1.0, "meters": 1.0,
    "cm": 0.01, "centimetre": 0.01, "centimeter": 0.01, "centimetres": 0.01,
    "centimeters": 0.01, "dm": 0.1, "decimetre": 0.1, "decimeter": 0.1,
    "mm": 0.001, "millimetre": 0.001, "millimeter": 0.001,
    "ft": 0.3048, "foot": 0.3048, "feet": 0.3048, "international foot": 0.3048,
    "international feet": 0.3048, "intl foot": 0.3048,
    "us survey foot": 1200.0 / 3937.0, "us survey feet": 1200.0 / 3937.0,
    "us ft": 1200.0 / 3937.0, "ftus": 1200.0 / 3937.0, "foot us": 1200.0 / 3937.0,
    "us foot": 1200.0 / 3937.0, "survey foot": 1200.0 / 3937.0,
}


def metres_per_unit(name: Optional[str]) -> Optional[float]:
    """Metres per unit of a length unit named as a raster declares it (a DEM band's unit
    type, a vertical CRS's unit): 1 for metres and for no name, None for a name that is
    not a known length unit. Heights in feet make every slope 3.28 times too steep when
    they are read as metres.

    Examples
    --------
    >>> metres_per_unit("m"), metres_per_unit(""), metres_per_unit(None)
    (1.0, 1.0, 1.0)
    >>> metres_per_unit("ft")
    0.3048
    >>> round(metres_per_unit("US survey foot"), 10)
    0.3048006096
    >>> metres_per_unit("us-ft") == metres_per_unit("US_survey_foot")
    True
    >>> metres_per_unit("kg/m2") is None
    True
    """
    key = " ".join(str(name or "").lower().replace("-", " ").replace("_", " ").split())
    return _METRES_PER_UNIT.get(key)
