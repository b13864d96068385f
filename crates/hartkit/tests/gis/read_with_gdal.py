"""Reads a GeoJSON file with GDAL (through pyogrio, run from the interop venv as a
separate process) and prints what a GIS sees as one JSON object: the driver, the
layer's feature count, geometry type and CRS, the fields with the types GDAL gave
them, and the first feature. Used by crates/hartkit/tests/wells_export.rs."""

import json
import sys

import pyogrio
import pyogrio.raw

path = sys.argv[1]
info = pyogrio.read_info(path)
meta, _fids, geometry, fields = pyogrio.raw.read(path)
names = list(meta["fields"])


def plain(v):
    return v.item() if hasattr(v, "item") else v


print(
    json.dumps(
        {
            "gdal": pyogrio.__gdal_version_string__,
            "driver": info["driver"],
            "features": int(info["features"]),
            "geometry_type": info["geometry_type"],
            "crs": info["crs"],
            "fields": dict(zip(names, (str(d) for d in meta["dtypes"]))),
            "first": {n: plain(fields[i][0]) for i, n in enumerate(names)},
            "first_wkb_bytes": len(geometry[0]),
        },
        default=str,
    )
)
