"""Reads every frame's per-level windows from a tiled GeoTIFF with overviews through GDAL.

Usage: python3 gdal_frames.py SPEC.json. SPEC holds "tif", "sizes" (level sizes, finest first),
"runs" and "frames" (per frame, per level, [x, y, w, h]; frame 0 warms up and is not timed).
Each run opens the datasets afresh (empty block cache), reads frame 0, then times each later
frame: one pixel-interleaved ReadRaster per level. Prints JSON: per run, per frame, seconds.
"""
import json
import sys
import time

from osgeo import gdal

gdal.UseExceptions()
spec = json.load(open(sys.argv[1]))
tif, sizes = spec["tif"], spec["sizes"]


def open_levels():
    ds = [gdal.Open(tif)]
    for k in range(1, len(sizes)):
        ds.append(gdal.OpenEx(tif, open_options=["OVERVIEW_LEVEL=%d" % (k - 1)]))
    for d, n in zip(ds, sizes):
        if (d.RasterXSize, d.RasterYSize) != (n, n):
            sys.exit("level of %dx%d, expected %d" % (d.RasterXSize, d.RasterYSize, n))
    return ds


def read(ds, frame):
    for d, (x, y, w, h) in zip(ds, frame):
        buf = d.ReadRaster(x, y, w, h, buf_pixel_space=4, buf_line_space=4 * w, buf_band_space=1)
        if len(buf) != 4 * w * h:
            sys.exit("short read")


runs = []
for _ in range(spec["runs"]):
    ds = open_levels()
    read(ds, spec["frames"][0])
    times = []
    for frame in spec["frames"][1:]:
        t = time.perf_counter()
        read(ds, frame)
        times.append(time.perf_counter() - t)
    runs.append(times)
    ds = None
print(json.dumps({"version": gdal.__version__, "cache_max_bytes": gdal.GetCacheMax(), "runs": runs}))
