"""Writes the PMTiles archives of the archive tests with the reference writer (the `pmtiles`
package), and for each a manifest of what it wrote: one record per addressed tile, `z x y`
as little-endian u8, u32, u32, the tile's length as u32, then its bytes (before any tile
compression). Usage: write_pmtiles.py DIR."""

import gzip
import random
import struct
import sys

from pmtiles.tile import Compression, TileType, zxy_to_tileid, tileid_to_zxy
from pmtiles.writer import Writer

out = sys.argv[1]
rng = random.Random(47)


def png_like(tag, extra):
    """PNG's magic and a 256 x 256 IHDR, then bytes of its own."""
    body = struct.pack(">II", 256, 256) + b"\x08\x06\x00\x00\x00" + tag.to_bytes(8, "little")
    return b"\x89PNG\r\n\x1a\n\x00\x00\x00\x0dIHDR" + body + bytes(rng.getrandbits(8) for _ in range(extra))


def write(name, tiles, tile_type, tile_compression=Compression.NONE, runs=()):
    """`tiles`: (tile id, bytes) in increasing id order; `runs`: (first id, count, bytes) written
    tile by tile, the same bytes for consecutive ids, which the writer folds into run-length
    entries. Only the tiles of `tiles` go into the manifest (runs are too many); the runs are
    listed in NAME.runs as `first count length` with their bytes."""
    items = [(i, b, False) for i, b in tiles] + [(first, (n, b), True) for first, n, b in runs]
    items.sort(key=lambda t: t[0])
    with open(f"{out}/{name}", "wb") as f, open(f"{out}/{name}.manifest", "wb") as m, open(f"{out}/{name}.runs", "wb") as r:
        w = Writer(f)
        for tid, b, is_run in items:
            if is_run:
                n, data = b
                stored = gzip.compress(data, mtime=0) if tile_compression == Compression.GZIP else data
                for k in range(n):
                    w.write_tile(tid + k, stored)
                r.write(struct.pack("<QQI", tid, n, len(data)) + data)
            else:
                stored = gzip.compress(b, mtime=0) if tile_compression == Compression.GZIP else b
                w.write_tile(tid, stored)
                z, x, y = tileid_to_zxy(tid)
                m.write(struct.pack("<BIII", z, x, y, len(b)) + b)
        zooms = [tileid_to_zxy(t[0])[0] for t in items]
        w.finalize(
            {
                "tile_type": tile_type,
                "tile_compression": tile_compression,
                "min_zoom": min(zooms),
                "max_zoom": max(zooms),
                "min_lon_e7": int(-180e7),
                "min_lat_e7": int(-85.0511287e7),
                "max_lon_e7": int(180e7),
                "max_lat_e7": int(85.0511287e7),
            },
            {"name": name},
        )


# A small archive: every tile of zooms 0..3 but a few, and a run of four equal tiles at zoom 3.
small = [(zxy_to_tileid(z, x, y), png_like(zxy_to_tileid(z, x, y), 20)) for z in range(4) for x in range(1 << z) for y in range(1 << z) if (x * 7 + y) % 5 != 4]
small.sort()
run_at = zxy_to_tileid(3, 0, 0)
small = [t for t in small if not run_at <= t[0] < run_at + 4]
write("small.pmtiles", small, TileType.PNG, runs=[(run_at, 4, png_like(999, 30))])

# The same tiles, gzip-compressed in the archive (its header says so), as JPEG-typed tiles.
jpeg = [(i, b"\xff\xd8\xff\xe0" + b[4:]) for i, b in small]
write("gzip.pmtiles", jpeg, TileType.JPEG, Compression.GZIP)

# Enough distinct tiles (sparse ids, lengths of their own) that the root directory passes
# 16 KiB and the writer moves the entries into leaf directories; runs among them.
many, tid = [], zxy_to_tileid(10, 0, 0)
runs = []
for k in range(60000):
    tid += rng.randint(1, 40)
    if k % 1000 == 500:
        runs.append((tid, 17, png_like(tid, 10)))
        tid += 17
        continue
    many.append((tid, png_like(tid, rng.randint(0, 60))))
write("leaves.pmtiles", many, TileType.PNG, runs=runs)

# A sparse planet, zooms 0..18: a few tiles at every zoom, leaves of scattered tiles at zoom 14,
# and runs of millions of equal tiles (an ocean) at zooms 17 and 18.
planet = []
for z in range(0, 19):
    n = 1 << z
    for _ in range(3):
        x, y = rng.randrange(n), rng.randrange(n)
        planet.append(zxy_to_tileid(z, x, y))
tid = zxy_to_tileid(14, 0, 0)
for _ in range(40000):
    tid += rng.randint(1, 2000)
    planet.append(tid)
ocean = [(zxy_to_tileid(17, 0, 0) + 1000, 1_000_000, png_like(17, 5)), (zxy_to_tileid(18, 0, 0) + 5000, 2_000_000, png_like(18, 5))]
planet = sorted(set(planet))
planet = [t for t in planet if not any(f <= t < f + n for f, n, _ in ocean)]
write("planet.pmtiles", [(t, png_like(t, rng.randint(0, 8))) for t in planet], TileType.PNG, runs=ocean)
