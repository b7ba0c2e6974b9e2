#!/usr/bin/env python3
"""Read a clip texture published by clipmapd in shared memory (layout version 2, docs/SHM.md).

Standard library only (mmap, struct). As a module:

    m = Mapping(path)                 # maps read-only, checks every static field (Refused)
    snap = m.snapshot()               # Busy or Corrupt on failure; m keeps the last good one
    data = m.read_region(level, s0, t0, w, h)   # bytes, rows in increasing t, s fastest
    # raises NotValid (outside the level's published region), Missing (a tile could not be read:
    # use a coarser level), Stale (a slot holds another tile: take a new snapshot), Busy
    m.texel(level, s, t)              # one texel's bytes

Views (docs/SHM.md, "Views"): besides the primary view, `main` (the snapshot above), a mapping may
publish further views, each with its own snapshot over the same slots:

    m.view_names()                    # ["main", ...]: the live view records' names, in record order
    v = m.view("north")               # NoView (lists the views), Busy, Corrupt; "main" always exists
    snap = v.snapshot()               # as Mapping.snapshot, or Removed: the view was removed
    data = v.read_region(level, s0, t0, w, h)   # texels under the view's snapshot
    m.snapshot(view="north")          # the same as m.view("north").snapshot()
    request_centre(socket_path, s, t, view="north")   # through the control socket (below)

A view with grids of its own (views block version 2, docs/SHM.md "A view with grids of its own")
reads `main` of another mapping of the service, DIR/clipmap-NAME@VIEW.map beside the service's
DIR/clipmap-NAME.map (m must be opened by that name): m.view(name) opens it (every check of any
mapping, not followed when it is a symbolic link, owned by the owner of m's file) and returns a
View whose `own` is True and whose `mapping` is that Mapping; snapshot(), read_region() and
texel() then read it as above, and snapshot() still raises Removed when the view is removed.
m.views() lists such views (own True) without opening their mappings.

As a program it reads random texel blocks inside the published valid regions of a texture
served by `clipmapd --source hash` and checks every texel:

    python3 clients/python/clipmap_shm.py /dev/shm/clipmap-hash.map 100000 [seed [seconds]]

prints "N passed, M failed (...)"; `python3 clients/python/clipmap_shm.py MAPPING --growth`
prints a growing texture's growth block as JSON (null when it does not grow). Exit status 0 no mismatch, 1 a mismatch, 2 the mapping was
refused (at open, or published state out of bounds), with the reason on standard error.
`MAPPING --dump LEVEL S0,T0,S1,T1 OUT [SECONDS]` writes the region [S0, S1) x [T0, T1) of LEVEL of
any texture to OUT: OUT.raw the stored bytes (rows in increasing t, s fastest, no header; as the C
reader's --dump and `clipmap-read --dump-level ... --out FILE.raw` write), OUT.png a PNG with t
upwards (its top row is T1 - 1), 8-bit grey, RGB or RGBA, or 16-bit for the 16-bit formats (the
stored values; write_png); other formats (packed, heights) only as .raw. It waits up to SECONDS
(default 5) for the region to be published.
`--view NAME` (anywhere after MAPPING) reads that view instead of `main` (exit 2 listing the views
when there is none of that name, 3 when it is removed while it is read); `MAPPING --views` lists the
views, `MAPPING --snapshot [--view NAME]` prints a view's snapshot (as the C reader's do).
`MAPPING --georef` prints the georef block (`Mapping.georef`; "not georeferenced" when there is
none), as the C reader's --georef does; `MAPPING --map-of-texel LEVEL S T` prints the map
coordinates "X Y" of the continuous texel position (S, T) of LEVEL (`Mapping.map_of_texel`), as
the C reader's --map-of-texel does.

Requests: Python has no compare-and-swap on a mapping, so it cannot take the request
mapping's lock words; a Python renderer asks for a centre through the control socket
(`request_centre`: `CENTRE s t`, or `VIEW CENTRE NAME s t` for a view).

Consistency: the snapshot and every slot tag are read under their seqlocks (sequence read
before and after, accepted only when even and equal). Every field the writer changes is loaded
through a native memoryview (one 8-byte load each; struct's "<Q" is not promised to be one
load). Python has no memory fences; on x86-64 (loads are not reordered with other loads) that
is enough, elsewhere treat this module as a reference, not a production reader. A file
truncated after it was mapped raises SIGBUS on access, as with any mmap.
"""

import errno
import math
import mmap
import os
import socket
import stat
import struct
import sys
import time
import zlib

MAGIC = b"CLIPMAP2"
REQUEST_MAGIC = b"CLIPREQ2"
VERSION = 2
PAGE = 4096
MAX_LEVELS = 32
MAX_RETRIES = 64
REQUEST_BYTES = 4096

# Header offsets.
H_MAGIC, H_VERSION, H_HEADER_BYTES, H_TOTAL_BYTES = 0, 8, 12, 16
H_TEXEL_FORMAT, H_BYTES_PER_TEXEL, H_CLIP_SIZE, H_LEVEL_COUNT = 24, 28, 32, 36
H_LEVEL0_S, H_LEVEL0_T, H_WRITER_PID = 40, 48, 56
H_HEARTBEAT, H_HEARTBEAT_MS, H_GENERATION, H_FLAGS, H_TICK_PERIOD_NS = 64, 72, 80, 88, 96
# u64 byte offset of the views block (a multiple of 4096, after every level's slots); 0: none.
H_VIEWS_OFFSET = 104
H_SNAPSHOT = SNAPSHOT = 128

# Snapshot fields, relative to H_SNAPSHOT (one seqlock over all of them).
SNAP_SEQ, SNAP_MIN_LOD, SNAP_TICK, SNAP_INVALID_BORDER = 0, 8, 16, 24
SNAP_CENTRE_S, SNAP_CENTRE_T, SNAP_LEVELS = 32, 40, 64
STATE_BYTES = 64
SNAPSHOT_BYTES = SNAP_LEVELS + MAX_LEVELS * STATE_BYTES

# The same fields as absolute offsets (the names layout 1 used for them).
H_GLOBAL_SEQ = H_SNAPSHOT + SNAP_SEQ
H_MIN_LOD = H_SNAPSHOT + SNAP_MIN_LOD
H_TICK = H_SNAPSHOT + SNAP_TICK
H_LEVEL_STATES = H_SNAPSHOT + SNAP_LEVELS

# Level state fields, relative to the state.
S_CENTRE_S, S_CENTRE_T, S_VALID_S0, S_VALID_T0, S_VALID_S1, S_VALID_T1 = 0, 8, 16, 24, 32, 40
S_ENABLED, S_UPDATED_TICK = 48, 56

H_LEVEL_DESCS = LEVEL_DESCS = H_SNAPSHOT + SNAPSHOT_BYTES
DESC_BYTES = 128
# The growth block (growing textures; all zero otherwise), u64 fields under one seqlock.
H_GROWTH = H_LEVEL_DESCS + MAX_LEVELS * DESC_BYTES
GROWTH_BYTES = 128
# The heights block (static; all zero for a texture that is not heights): u32 flag, u32 level
# rule, f64 scale, offset and nodata (a stored value; NaN: none).
H_HEIGHTS = H_GROWTH + GROWTH_BYTES
HEIGHTS_BYTES = 64
# The georef block (static; all zero for a texture without georeferencing): u32 present, u32 EPSG
# code (0: none), u32 flags (bit 0: wraps in longitude), u32 definition length, f64 origin x, y
# (level 0's GDAL geotransform [0], [3]: its north-west corner), f64 level-0 terms [1], [2], [4],
# [5], then the CRS definition (UTF-8, not NUL-terminated). Each level's terms are also in its
# descriptor (DESC_GEOREF).
H_GEOREF = H_HEIGHTS + HEIGHTS_BYTES
GR_PRESENT, GR_EPSG, GR_FLAGS, GR_DEFINITION_LEN, GR_ORIGIN_X, GR_ORIGIN_Y, GR_TERMS, GR_DEFINITION = \
    0, 4, 8, 12, 16, 24, 32, 64
GEOREF_DEFINITION_MAX = GR_DEFINITION_MAX = 1024
GEOREF_BYTES = GR_DEFINITION + GR_DEFINITION_MAX
GR_WRAPS = 1
GR_KNOWN_FLAGS = GR_WRAPS
H_END = H_GEOREF + GEOREF_BYTES
HT_IS_HEIGHTS, HT_RULE, HT_SCALE, HT_OFFSET, HT_NODATA = 0, 4, 8, 16, 24
# Level rule codes (HT_RULE) and the height storage of each texel format code.
HEIGHT_RULES = ("mean", "point", "min", "max")
HEIGHT_STORAGES = {11: "l32f", 7: "l16", 12: "l16i"}
# Every height a format holds lies within this many metres of zero (10,000 km).
HEIGHT_LIMIT_M = 1.0e7
G_SEQ, G_GROWING, G_EXTENT_S0, G_EXTENT_T0, G_EXTENT_S1, G_EXTENT_T1 = 0, 8, 16, 24, 32, 40
G_DATA_LEVELS, G_PATCHES, G_TILES_REBUILT = 48, 56, 64
G_TILES_PENDING, G_TILES_REPLACED, G_WORLD_S0, G_WORLD_T0, G_TEXELS_PER_UNIT, G_OUTSIDE_FRAME = 72, 80, 88, 96, 104, 112

# Level descriptor fields (static u64s), relative to the descriptor.
DESC_SIZE_S, DESC_SIZE_T, DESC_TILE_S, DESC_TILE_T, DESC_GRID_S, DESC_GRID_T = 0, 8, 16, 24, 32, 40
DESC_SLOT_BYTES, DESC_TAGS_OFFSET, DESC_SLOTS_OFFSET, DESC_KIND = 48, 56, 64, 72
# u64 byte offset of the level's tile ranges (heights only; 0: none), between its tags and slots.
DESC_RANGES_OFFSET = 80
# f64 x 4: the level's GDAL geotransform terms [1], [2], [4], [5] (0: no georeferencing).
DESC_GEOREF = 88
# Tile range entries: one per slot at ranges + RANGE_BYTES * slot, f64 bits (metres, nodata
# excluded; both NaN when every texel is nodata), read under the slot's tag like texels.
RANGE_BYTES, RANGE_MIN, RANGE_MAX = 16, 0, 8

# Slot tags (at tags_offset + TAG_BYTES * slot), every field atomic.
TAG_BYTES = 32
TAG_SEQ, TAG_TILE_S, TAG_TILE_T, TAG_STATE = 0, 8, 16, 24
SLOT_EMPTY, SLOT_LOADING, SLOT_READY, SLOT_MISSING, SLOT_DEFAULT = 0, 1, 2, 3, 4

# Request mapping (DIR/clipmap-NAME.req).
REQ_MAGIC, REQ_VERSION, REQ_GENERATION, REQ_SEQ = 0, 8, 16, 64
REQ_CENTRE_S, REQ_CENTRE_T, REQ_VEL_S, REQ_VEL_T, REQ_CLIENT_PID, REQ_COUNT = 72, 80, 88, 96, 104, 112
# View request record r at REQ_VIEWS + VIEW_REQUEST_BYTES * r (r < MAX_VIEW_REQUESTS): the main
# request's fields at the same distances from their lock word, and the view's incarnation.
REQ_VIEWS, VIEW_REQUEST_BYTES, MAX_VIEW_REQUESTS = 512, 64, 24
VR_SEQ, VR_CENTRE_S, VR_CENTRE_T, VR_VEL_S, VR_VEL_T, VR_CLIENT_PID, VR_COUNT, VR_INCARNATION = 0, 8, 16, 24, 32, 40, 48, 56
# LOD request record i at REQ_LOD + LOD_RECORD_BYTES * i (0: main, 1 + r: view record r), under the
# same lock words (docs/SHM.md, "Asking for a view's levels"); Python asks through the socket.
REQ_LOD, LOD_RECORD_BYTES = 2048, 32
LOD_HEIGHT, LOD_PIXEL_ANGLE, LOD_EFFECTIVE, LOD_COUNT = 0, 8, 16, 24
# Position record i at REQ_POSITION + POSITION_RECORD_BYTES * i (0: main, 1 + r: view record r),
# under the same lock words (docs/SHM.md, "Positions in longitude / latitude or map coordinates"):
# the request's centre is the record's position when POS_FOR_COUNT equals the request's count and
# the kind is not KIND_TEXELS; else its texel centre.
REQ_POSITION, POSITION_RECORD_BYTES = 3072, 32
POS_KIND, POS_X, POS_Y, POS_FOR_COUNT = 0, 8, 16, 24
KIND_TEXELS, KIND_LONLAT, KIND_MAP = 0, 1, 2
KIND_NAMES = {KIND_TEXELS: "texels", KIND_LONLAT: "lonlat", KIND_MAP: "map"}


def read_request(req_path):
    """The main request of the request mapping at req_path as found (read, not locked: for
    display): a dict with "count", "centre" [s, t] (level-0 texels), "kind" ("texels", "lonlat",
    "map" or "unknown") and "position" [x, y] (None when the request is in texels). The position is
    the request's when the position record was written with it (POS_FOR_COUNT == count)."""
    with open(req_path, "rb") as f:
        b = f.read(REQUEST_BYTES)
    if len(b) != REQUEST_BYTES or b[0:8] != REQUEST_MAGIC:
        raise Corrupt(f"{req_path}: {len(b)} bytes starting {b[0:8]!r}, expected {REQUEST_BYTES} starting {REQUEST_MAGIC!r}")
    count = struct.unpack_from("<Q", b, REQ_COUNT)[0]
    s, t = struct.unpack_from("<qq", b, REQ_CENTRE_S)
    kind, x, y, for_count = struct.unpack_from("<QddQ", b, REQ_POSITION)
    positioned = count != 0 and for_count == count and kind != KIND_TEXELS
    return {
        "count": count,
        "centre": [s, t],
        "kind": KIND_NAMES.get(kind, "unknown") if positioned else "texels",
        "position": [x, y] if positioned else None,
    }

# Views (docs/SHM.md, "Views"): the primary view, "main", is the snapshot at H_SNAPSHOT; further
# views are the view records of the views block at H_VIEWS_OFFSET.
VIEWS_MAGIC = b"CLIPVIEW"
VIEWS_VERSION = 2  # the views block version of this reader; it reads versions VIEWS_VERSION_MIN to this
VIEWS_VERSION_MIN = 1  # version 1: no record in state VIEW_OWN
MAX_VIEWS = 64  # view records N: 1..64
VIEW_RECORD_BYTES = 2240
VIEW_NAME_BYTES, VIEW_NAME_MAX = 32, 31  # u8[32], NUL-padded: 1..31 of A-Z a-z 0-9 - _ . (never "main")
VIEW_NAME_CHARS = frozenset(b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_.")
# Views block fields (relative to the block): record r at VB_RECORDS + VIEW_RECORD_BYTES * r.
VB_MAGIC, VB_VERSION, VB_RECORD_COUNT, VB_RECORD_BYTES, VB_RECORDS = 0, 8, 12, 16, 64
# View record fields (relative to the record); 0..128 under the record's seqlock (V_SEQ).
V_SEQ, V_STATE, V_INCARNATION, V_WEIGHT, V_NAME, V_SNAPSHOT = 0, 8, 16, 24, 64, 128
VIEW_FREE, VIEW_LIVE = 0, 1
VIEW_OWN = 2  # live with grids of its own (version 2): name, weight, incarnation; the record's snapshot unused
NAME_MAX = 64  # a service's name: 1..64 of A-Z a-z 0-9 - _ . (DIR/clipmap-NAME.map)
OWN_SEPARATOR = "@"  # a view's own grids: DIR/clipmap-NAME@VIEW.map (and .req)

# The request lock word (REQ_SEQ; docs/SHM.md, "Request mapping"): odd while a renderer holds it,
# with its pid in bits 1..31; a word odd for REQUEST_TAKEOVER_MS is taken over only when that pid
# is no live process; a renderer gives up after REQUEST_WAIT_MS. This module writes no requests.
REQUEST_TAKEOVER_MS, REQUEST_WAIT_MS = 100, 1000

# Texel format codes (H_TEXEL_FORMAT): code -> (name, bytes per texel); 0 is any other format.
# 16-bit components are little-endian.
FORMATS = {
    1: ("l8", 1), 3: ("rgb8", 3), 4: ("rgba8", 4), 5: ("rgb565", 2), 6: ("rgba5551", 2),
    7: ("l16", 2), 8: ("la16", 4), 9: ("rgb16", 6), 10: ("rgba16", 8), 11: ("l32f", 4), 12: ("l16i", 2),
    # Block-compressed (docs/SHM.md, "Block-compressed formats"): the bytes are those of one 4 x 4 block.
    20: ("bc1", 8), 21: ("bc4", 8), 22: ("bc5", 16), 23: ("bc7", 16),
}
# The block-compressed codes: slots of ceil(TW / 4) x ceil(TH / 4) blocks, read whole (read_tile).
BLOCK_FORMATS = (20, 21, 22, 23)

M64 = (1 << 64) - 1


class ClipmapError(Exception):
    """Base of every error of this module."""


class Refused(ClipmapError):
    """The mapping cannot be used: its static fields are not those of a layout-2 mapping."""


class Corrupt(ClipmapError):
    """Published state outside its bounds."""


class ReadError(ClipmapError):
    """A read did not give texels (see the subclasses)."""


class NotValid(ReadError):
    """No such level, the level is disabled, or the region is outside its published region."""


class Missing(ReadError):
    """A tile of the region could not be read: use a coarser level for it."""


class Busy(ReadError):
    """The writer kept the snapshot or a tag locked for MAX_RETRIES attempts."""


class Stale(ReadError):
    """A slot holds another tile (or is loading): take a new snapshot."""


class NoView(ClipmapError):
    """No view of that name (the message lists the views that exist), or not a view name."""


class Removed(ClipmapError):
    """The view was removed: its record was freed or given to another view since it was found."""


def view_name_ok(name):
    """Whether `name` is a name a view record may carry: 1 to 31 of A-Z a-z 0-9 - _ ., not "main"."""
    b = name.encode("utf-8", "replace") if isinstance(name, str) else bytes(name)
    return 1 <= len(b) <= VIEW_NAME_MAX and all(c in VIEW_NAME_CHARS for c in b) and b != b"main"


def splitmix64(x):
    z = (x + 0x9E3779B97F4A7C15) & M64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & M64
    return z ^ (z >> 31)


def hash_texel(level, s, t, bpt):
    """The verification texel at (level, s, t): byte i is byte i % 8 of the little-endian hash."""
    v = splitmix64(((level << 58) | (t << 29) | s) & M64).to_bytes(8, "little")
    return (v * 8)[:bpt]


def _f64(bits):
    return struct.unpack("<d", struct.pack("<Q", bits))[0]


def _signed(v):
    return v - (1 << 64) if v >> 63 else v


def _ceil_div(a, b):
    return -(-a // b)


class LevelDesc:
    """One level's static description."""

    __slots__ = ("size", "tile", "grid", "slot_bytes", "slot_count", "tags", "slots", "pyramid", "ranges")

    def slot_index(self, S, T):
        """The slot of tile (S, T): (T mod GH) * GW + (S mod GW), Euclidean."""
        return (T % self.grid[1]) * self.grid[0] + (S % self.grid[0])

    def may_wrap(self, wraps):
        """Whether the level's region may run past its width: the texture wraps in longitude (the
        georef block's flag, `wraps`) and the width is a whole number of tiles (docs/SHM.md, "How
        a region wraps")."""
        return bool(wraps) and self.tile[0] > 0 and self.size[0] % self.tile[0] == 0

    def region_ok(self, v, wraps=False):
        """Whether an enabled level's region is inside the level (on a level that may wrap:
        0 <= s0 < width and s0 < s1 <= s0 + width, texel s being texel s mod width), non-empty,
        and spans at most GW x GH tiles."""
        for a in (0, 1):
            lo, hi = v[a], v[a + 2]
            if a == 0 and self.may_wrap(wraps):
                if not (0 <= lo < self.size[0] and lo < hi and hi - lo <= self.size[0]):
                    return False
            elif not (0 <= lo < hi <= self.size[a]):
                return False
            if (hi - 1) // self.tile[a] - lo // self.tile[a] + 1 > self.grid[a]:
                return False
        return True


class LevelState:
    __slots__ = ("centre", "valid", "enabled", "updated_tick")

    def __repr__(self):
        return f"LevelState(centre={self.centre}, valid={self.valid}, enabled={self.enabled})"


class Snapshot:
    """A consistent copy of the snapshot: min_lod, tick, invalid_border, centre, levels."""

    __slots__ = ("seq", "min_lod", "tick", "invalid_border", "centre", "levels")


class View:
    """A view bound by Mapping.view(name): the primary view `main` (record None) or a view record
    while it keeps the incarnation it had when it was found. snapshot() raises Removed once the
    record is freed or given to another view. `service` is the mapping holding the record;
    `mapping` the one whose texels the view reads: the same, or for a view with grids of its own
    (`own` True) the Mapping of DIR/clipmap-NAME@VIEW.map, read as its `main` (None in a listing of
    Mapping.views() until the view is read: then it is opened)."""

    __slots__ = ("service", "mapping", "name", "record", "incarnation", "weight", "offset", "snap", "own")

    def __repr__(self):
        return (f"View({self.name!r}, record={self.record}, incarnation={self.incarnation}, "
                f"weight={self.weight}{', own' if self.own else ''})")

    def alive(self):
        """Raises Removed when the view was removed (its record free, or another incarnation),
        Busy when the record stayed locked, Corrupt when it fails its checks."""
        if self.record is None:
            return
        state, inc, _, name = self.service._view_record(self.record)
        if state == VIEW_FREE:
            raise Removed(f'view "{self.name}" was removed: its record {self.record} is free')
        if inc != self.incarnation or (state == VIEW_OWN) != self.own:
            raise Removed(f'view "{self.name}" was removed: its record {self.record} went from incarnation '
                          f'{self.incarnation} to {inc} (view "{name}")')

    def texels(self):
        """The Mapping whose texels (and `main` snapshot, for a view with grids of its own) the
        view reads; a view with grids of its own listed by Mapping.views() has it opened now."""
        if self.mapping is None:
            self.mapping = self.service._open_own(self.name, self.record, self.incarnation)
        return self.mapping

    def snapshot(self):
        """A consistent, checked copy of the view's snapshot (docs/SHM.md, "Reading a view's
        snapshot"): the record's snapshot under its own sequence counter, then the record's state
        and incarnation under the record's seqlock. Also kept as self.snap. Raises Removed (the
        copy is not used), Busy or Corrupt (self.snap unchanged). Tick 0: nothing published yet."""
        m = self.texels()
        if self.record is None:
            self.snap = m.snapshot()
            return self.snap
        err = None
        try:
            # A view with grids of its own: `main`'s snapshot of its own mapping.
            snap = m._snapshot_at(H_SNAPSHOT if self.own else self.offset)
        except (Busy, Corrupt) as e:
            err = e
        self.alive()  # removed comes first: a record given to another view may be mid-way through its snapshot
        if err is not None:
            raise type(err)(f'view "{self.name}"{" (grids of its own)" if self.own else ""}: {err}')
        self.snap = snap
        return snap

    def read_region(self, level, s0, t0, w, h, snap=None):
        """Mapping.read_region under this view's snapshot (`snap`, else the last one taken, else a
        new one)."""
        return self.texels().read_region(level, s0, t0, w, h, snap or self.snap or self.snapshot())

    def texel(self, level, s, t, snap=None):
        return self.read_region(level, s, t, 1, 1, snap)


def own_mapping_name(service, view):
    """The name of the mapping of view `view`'s grids of its own, for the service named `service`:
    its files are DIR/clipmap-{service}@{view}.map and .req."""
    return f"{service}{OWN_SEPARATOR}{view}"


def own_mapping_path(path, view):
    """The path of view `view`'s own mapping beside the service's mapping `path`, which must be
    named DIR/clipmap-NAME.map (docs/SHM.md, "A view with grids of its own"): derived from the two
    names alone. Raises NoView for a name that is no view name, Refused for a `path` not so named."""
    if not view_name_ok(view):
        raise NoView(f'"{view}" is not a view name: expected 1 to {VIEW_NAME_MAX} of A-Z a-z 0-9 - _ .')
    d, base = os.path.split(path)
    name = base[len("clipmap-"):-len(".map")] if base.startswith("clipmap-") and base.endswith(".map") else ""
    if not (1 <= len(name) <= NAME_MAX and all(c in VIEW_NAME_CHARS for c in name.encode())):
        raise Refused(f'view "{view}" has grids of its own in DIR/clipmap-NAME{OWN_SEPARATOR}VIEW.map, named after '
                      f"the service's mapping, but the service's mapping was opened as {path}, not "
                      f"DIR/clipmap-NAME.map (NAME 1 to {NAME_MAX} of A-Z a-z 0-9 - _ .): open it by its published name")
    return os.path.join(d, f"clipmap-{own_mapping_name(name, view)}.map")


def request_centre(socket_path, s, t, view=None, timeout=5.0):
    """Asks the service for a level-0 centre through its control socket: `CENTRE s t` for the
    primary view (view None or "main"), `VIEW CENTRE NAME s t` for another (a name or a View).
    Python has no compare-and-swap on a mapping, so it cannot take the request mapping's lock
    words (docs/SHM.md); the socket's command does the same for anyone who can reach it. Returns
    the reply line ("OK ..."); raises NoView for a name that is no view name, ClipmapError on an
    ERR reply, OSError when the socket cannot be reached."""
    name = view.name if isinstance(view, View) else view
    if name is None or name == "main":
        line = f"CENTRE {int(s)} {int(t)}\n"
    elif view_name_ok(name):
        line = f"VIEW CENTRE {name} {int(s)} {int(t)}\n"
    else:
        raise NoView(f'"{name}" is not a view name: expected "main" or 1 to {VIEW_NAME_MAX} of A-Z a-z 0-9 - _ .')
    return _ask(socket_path, line, timeout)


def request_lod(socket_path, height, pixel_angle, effective=0, view=None, timeout=5.0):
    """Asks the service for the levels a view (None or "main": the primary; a name or a View) can
    use from `height` level-0 texels above the texture, one screen pixel spanning `pixel_angle`
    radians, addressing `effective` levels at once (0: all), through the control socket's
    `VIEW HEIGHT NAME HEIGHT ANGLE EFFECTIVE`: the service moves the view's LOD offset to the
    finest level sampled there and holds and reads nothing finer for it (docs/VIEWS.md, "Virtual
    views"). Raises ValueError for numbers that are not finite and above 0 (the angle below pi),
    NoView and ClipmapError as request_centre does."""
    import math

    h, a = float(height), float(pixel_angle)
    if not (math.isfinite(h) and h > 0 and math.isfinite(a) and 0 < a < math.pi):
        raise ValueError(f"height {h} and pixel angle {a}: expected a finite height above 0 (level-0 texels) "
                         "and an angle above 0 and below pi (radians)")
    e = int(effective)
    if e < 0:
        raise ValueError(f"effective levels {e}: expected 0 (all) or more")
    name = view.name if isinstance(view, View) else (view or "main")
    if name != "main" and not view_name_ok(name):
        raise NoView(f'"{name}" is not a view name: expected "main" or 1 to {VIEW_NAME_MAX} of A-Z a-z 0-9 - _ .')
    return _ask(socket_path, f"VIEW HEIGHT {name} {h!r} {a!r} {e}\n", timeout)


def _ask(socket_path, line, timeout):
    """One control-socket request line and its reply ("OK ..."), ClipmapError on anything else."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as c:
        c.settimeout(timeout)
        c.connect(socket_path)
        c.sendall(line.encode())
        reply = b""
        while not reply.endswith(b"\n"):
            got = c.recv(4096)
            if not got:
                break
            reply += got
    reply = reply.decode("utf-8", "replace").rstrip("\r\n")
    if not reply.startswith("OK"):
        raise ClipmapError(f"{socket_path}: {line.strip()}: {reply or 'no reply'}")
    return reply


class Mapping:
    """One texel mapping, mapped read-only; every static field checked (Refused otherwise). With
    `owner` (a uid; how a view's own mapping is opened): the name is not followed when it is a
    symbolic link (Refused) and the file must be owned by that uid."""

    def __init__(self, path, owner=None):
        self.path = path
        self.mm = None
        self.q = None
        self.snap = None
        self.owns = {}  # (record, incarnation) -> the own mapping of a view bound through this one (closed with it)
        # O_NONBLOCK: a FIFO given as the path must not block the open (it is refused below).
        flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
        try:
            fd = os.open(path, flags | (os.O_NOFOLLOW if owner is not None else 0))
        except OSError as e:
            if owner is not None and e.errno == errno.ELOOP:
                raise Refused(f"{path}: a symbolic link: expected the mapping itself (a name the service publishes "
                              f"is never a link)") from None
            raise
        try:
            st = os.fstat(fd)
            self.uid = st.st_uid
            if not stat.S_ISREG(st.st_mode):
                raise Refused(f"{path}: not a regular file")
            if owner is not None and st.st_uid != owner:
                raise Refused(f"{path}: owned by uid {st.st_uid}, expected uid {owner}, the owner of the service's "
                              f"mapping: not a file the service published (remove it, or ask its owner)")
            size = st.st_size
            if size < H_END:
                raise Refused(f"{path}: truncated: {size} bytes, a mapping has at least {H_END}")
            self.mm = mmap.mmap(fd, size, mmap.MAP_SHARED, mmap.PROT_READ)
        finally:
            os.close(fd)
        try:
            self._check(size)
        except Refused:
            self.close()
            raise
        # Native 8-byte loads (one load instruction each) for the fields the writer changes.
        # (Only whole 8-byte words: a file whose size is not a multiple of 8 still maps.)
        self.q = memoryview(self.mm)[: size // 8 * 8].cast("Q")

    def _u32(self, off):
        return struct.unpack_from("<I", self.mm, off)[0]

    def _u64(self, off):
        return struct.unpack_from("<Q", self.mm, off)[0]

    def _check(self, size):
        path, m = self.path, self.mm
        if m[0:7] != MAGIC[:7]:
            raise Refused(f"{path}: wrong magic {bytes(m[0:8])!r}: not a clipmap mapping (expected {MAGIC.decode()!r})")
        version = self._u32(H_VERSION)
        if m[7:8] != MAGIC[7:8] or version != VERSION:
            raise Refused(f"{path}: layout version {version} (magic {bytes(m[0:8])!r}); "
                          f"this reader reads layout version {VERSION} only")
        total = self._u64(H_TOTAL_BYTES)
        if total != size:
            raise Refused(f"{path}: the header says {total} bytes but the file has {size} (truncated or padded)")
        hb = self._u32(H_HEADER_BYTES)
        if hb % PAGE or hb < H_END or hb > total:
            raise Refused(f"{path}: header bytes {hb}: expected a multiple of {PAGE}, at least {H_END} "
                          f"and at most the {total} bytes of the mapping")
        self.header_bytes = hb
        self.bpt = bpt = self._u32(H_BYTES_PER_TEXEL)
        self.clip = clip = self._u32(H_CLIP_SIZE)
        self.count = n = self._u32(H_LEVEL_COUNT)
        self.format = self._u32(H_TEXEL_FORMAT)
        self.writer_pid = self._u32(H_WRITER_PID)
        self.size = (self._u64(H_LEVEL0_S), self._u64(H_LEVEL0_T))
        self.generation = self._u64(H_GENERATION)
        self.tick_period_ns = self._u64(H_TICK_PERIOD_NS)
        if not 1 <= bpt <= 64:
            raise Refused(f"{path}: {bpt} bytes per texel: expected 1 to 64")
        if self.format in FORMATS and FORMATS[self.format][1] != bpt:
            raise Refused(f"{path}: texel format {self.format} has {FORMATS[self.format][1]} bytes per texel, "
                          f"the header says {bpt}")
        self.heights = self._heights(path)
        if clip == 0:
            raise Refused(f"{path}: clip size 0: expected at least 1")
        if not 1 <= n <= MAX_LEVELS:
            raise Refused(f"{path}: {n} levels: expected 1 to {MAX_LEVELS}")
        self.georef = self._georef(path)
        if 0 in self.size:
            raise Refused(f"{path}: level 0 is {self.size[0]}x{self.size[1]}: expected a non-zero size")
        prev_end = hb
        self.levels = []
        for k in range(n):
            f = struct.unpack_from("<11Q", m, H_LEVEL_DESCS + k * DESC_BYTES)
            d = LevelDesc()
            d.size, d.tile, d.grid = (f[0], f[1]), (f[2], f[3]), (f[4], f[5])
            d.slot_bytes, d.tags, d.slots, kind, d.ranges = f[6], f[7], f[8], f[9], f[10]
            want = tuple(max(1, self.size[a] >> k) for a in (0, 1))
            if d.size != want:
                raise Refused(f"{path}: level {k} is {d.size[0]}x{d.size[1]}: expected level 0's "
                              f"{self.size[0]}x{self.size[1]} halved {k} times")
            if 0 in d.tile or 0 in d.grid:
                raise Refused(f"{path}: level {k}: tile {d.tile[0]}x{d.tile[1]}, grid {d.grid[0]}x{d.grid[1]}: "
                              "expected non-zero tiles and grids")
            d.pyramid = d.size[0] <= clip and d.size[1] <= clip
            for a in (0, 1):
                tiles = _ceil_div(d.size[a], d.tile[a])
                least = min(_ceil_div(min(clip, d.size[a]), d.tile[a]) + 1, tiles)
                g = f"grid {d.grid[0]}x{d.grid[1]}"
                if d.grid[a] > tiles:
                    raise Refused(f"{path}: level {k}: {g} is larger than the level's {tiles} tiles along axis {a}")
                if d.grid[a] < least:
                    raise Refused(f"{path}: level {k}: {g} cannot hold a {clip}-texel window "
                                  f"(needs {least} along axis {a})")
                if d.pyramid and d.grid[a] != tiles:
                    raise Refused(f"{path}: level {k}: a pyramid level's {g} must hold all its {tiles} tiles "
                                  f"along axis {a}")
            if kind != int(d.pyramid):
                raise Refused(f"{path}: level {k} ({d.size[0]}x{d.size[1]}, clip {clip}): kind {kind}, "
                              f"expected {int(d.pyramid)} ({'pyramid' if d.pyramid else 'stack'})")
            if self.format in BLOCK_FORMATS:
                sb = _ceil_div(d.tile[0], 4) * _ceil_div(d.tile[1], 4) * bpt
                if sb > M64 or sb != d.slot_bytes:
                    raise Refused(f"{path}: level {k}: slot bytes {d.slot_bytes}, expected tile "
                                  f"{d.tile[0]}x{d.tile[1]} in 4 x 4 blocks x {bpt} bytes per block"
                                  + (" (overflows 64 bits)" if sb > M64 else ""))
            sb = d.tile[0] * d.tile[1] * bpt
            if self.format not in BLOCK_FORMATS and (sb > M64 or sb != d.slot_bytes):
                raise Refused(f"{path}: level {k}: slot bytes {d.slot_bytes}, expected tile "
                              f"{d.tile[0]}x{d.tile[1]} x {bpt} bytes per texel"
                              + (" (overflows 64 bits)" if sb > M64 else ""))
            d.slot_count = d.grid[0] * d.grid[1]
            tags_bytes, slots_bytes = d.slot_count * TAG_BYTES, d.slot_count * d.slot_bytes
            if d.slot_count > M64 or tags_bytes > M64 or slots_bytes > M64:
                raise Refused(f"{path}: level {k}: grid {d.grid[0]}x{d.grid[1]} of {d.slot_bytes}-byte slots "
                              "overflows")
            tags_end = d.tags + tags_bytes
            if d.tags % PAGE or d.tags < prev_end or tags_end > total:
                raise Refused(f"{path}: level {k}: tags at {d.tags} ({tags_bytes} bytes): expected a page-aligned "
                              f"offset at or after {prev_end}, ending inside the {total}-byte mapping")
            slots_end = d.slots + slots_bytes
            if d.slots % PAGE or d.slots < tags_end or slots_end > total:
                raise Refused(f"{path}: level {k}: slots at {d.slots} ({slots_bytes} bytes): expected a "
                              f"page-aligned offset at or after the tags' end {tags_end}, ending inside the "
                              f"{total}-byte mapping")
            if d.ranges:
                at = f"{path}: level {k} descriptor, byte {H_LEVEL_DESCS + k * DESC_BYTES + DESC_RANGES_OFFSET} " \
                     f"(tile ranges offset): found {d.ranges}"
                if self.heights is None:
                    raise Refused(f"{at}, expected 0: the texels are not heights (heights block all zero)")
                if d.ranges % PAGE or d.ranges < tags_end or d.ranges + d.slot_count * RANGE_BYTES > d.slots:
                    raise Refused(f"{at}, expected 0 or a multiple of 4096 at or after the tags' end ({tags_end}) "
                                  f"whose {d.slot_count} entries of {RANGE_BYTES} bytes end at or before the slots "
                                  f"({d.slots})")
            prev_end = slots_end
            self.levels.append(d)
        self._check_views(prev_end)

    def _check_views(self, slots_end):
        """Checks the views block (docs/SHM.md, "Checks of the block") and sets views_offset,
        view_records and views_error. Refused for an offset that is not 0, not a multiple of 4096,
        before `slots_end` (the end of the last level's slots) or with the block past the end of
        the mapping; for a version-1 or -2 block with N outside 1..64, record bytes other than 2240, or
        a record that fails its checks (one the writer keeps locked is checked when it is read).
        A magic or version this reader does not know leaves "main" readable and every other view
        not (views_error says why), as a reader of layout 2 that ignores the block would."""
        path, m, total = self.path, self.mm, len(self.mm)
        off = self._u64(H_VIEWS_OFFSET)
        self.views_offset, self.view_records, self.views_error, self.views_version = 0, 0, None, 0
        if off == 0:
            return
        if off % PAGE or off < slots_end or off + VB_RECORDS > total:
            raise Refused(f"{path}: header byte {H_VIEWS_OFFSET} (views block offset): found {off}, expected 0 (no "
                          f"views) or a multiple of {PAGE} at or after the end of the last level's slots "
                          f"({slots_end}), the block inside the {total}-byte mapping")
        self.views_offset = off
        magic = bytes(m[off + VB_MAGIC:off + VB_MAGIC + 8])
        version = self._u32(off + VB_VERSION)
        if magic != VIEWS_MAGIC:
            self.views_error = (f"views block at {off}, byte {off + VB_MAGIC} (magic): found {magic!r}, "
                                f"expected {VIEWS_MAGIC.decode()!r}")
            return
        if not VIEWS_VERSION_MIN <= version <= VIEWS_VERSION:
            self.views_error = (f"views block at {off}, byte {off + VB_VERSION} (version): found {version}, "
                                f"this reader reads views block versions {VIEWS_VERSION_MIN} to {VIEWS_VERSION} only "
                                f"(main still reads; for other views use a reader of the service's release)")
            return
        n, rb = self._u32(off + VB_RECORD_COUNT), self._u32(off + VB_RECORD_BYTES)
        if not 1 <= n <= MAX_VIEWS:
            raise Refused(f"{path}: views block at {off}, byte {off + VB_RECORD_COUNT} (view records): found {n}, "
                          f"expected 1 to {MAX_VIEWS}")
        if rb != VIEW_RECORD_BYTES:
            raise Refused(f"{path}: views block at {off}, byte {off + VB_RECORD_BYTES} (record bytes): found {rb}, "
                          f"expected {VIEW_RECORD_BYTES}")
        size = _ceil_div(VB_RECORDS + n * VIEW_RECORD_BYTES, PAGE) * PAGE
        if off + size > total:
            raise Refused(f"{path}: header byte {H_VIEWS_OFFSET} (views block offset): found {off}, but the views "
                          f"block of {n} records ({size} bytes) then ends at {off + size}, past the end of the "
                          f"{total}-byte mapping")
        self.view_records, self.views_version = n, version
        q = memoryview(m)[off:off + size].cast("Q")  # the records' words, before self.q exists
        try:
            for r in range(n):
                try:
                    self._view_record(r, q, off)
                except Busy:
                    pass
                except Corrupt as e:
                    raise Refused(f"{path}: {e}") from None
        finally:
            q.release()

    def _view_record(self, r, q=None, base=None):
        """View record r's fields 0..128 read under the record's seqlock and checked: (state,
        incarnation, weight, name). Busy when the writer kept it locked for MAX_RETRIES attempts;
        Corrupt for a state other than 0 or 1 or, on a live record, a weight not finite and above
        0 or a name not 1 to 31 allowed characters followed by NULs only (or "main"). State 2 (VIEW_OWN,
        live with grids of its own) is one only a version-2 block may hold."""
        if q is None:
            q, base = self.q, 0
        at = self.views_offset + VB_RECORDS + r * VIEW_RECORD_BYTES
        b = (at - base) // 8
        for _ in range(MAX_RETRIES):
            s1 = q[b]
            if s1 & 1:
                continue
            f = q[b + 1: b + V_NAME // 8 + 4].tolist()
            if q[b] == s1:
                break
        else:
            raise Busy(f"view record {r}: the writer kept it locked for {MAX_RETRIES} attempts")
        state, inc, wbits = f[0], f[1], f[2]
        raw = b"".join(x.to_bytes(8, "little") for x in f[V_NAME // 8 - 1:])
        where = f"views block at {self.views_offset}, record {r}, byte"
        if self.views_version >= 2 and state > VIEW_OWN:
            raise Corrupt(f"{where} {at + V_STATE} (state): found {state}, expected 0 (free), 1 (live) or 2 (live "
                          f"with grids of its own)")
        if self.views_version < 2 and state > VIEW_LIVE:
            raise Corrupt(f"{where} {at + V_STATE} (state): found {state}, expected 0 (free) or 1 (live) in a views "
                          f"block of version {self.views_version} (state 2 comes with version 2)")
        weight = struct.unpack("<d", struct.pack("<Q", wbits))[0]
        n = raw.find(b"\0")
        n = len(raw) if n < 0 else n
        name = raw[:n].decode("ascii", "replace")
        if state == VIEW_FREE:
            return state, inc, weight, name
        if not (math.isfinite(weight) and weight > 0):
            raise Corrupt(f"{where} {at + V_WEIGHT} (weight): found {weight!r} (bits {wbits:016x}), expected a "
                          f"finite number above 0")
        if not (view_name_ok(raw[:n]) and not any(raw[n:])):
            raise Corrupt(f"{where} {at + V_NAME} (name): found {raw!r}, expected 1 to {VIEW_NAME_MAX} of "
                          f"A-Z a-z 0-9 - _ . followed by NULs only (never \"main\")")
        return state, inc, weight, name

    def views(self):
        """The views that exist: [View] with `main` first, then one per live view record in record
        order (each record read under its seqlock; a view with grids of its own has own True, its
        mapping not opened yet). Busy when a record stayed locked, Corrupt when one fails its checks
        or the views block has a magic or version this reader does not read."""
        out = [self._main_view()]
        if self.views_error:
            raise Corrupt(self.views_error)
        for r in range(self.view_records):
            state, inc, weight, name = self._view_record(r)
            if state != VIEW_FREE:
                out.append(self._bind(r, inc, weight, name, state == VIEW_OWN))
        return out

    def view_names(self):
        """The names of the views that exist: "main", then each live view record's in record order."""
        return [v.name for v in self.views()]

    def _main_view(self):
        v = View()
        v.mapping, v.name, v.record, v.incarnation, v.weight, v.offset, v.snap = self, "main", None, 0, 0.0, H_SNAPSHOT, None
        v.service, v.own = self, False
        return v

    def _bind(self, r, inc, weight, name, own=False):
        """A View of record r; with `own` (state VIEW_OWN) its mapping is opened when it is read."""
        v = View()
        v.service, v.name, v.record, v.incarnation, v.weight, v.snap, v.own = self, name, r, inc, weight, None, own
        v.mapping = None if own else self
        v.offset = None if own else self.views_offset + VB_RECORDS + r * VIEW_RECORD_BYTES + V_SNAPSHOT
        return v

    def _open_own(self, name, record, incarnation):
        """Opens the mapping of view `name`'s grids of its own (own_mapping_path): every check of
        any mapping, not followed when a symbolic link, owned by the owner of this mapping's file.
        Refused (naming the path) when it is missing or refused; closed with this mapping. The view
        of record `record` and `incarnation` has one: a second binding of it shares the first's."""
        if (record, incarnation) in self.owns:
            return self.owns[(record, incarnation)]
        path = own_mapping_path(self.path, name)
        try:
            own = Mapping(path, owner=self.uid)
        except FileNotFoundError:
            raise Refused(f'view "{name}" has grids of its own: {path}: no such file (expected the mapping the '
                          f"service publishes for the view: it was removed or is not published yet; look the view "
                          f"up again)") from None
        except OSError as e:
            raise Refused(f'view "{name}" has grids of its own: {path}: {e.strerror or e}') from None
        except Refused as e:
            raise Refused(f'view "{name}" has grids of its own: {e}') from None
        # It carries the generation of the service's start that published it (docs/SHM.md, "A
        # view with grids of its own"): another one is a mapping of another start, a reused name.
        if own.generation != self.generation:
            found = own.generation
            own.close()
            raise Refused(f'{path}: view "{name}" has grids of its own, but this mapping carries generation '
                          f"{found}, expected {self.generation} (the service's mapping's): it belongs to another "
                          f"start of the service; open the service's mapping again and look the view up there")
        self.owns[(record, incarnation)] = own
        return own

    def view(self, name):
        """Binds the view called `name` (docs/SHM.md, "Finding a view by name"): "main" is the
        primary view; any other name is looked for among the live view records (each read under
        its seqlock), and the record and its incarnation are kept. A view with grids of its own
        (record state 2) has its own mapping opened now (Refused, naming its path, when it is
        missing or refused), and is read as that mapping's `main`. Raises NoView (not a view name,
        or no live record carries it: the message names the views that exist), Busy (no record
        carries it but one stayed locked), Corrupt (a record fails its checks, or the views block
        has a magic or version this reader does not read)."""
        if name == "main":
            return self._main_view()
        if not view_name_ok(name):
            raise NoView(f'"{name}" is not a view name: expected "main" or 1 to {VIEW_NAME_MAX} of '
                         f"A-Z a-z 0-9 - _ .")
        if self.views_error:
            raise Corrupt(self.views_error)
        names, busy = ["main"], None
        for r in range(self.view_records):
            try:
                state, inc, weight, got = self._view_record(r)
            except Busy:
                busy = r
                continue
            if state == VIEW_FREE:
                continue
            if got == name:
                v = self._bind(r, inc, weight, got, state == VIEW_OWN)
                v.texels()  # a view with grids of its own: open its mapping now
                return v
            names.append(got)
        if busy is not None:
            raise Busy(f'no live view record is called "{name}" but view record {busy} stayed locked for '
                       f'{MAX_RETRIES} attempts')
        none = " (the mapping has no views block)" if self.views_offset == 0 else ""
        raise NoView(f'no view "{name}"{none}; the views are: {", ".join(names)}')

    def _georef(self, path):
        """The georef block and each level's affine terms, checked (docs/SHM.md, "Georef block"):
        None when the block is all zero (no georeferencing), else a dict of epsg (None: none
        known), wraps, definition (str), origin [x, y] (level 0's GDAL geotransform [0] and [3])
        and levels (per level [1], [2], [4], [5])."""
        b, m = H_GEOREF, self.mm
        names = ((0, "present"), (4, "EPSG code"), (8, "flags"), (12, "definition length"), (16, "origin x"),
                 (24, "origin y"), (32, "geotransform [1]"), (40, "geotransform [2]"), (48, "geotransform [4]"),
                 (56, "geotransform [5]"), (64, "definition"))
        def at(field):
            name = [n for o, n in names if o <= field][-1]
            return f"{path}: georef block, byte {b + field} ({name})"
        terms = ("[1]", "[2]", "[4]", "[5]")
        def desc_at(k, i):
            return f"{path}: level {k} descriptor, byte {H_LEVEL_DESCS + k * DESC_BYTES + DESC_GEOREF + 8 * i} " \
                   f"(georef {terms[i]})"
        block = bytes(m[b:b + GEOREF_BYTES])
        descs = [struct.unpack_from("<4Q", m, H_LEVEL_DESCS + k * DESC_BYTES + DESC_GEOREF) for k in range(self.count)]
        present = self._u32(b + GR_PRESENT)
        if present == 0:
            for i, v in enumerate(block):
                if v:
                    raise Refused(f"{at(i)}: found byte {v:#04x}, expected 0: the block says the texture has no "
                                  f"georeferencing (present 0), so it must be all zero")
            for k, d in enumerate(descs):
                for i, w in enumerate(d):
                    if w:
                        raise Refused(f"{desc_at(k, i)}: found {_f64(w):.17g}, expected 0: the texture has no "
                                      f"georeferencing (georef block all zero)")
            return None
        if present != 1:
            raise Refused(f"{at(GR_PRESENT)}: found {present}, expected 0 (no georeferencing) or 1 (georeferenced)")
        flags = self._u32(b + GR_FLAGS)
        if flags & ~GR_KNOWN_FLAGS:
            raise Refused(f"{at(GR_FLAGS)}: found {flags:#x}, expected only bit 0 (wraps in longitude): a bit "
                          f"this reader does not know")
        n = self._u32(b + GR_DEFINITION_LEN)
        if n > GR_DEFINITION_MAX:
            raise Refused(f"{at(GR_DEFINITION_LEN)}: found {n}, expected at most {GR_DEFINITION_MAX}")
        values = []
        for o in (GR_ORIGIN_X, GR_ORIGIN_Y, GR_TERMS, GR_TERMS + 8, GR_TERMS + 16, GR_TERMS + 24):
            v = struct.unpack_from("<d", block, o)[0]
            if not math.isfinite(v):
                raise Refused(f"{at(o)}: found {v:.17g}, expected a finite number")
            values.append(v)
        level0 = values[2:]
        det = level0[0] * level0[3] - level0[1] * level0[2]
        if not math.isfinite(det) or det == 0:
            raise Refused(f"{at(GR_TERMS)}: [1] x [5] - [2] x [4] = {det:.17g}, expected a finite number other than 0 "
                          f"(texels must span an area)")
        text = block[GR_DEFINITION:GR_DEFINITION + n]
        try:
            definition = text.decode("utf-8")
        except UnicodeDecodeError as e:
            raise Refused(f"{at(GR_DEFINITION + e.start)}: byte {e.start} of the definition ({text[e.start]:#04x}) "
                          f"is not UTF-8, expected UTF-8 text (a PROJ string or WKT)") from None
        if 0 in text:
            i = text.index(0)
            raise Refused(f"{at(GR_DEFINITION + i)}: a NUL at byte {i} of the {n}-byte definition, expected text "
                          f"without NUL")
        for i, v in enumerate(block[GR_DEFINITION + n:]):
            if v:
                raise Refused(f"{at(GR_DEFINITION + n + i)}: found byte {v:#04x} after the definition's {n} bytes, "
                              f"expected 0")
        levels = []
        for k, d in enumerate(descs):
            t = [_f64(w) for w in d]
            for i, v in enumerate(t):
                if not math.isfinite(v):
                    raise Refused(f"{desc_at(k, i)}: found {v:.17g}, expected a finite number")
            det = t[0] * t[3] - t[1] * t[2]
            if not math.isfinite(det) or det == 0:
                raise Refused(f"{desc_at(k, 0)}: [1] x [5] - [2] x [4] = {det:.17g}, expected a finite number other "
                              f"than 0 (the level's texels must span an area)")
            if k == 0:
                for i in range(4):
                    if d[i] != struct.unpack_from("<Q", block, GR_TERMS + 8 * i)[0]:
                        raise Refused(f"{desc_at(0, i)}: found {t[i]:.17g}, expected {level0[i]:.17g}, the georef block's "
                                      f"level-0 term (byte {b + GR_TERMS + 8 * i})")
            levels.append(t)
        epsg = self._u32(b + GR_EPSG)
        return {"epsg": epsg or None, "wraps": bool(flags & GR_WRAPS), "definition": definition,
                "origin": values[:2], "levels": levels}

    def map_of_texel(self, level, s, t):
        """The map coordinates of the continuous texel position (s, t) of `level` (t counting up
        from the south); None without georeferencing. Every level is anchored at the south-west
        corner SW = origin + H0 * ([2], [5]) of level 0 (H0 the level-0 height; a level whose
        height was rounded down drops level 0's northmost rows), so the position is
        SW + s * ([1], [4]) - t * ([2], [5]) of the level's terms."""
        g = self.georef
        if g is None:
            return None
        _, b0, _, e0 = g["levels"][0]
        h0 = self.size[1]
        swx, swy = g["origin"][0] + h0 * b0, g["origin"][1] + h0 * e0
        a, b, d, e = g["levels"][level]
        return (swx + a * s - b * t, swy + d * s - e * t)

    def _heights(self, path):
        """The heights block, checked: None when the texels are not heights, else a dict of
        storage, scale, offset, nodata (a stored value, None: none) and levels (the rule)."""
        b = H_HEIGHTS
        flag, rule = self._u32(b + HT_IS_HEIGHTS), self._u32(b + HT_RULE)
        raw = [self._u64(b + o) for o in (HT_SCALE, HT_OFFSET, HT_NODATA)]
        scale, offset, nodata = (struct.unpack("<d", struct.pack("<Q", v))[0] for v in raw)
        at = lambda field, name: f"{path}: heights block, byte {b + field} ({name})"
        if flag == 0:
            if rule or any(raw):
                raise Refused(f"{at(HT_IS_HEIGHTS, 'heights flag')}: the texels are not heights but the "
                              f"block is not all zero; expected all zero")
            return None
        if flag != 1:
            raise Refused(f"{at(HT_IS_HEIGHTS, 'heights flag')}: found {flag}, expected 0 (not heights) or 1 (heights)")
        storage = HEIGHT_STORAGES.get(self.format)
        if storage is None:
            raise Refused(f"{at(HT_IS_HEIGHTS, 'heights flag')}: heights on texel format code {self.format}, "
                          f"expected a height format: 11 (l32f), 7 (l16) or 12 (l16i)")
        if rule >= len(HEIGHT_RULES):
            raise Refused(f"{at(HT_RULE, 'level rule')}: found {rule}, expected 0 (mean), 1 (point), 2 (min) or 3 (max)")
        if not (math.isfinite(scale) and scale > 0):
            raise Refused(f"{at(HT_SCALE, 'scale')}: found {scale}, expected a finite number above zero")
        if not math.isfinite(offset):
            raise Refused(f"{at(HT_OFFSET, 'offset')}: found {offset}, expected a finite number")
        if storage == "l32f" and (scale != 1.0 or offset != 0.0):
            raise Refused(f"{at(HT_SCALE, 'scale')}: l32f stores metres: found scale {scale}, offset {offset}, "
                          f"expected 1 and 0")
        if storage != "l32f":
            # What HeightFormat::new refuses (crates/clipmap-base/src/height.rs): heights past 10,000 km from zero, and
            # steps too fine to be told apart at the heights' distance from zero.
            lo, hi = (0, 65535) if storage == "l16" else (-32768, 32767)
            m_lo, m_hi = lo * scale + offset, hi * scale + offset
            if abs(m_lo) > HEIGHT_LIMIT_M or abs(m_hi) > HEIGHT_LIMIT_M:
                field, name = (HT_OFFSET, "offset") if abs(offset) > HEIGHT_LIMIT_M else (HT_SCALE, "scale")
                raise Refused(f"{at(field, name)}: found scale {scale!r}, offset {offset!r}: {storage} then holds "
                              f"{m_lo!r} m to {m_hi!r} m, expected every height within 10000000 m of zero")
            big = max(abs(m_lo), abs(m_hi), abs(offset))
            least = big * sys.float_info.epsilon * 64.0
            if scale < least:
                raise Refused(f"{at(HT_SCALE, 'scale')}: found {scale!r}, expected a step of at least {least!r}: "
                              f"steps that small cannot be told apart at {big!r} m from zero in 64-bit arithmetic")
        if math.isnan(nodata):
            nodata = None
        elif storage == "l32f":
            if not math.isfinite(nodata) or struct.unpack("<f", struct.pack("<f", nodata))[0] != nodata:
                raise Refused(f"{at(HT_NODATA, 'nodata')}: found {nodata}, expected a finite 32-bit float or NaN (none)")
        else:
            lo, hi = (0, 65535) if storage == "l16" else (-32768, 32767)
            if not math.isfinite(nodata) or nodata != int(nodata) or not lo <= nodata <= hi:
                raise Refused(f"{at(HT_NODATA, 'nodata')}: found {nodata}, expected a whole number in {lo}..{hi} "
                              f"or NaN (none)")
        return {"storage": storage, "scale": scale, "offset": offset, "nodata": nodata, "levels": HEIGHT_RULES[rule]}

    def snapshot(self, view=None):
        """A consistent, checked copy of the primary view's snapshot; also kept as self.snap. Busy
        when the writer kept it locked (self.snap unchanged), Corrupt when published state is out
        of bounds. With `view` (a name or a View other than "main"): that view's snapshot, as
        View.snapshot (Removed, too; self.snap is left alone)."""
        if view is not None and view != "main" and not (isinstance(view, View) and view.record is None):
            return (self.view(view) if isinstance(view, str) else view).snapshot()
        self.snap = self._snapshot_at(H_SNAPSHOT)
        return self.snap

    def _snapshot_at(self, at):
        """The snapshot at byte offset `at` (H_SNAPSHOT for "main", a view record's V_SNAPSHOT for
        another view: every snapshot is laid out the same), consistent and checked."""
        q, n = self.q, self.count
        b = at // 8
        for _ in range(MAX_RETRIES):
            s1 = q[b]
            if s1 & 1:
                continue
            head = q[b + 1: b + 6].tolist()
            states = q[b + SNAP_LEVELS // 8: b + (SNAP_LEVELS + n * STATE_BYTES) // 8].tolist()
            if q[b] == s1:
                break
        else:
            raise Busy(f"the writer kept the snapshot locked for {MAX_RETRIES} attempts")
        snap = Snapshot()
        snap.seq = s1
        snap.min_lod = struct.unpack("<d", struct.pack("<Q", head[0]))[0]
        snap.tick, snap.invalid_border = head[1], head[2]
        snap.centre = (_signed(head[3]), _signed(head[4]))
        if not 0.0 <= snap.min_lod <= n:  # refuses NaN and infinities too
            raise Corrupt(f"published min LOD {snap.min_lod!r} (bits {head[0]:016x}): expected a finite value "
                          f"in 0..={n}")
        snap.levels = []
        for k in range(n):
            f = states[8 * k: 8 * k + 8]
            st = LevelState()
            st.centre = (_signed(f[0]), _signed(f[1]))
            st.valid = tuple(_signed(x) for x in f[2:6])
            st.updated_tick = f[7]
            if f[6] > 1:
                raise Corrupt(f"level {k}: published enabled flag {f[6]}: expected 0 or 1")
            st.enabled = f[6] == 1
            d = self.levels[k]
            if st.enabled and not d.region_ok(st.valid, self.wraps):
                v = st.valid
                how = " (it wraps: s0 inside the level, s1 - s0 at most its width)" if d.may_wrap(self.wraps) else ""
                raise Corrupt(f"level {k}: published region [{v[0]}, {v[2]}) x [{v[1]}, {v[3]}): expected a "
                              f"non-empty rectangle inside the {d.size[0]}x{d.size[1]} level spanning at most "
                              f"{d.grid[0]}x{d.grid[1]} tiles{how}")
            snap.levels.append(st)
        return snap

    def growth(self):
        """A growing texture's growth block as a dict (extent, data_levels, patches, tiles_rebuilt,
        tiles_pending, tiles_replaced, world_origin, texels_per_unit, outside_frame), or None for a
        texture that does not grow. Read again to follow growth: addresses never move. Busy when
        the writer kept it locked, Corrupt when its values are impossible."""
        q = self.q
        b = H_GROWTH // 8
        for _ in range(MAX_RETRIES):
            s1 = q[b]
            if s1 & 1:
                continue
            f = q[b: b + GROWTH_BYTES // 8].tolist()
            if q[b] == s1:
                break
        else:
            raise Busy(f"the writer kept the growth block locked for {MAX_RETRIES} attempts")
        if f[1] > 1:
            raise Corrupt(f"growth block: growing is {f[1]}, expected 0 or 1")
        if f[1] == 0:
            return None
        fl = lambda i: struct.unpack("<d", struct.pack("<Q", f[i]))[0]
        g = {
            "extent": [_signed(x) for x in f[2:6]],
            "data_levels": f[6], "patches": f[7], "tiles_rebuilt": f[8], "tiles_pending": f[9],
            "tiles_replaced": f[10], "world_origin": [fl(11), fl(12)], "texels_per_unit": fl(13),
            "outside_frame": f[14],
        }
        e = g["extent"]
        w, h = self.levels[0].size
        if e != [0, 0, 0, 0] and not (0 <= e[0] < e[2] <= w and 0 <= e[1] < e[3] <= h):
            raise Corrupt(f"growth block: extent {e} is not inside the {w}x{h} frame")
        finite = all(abs(v) < float("inf") for v in g["world_origin"] + [g["texels_per_unit"]])
        if not finite or not g["texels_per_unit"] > 0 or g["data_levels"] > 64:
            raise Corrupt(f"growth block: world origin {g['world_origin']}, {g['texels_per_unit']} texels a unit, "
                          f"{g['data_levels']} data levels: expected finite numbers, a resolution above 0, "
                          f"at most 64 levels")
        return g

    def texel_offset(self, level, s, t):
        """Byte offset in the mapping of texel (s, t) of `level` in the slot its tile maps to
        (None outside the level). Says nothing about what the slot holds: see read_region."""
        if not 0 <= level < self.count:
            return None
        d = self.levels[level]
        if not (0 <= s < d.size[0] and 0 <= t < d.size[1]):
            return None
        S, T = s // d.tile[0], t // d.tile[1]
        return d.slots + d.slot_index(S, T) * d.slot_bytes + ((t - T * d.tile[1]) * d.tile[0] + s - S * d.tile[0]) * self.bpt

    def read_region(self, level, s0, t0, w, h, snap=None):
        """The w x h texels of `level` from (s0, t0), as bytes (rows in increasing t, s fastest,
        row pitch w * bpt), read tile by tile under each slot's tag. `snap` defaults to the last
        snapshot taken (one is taken if there is none). Raises NotValid, Missing, Stale or Busy."""
        if self.format in BLOCK_FORMATS:
            raise ReadError(f"texel format {FORMATS[self.format][0]} is block-compressed: read whole tiles "
                            "(read_tile) or decode them (decode_tile)")
        snap = snap or self.snap or self.snapshot()
        if not 0 <= level < min(self.count, len(snap.levels)):
            raise NotValid(f"level {level} does not exist")
        st, d = snap.levels[level], self.levels[level]
        v = st.valid
        if not st.enabled:
            raise NotValid(f"level {level} is disabled")
        if w <= 0 or h <= 0:
            return b""
        width = d.size[0]
        if self.wraps:
            # Texel s is texel s mod width: the rectangle, taken to the region's lap, must end by s1.
            at = v[0] + (s0 - v[0]) % width
            inside = w <= width and at + w <= v[2] and v[1] <= t0 and t0 + h <= v[3]
        else:
            inside = v[0] <= s0 and s0 + w <= v[2] and v[1] <= t0 and t0 + h <= v[3]
        if not inside:
            raise NotValid(f"[{s0}, {s0 + w}) x [{t0}, {t0 + h}) is not inside level {level}'s published region "
                           f"[{v[0]}, {v[2]}) x [{v[1]}, {v[3]})" + (" (s taken modulo the width)" if self.wraps else ""))
        out = bytearray(w * h * self.bpt)
        if not self.wraps:
            self._copy(level, d, s0, t0, w, h, out, w, 0)
            return bytes(out)
        col, real = 0, s0 % width
        while col < w:
            n = min(w - col, width - real)
            self._copy(level, d, real, t0, n, h, out, w, col)
            col, real = col + n, 0
        return bytes(out)

    @property
    def wraps(self):
        """Whether the texture wraps in longitude (the georef block's flag bit 0): texel s of every
        level is texel s mod width, and a level's region may run past its width."""
        return bool(self.georef and self.georef["wraps"])

    def _copy(self, level, d, s0, t0, w, h, out, pitch, col):
        """Copies the w x h texels from (s0, t0), inside the level, into `out` at column `col` of
        rows `pitch` texels long, tile by tile under each slot's tag."""
        bpt, (tw, th), mm, q = self.bpt, d.tile, self.mm, self.q
        for T in range(t0 // th, (t0 + h - 1) // th + 1):
            ta, tb = max(t0, T * th), min(t0 + h, (T + 1) * th)
            for S in range(s0 // tw, (s0 + w - 1) // tw + 1):
                sa, sb = max(s0, S * tw), min(s0 + w, (S + 1) * tw)
                slot = d.slot_index(S, T)
                tag = (d.tags + slot * TAG_BYTES) // 8
                base = d.slots + slot * d.slot_bytes
                run = (sb - sa) * bpt
                for _ in range(MAX_RETRIES):
                    seq = q[tag]
                    if seq & 1:
                        continue
                    ts, tt, state = _signed(q[tag + 1]), _signed(q[tag + 2]), q[tag + 3]
                    if ts == S and tt == T and state in (SLOT_READY, SLOT_DEFAULT):
                        for t in range(ta, tb):
                            src = base + ((t - T * th) * tw + (sa - S * tw)) * bpt
                            dst = ((t - t0) * pitch + col + (sa - s0)) * bpt
                            out[dst:dst + run] = mm[src:src + run]
                        if q[tag] == seq:
                            break
                        continue
                    if q[tag] != seq:
                        continue
                    if ts == S and tt == T and state == SLOT_MISSING:
                        raise Missing(f"level {level} tile ({S}, {T}) is missing")
                    raise Stale(f"level {level} tile ({S}, {T}): its slot holds tile ({ts}, {tt}) in state {state}")
                else:
                    raise Busy(f"level {level} tile ({S}, {T}): the tag stayed locked for {MAX_RETRIES} attempts")

    def read_tile(self, level, S, T):
        """The bytes of tile (S, T)'s slot of `level` as they are (for a block format, its
        ceil(TW / 4) x ceil(TH / 4) blocks in rows), copied under the slot's tag. Raises NotValid,
        Missing, Stale or Busy."""
        if not 0 <= level < self.count:
            raise NotValid(f"level {level} does not exist")
        d, q, mm = self.levels[level], self.q, self.mm
        if not (0 <= S < _ceil_div(d.size[0], d.tile[0]) and 0 <= T < _ceil_div(d.size[1], d.tile[1])):
            raise NotValid(f"level {level} has no tile ({S}, {T})")
        slot = d.slot_index(S, T)
        tag = (d.tags + slot * TAG_BYTES) // 8
        base = d.slots + slot * d.slot_bytes
        for _ in range(MAX_RETRIES):
            seq = q[tag]
            if seq & 1:
                continue
            ts, tt, state = _signed(q[tag + 1]), _signed(q[tag + 2]), q[tag + 3]
            if ts == S and tt == T and state in (SLOT_READY, SLOT_DEFAULT):
                out = bytes(mm[base:base + d.slot_bytes])
                if q[tag] == seq:
                    return out
                continue
            if q[tag] != seq:
                continue
            if ts == S and tt == T and state == SLOT_MISSING:
                raise Missing(f"level {level} tile ({S}, {T}) is missing")
            raise Stale(f"level {level} tile ({S}, {T}): its slot holds tile ({ts}, {tt}) in state {state}")
        raise Busy(f"level {level} tile ({S}, {T}): the tag stayed locked for {MAX_RETRIES} attempts")

    def decode_tile(self, level, S, T):
        """Tile (S, T) of `level` of a block-compressed mapping decoded in pure Python
        (decode_blocks): TW x TH texels, RGBA8 for bc1 and bc7, one byte for bc4, two for bc5,
        equal to the Rust client's decode_tile bit for bit."""
        d = self.levels[level]
        return decode_blocks(self.format, self.read_tile(level, S, T), d.tile[0], d.tile[1])

    def tile_range(self, level, S, T):
        """The range of heights of tile (S, T) of `level` as the service published it beside the
        slot's tag, read under the tag like texels: (min, max) in metres, nodata excluded, both
        NaN when every texel of the tile is nodata. None when the texels are not heights (no
        ranges) or the slot does not hold the tile ready or default. Raises Busy."""
        if not 0 <= level < self.count:
            raise NotValid(f"level {level} does not exist")
        d = self.levels[level]
        if not d.ranges:
            return None
        slot = d.slot_index(S, T)
        tag = (d.tags + slot * TAG_BYTES) // 8
        e = (d.ranges + slot * RANGE_BYTES) // 8
        q = self.q
        for _ in range(MAX_RETRIES):
            seq = q[tag]
            if seq & 1:
                continue
            ts, tt, state = _signed(q[tag + 1]), _signed(q[tag + 2]), q[tag + 3]
            lo, hi = q[e + RANGE_MIN // 8], q[e + RANGE_MAX // 8]
            if q[tag] != seq:
                continue
            if ts != S or tt != T or state not in (SLOT_READY, SLOT_DEFAULT):
                return None
            return tuple(struct.unpack("<d", struct.pack("<Q", v))[0] for v in (lo, hi))
        raise Busy(f"level {level} tile ({S}, {T}): the tag stayed locked for {MAX_RETRIES} attempts")

    def metres(self, texel):
        """The height in metres of one texel's bytes (None: nodata); the texels must be heights."""
        h = self.heights
        fmt = {"l32f": "<f", "l16": "<H", "l16i": "<h"}[h["storage"]]
        v = struct.unpack(fmt, texel)[0]
        if h["nodata"] is not None and v == h["nodata"]:
            return None
        return v * h["scale"] + h["offset"]

    def texel(self, level, s, t, snap=None):
        """One texel's bytes (see read_region)."""
        return self.read_region(level, s, t, 1, 1, snap)

    def heartbeat_age_ms(self):
        return max(0, int(time.time() * 1000) - self.q[H_HEARTBEAT_MS // 8])

    def closed(self):
        """True when the writer shut down cleanly (flag bit 0)."""
        return bool(self.q[H_FLAGS // 8] & 1)

    def close(self):
        for own in self.owns.values():
            own.close()
        self.owns = {}
        if self.q is not None:
            self.q.release()
            self.q = None
        if self.mm is not None:
            self.mm.close()
            self.mm = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


Clipmap = Mapping  # the layout-1 name

SMALL, LARGE = 8, 128


def _pick(rng, mode, v0, v1, tile):
    """A random extent (lo, n) inside [v0, v1): mode 0 small, 1 large, 2 across a tile edge."""
    span = v1 - v0
    if mode == 2:
        rng[0] = splitmix64(rng[0])
        at = v0 + rng[0] % span
        e = (at // tile + 1) * tile
        if v0 < e < v1:
            rng[0] = splitmix64(rng[0])
            before = 1 + rng[0] % SMALL
            rng[0] = splitmix64(rng[0])
            after = 1 + rng[0] % SMALL
            a, b = max(v0, e - before), min(v1, e + after)
            return a, b - a
        mode = 0
    most = SMALL if mode == 0 else LARGE
    rng[0] = splitmix64(rng[0])
    w = 1 + rng[0] % min(span, most)
    rng[0] = splitmix64(rng[0])
    return v0 + rng[0] % (span - w + 1), w


# PNG colour type and bit depth of the formats a PNG holds exactly (code -> (type, depth)).
PNG_FORMATS = {1: (0, 8), 3: (2, 8), 4: (6, 8), 7: (0, 16), 8: (4, 16), 9: (2, 16), 10: (6, 16)}


def _bc4_values(b):
    """The 16 values of a BC4 block (8 bytes), by the eight- or six-value palette of its endpoints
    (bcdec's arithmetic, so the values equal the Rust client's decoder's)."""
    e0, e1 = b[0], b[1]
    if e0 > e1:
        w = (9363, 18724, 28086, 37450, 46812, 56173)
        pal = [e0, e1] + [(w[6 - i] * e0 + w[i - 1] * e1 + 32768) >> 16 for i in range(1, 7)]
    else:
        w = (13107, 26215, 39321, 52429)
        pal = [e0, e1] + [(w[4 - i] * e0 + w[i - 1] * e1 + 32768) >> 16 for i in range(1, 5)] + [0, 255]
    bits = int.from_bytes(b[2:8], "little")
    return [pal[(bits >> (3 * i)) & 7] for i in range(16)]


def _bc1_texels(b):
    """The 16 RGBA8 texels of a BC1 block (8 bytes): bcdec's arithmetic (5:6:5 widened, the thirds
    and the mean in fixed point), so the texels equal the Rust client's decoder's."""
    c0, c1 = int.from_bytes(b[0:2], "little"), int.from_bytes(b[2:4], "little")
    e0, e1 = ((c0 >> 11) & 31, (c0 >> 5) & 63, c0 & 31), ((c1 >> 11) & 31, (c1 >> 5) & 63, c1 & 31)

    def wide(e):
        return [(e[0] * 527 + 23) >> 6, (e[1] * 259 + 33) >> 6, (e[2] * 527 + 23) >> 6, 255]

    def third(x, y):  # (2x + y) / 3 of 5:6:5 components
        return [((2 * x[0] + y[0]) * 351 + 61) >> 7, ((2 * x[1] + y[1]) * 2763 + 1039) >> 11,
                ((2 * x[2] + y[2]) * 351 + 61) >> 7, 255]
    if c0 > c1:
        pal = [wide(e0), wide(e1), third(e0, e1), third(e1, e0)]
    else:
        half = [((e0[0] + e1[0]) * 1053 + 125) >> 8, ((e0[1] + e1[1]) * 4145 + 1019) >> 11,
                ((e0[2] + e1[2]) * 1053 + 125) >> 8, 255]
        pal = [wide(e0), wide(e1), half, [0, 0, 0, 0]]
    bits = int.from_bytes(b[4:8], "little")
    return [pal[(bits >> (2 * i)) & 3] for i in range(16)]


# BC7 (docs/SHM.md, "Block-compressed formats"): the format's tables. Each partition is its 16
# texels' subsets (texel i = 4 * row + column); an anchor is the texel whose index of a subset
# other than subset 0 is stored with one bit less (subset 0's is texel 0).
_BC7_PARTITIONS2 = (
    "0011001100110011", "0001000100010001", "0111011101110111", "0001001100110111",
    "0000000100010011", "0011011101111111", "0001001101111111", "0000000100110111",
    "0000000000010011", "0011011111111111", "0000000101111111", "0000000000010111",
    "0001011111111111", "0000000011111111", "0000111111111111", "0000000000001111",
    "0000100011101111", "0111000100000000", "0000000010001110", "0111001100010000",
    "0011000100000000", "0000100011001110", "0000000010001100", "0111001100110001",
    "0011000100010000", "0000100010001100", "0110011001100110", "0011011001101100",
    "0001011111101000", "0000111111110000", "0111000110001110", "0011100110011100",
    "0101010101010101", "0000111100001111", "0101101001011010", "0011001111001100",
    "0011110000111100", "0101010110101010", "0110100101101001", "0101101010100101",
    "0111001111001110", "0001001111001000", "0011001001001100", "0011101111011100",
    "0110100110010110", "0011110011000011", "0110011010011001", "0000011001100000",
    "0100111001000000", "0010011100100000", "0000001001110010", "0000010011100100",
    "0110110010010011", "0011011011001001", "0110001110011100", "0011100111000110",
    "0110110011001001", "0110001100111001", "0111111010000001", "0001100011100111",
    "0000111100110011", "0011001111110000", "0010001011101110", "0100010001110111",
)
_BC7_ANCHORS2 = (15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 2, 8, 2, 2, 8, 8, 15, 2, 8, 2, 2, 8, 8, 2, 2, 15, 15, 6, 8, 2, 8, 15, 15, 2, 8, 2, 2, 2, 15, 15, 6, 6, 2, 6, 8, 15, 15, 2, 2, 15, 15, 15, 15, 15, 2, 2, 15)
_BC7_PARTITIONS3 = (
    "0011001102212222", "0001001122112221", "0000200122112211", "0222002200110111",
    "0000000011221122", "0011001100220022", "0022002211111111", "0011001122112211",
    "0000000011112222", "0000111111112222", "0000111122222222", "0012001200120012",
    "0112011201120112", "0122012201220122", "0011011211221222", "0011200122002220",
    "0001001101121122", "0111001120012200", "0000112211221122", "0022002200221111",
    "0111011102220222", "0001000122212221", "0000001101220122", "0000110022102210",
    "0122012200110000", "0012001211222222", "0110122112210110", "0000011012211221",
    "0022110211020022", "0110011020022222", "0011012201220011", "0000200022112221",
    "0000000211221222", "0222002200120011", "0011001200220222", "0120012001200120",
    "0000111122220000", "0120120120120120", "0120201212010120", "0011220011220011",
    "0011112222000011", "0101010122222222", "0000000021212121", "0022112200221122",
    "0022001100220011", "0220122102201221", "0101222222220101", "0000212121212121",
    "0101010101012222", "0222011102220111", "0002111200021112", "0000211221122112",
    "0222011101110222", "0002111211120002", "0110011001102222", "0000000021122112",
    "0110011022222222", "0022001100110022", "0022112211220022", "0000000000002112",
    "0002000100020001", "0222122202221222", "0101222222222222", "0111201122012220",
)
_BC7_ANCHORS3 = ((3, 15), (3, 8), (15, 8), (15, 3), (8, 15), (3, 15), (15, 3), (15, 8), (8, 15), (8, 15), (6, 15), (6, 15), (6, 15), (5, 15), (3, 15), (3, 8), (3, 15), (3, 8), (8, 15), (15, 3), (3, 15), (3, 8), (6, 15), (10, 8), (5, 3), (8, 15), (8, 6), (6, 10), (8, 15), (5, 15), (15, 10), (15, 8), (8, 15), (15, 3), (3, 15), (5, 10), (6, 10), (10, 8), (8, 9), (15, 10), (15, 6), (3, 15), (15, 8), (5, 15), (15, 3), (15, 6), (15, 6), (15, 8), (3, 15), (15, 3), (5, 15), (5, 15), (5, 15), (8, 15), (5, 15), (10, 15), (5, 15), (10, 15), (8, 15), (13, 15), (15, 3), (12, 15), (3, 15), (3, 8))
_BC7_WEIGHTS = {
    2: (0, 21, 43, 64),
    3: (0, 9, 18, 27, 37, 46, 55, 64),
    4: (0, 4, 9, 13, 17, 21, 26, 30, 34, 38, 43, 47, 51, 55, 60, 64),
}
# Per mode 0..7: subsets, partition bits, rotation bits, index selection bits, colour bits, alpha
# bits, p-bits per endpoint, shared p-bits per subset, index bits, secondary index bits.
_BC7_MODES = (
    (3, 4, 0, 0, 4, 0, 1, 0, 3, 0),
    (2, 6, 0, 0, 6, 0, 0, 1, 3, 0),
    (3, 6, 0, 0, 5, 0, 0, 0, 2, 0),
    (2, 6, 0, 0, 7, 0, 1, 0, 2, 0),
    (1, 0, 2, 1, 5, 6, 0, 0, 2, 3),
    (1, 0, 2, 0, 7, 8, 0, 0, 2, 2),
    (1, 0, 0, 0, 7, 7, 1, 0, 4, 0),
    (2, 6, 0, 0, 5, 5, 1, 0, 2, 0),
)


def _bc7_texels(b):
    """The 16 RGBA8 texels of a BC7 block (16 bytes), every mode 0..7 by the format's definition
    (Direct3D 11's BC7 decoding; exact, so the texels equal any conforming decoder's, bcdec's
    among them). A block whose first byte is 0 (no mode) decodes to transparent black."""
    v = int.from_bytes(b[:16], "little")
    mode = 0
    while mode < 8 and not (v >> mode) & 1:
        mode += 1
    if mode == 8:
        return [[0, 0, 0, 0]] * 16
    at = mode + 1

    def take(n):
        nonlocal at
        x = (v >> at) & ((1 << n) - 1)
        at += n
        return x
    ns, pb, rb, isb, cb, ab, epb, spb, ib, ib2 = _BC7_MODES[mode]
    partition, rotation, selection = take(pb), take(rb), take(isb)
    ends = 2 * ns
    # Endpoints: red of every endpoint, then green, blue and alpha (subset 0's two first).
    ep = [[0, 0, 0, 255] for _ in range(ends)]
    for c in range(3):
        for e in range(ends):
            ep[e][c] = take(cb)
    if ab:
        for e in range(ends):
            ep[e][3] = take(ab)
    # P-bits: one per endpoint, or one per subset shared by its two endpoints.
    if epb:
        pbits = [take(1) for _ in range(ends)]
    elif spb:
        shared = [take(1) for _ in range(ns)]
        pbits = [shared[e // 2] for e in range(ends)]
    else:
        pbits = None
    for e in range(ends):
        for c in range(4):
            n = cb if c < 3 else ab
            if n == 0:
                continue
            x = ep[e][c]
            if pbits is not None:
                x, n = x << 1 | pbits[e], n + 1
            x <<= 8 - n
            ep[e][c] = x | x >> n
    if ns == 1:
        subsets, anchors = "0" * 16, (0,)
    elif ns == 2:
        subsets, anchors = _BC7_PARTITIONS2[partition], (0, _BC7_ANCHORS2[partition])
    else:
        subsets, anchors = _BC7_PARTITIONS3[partition], (0,) + _BC7_ANCHORS3[partition]
    idx = [take(ib - (i in anchors)) for i in range(16)]
    idx2 = [take(ib2 - (i == 0)) for i in range(16)] if ib2 else idx
    wc, wa = _BC7_WEIGHTS[ib], _BC7_WEIGHTS[ib2 or ib]
    if selection:  # mode 4: the colour takes the secondary indices, alpha the primary ones
        idx, idx2, wc, wa = idx2, idx, wa, wc
    out = []
    for i in range(16):
        e0, e1 = ep[2 * int(subsets[i])], ep[2 * int(subsets[i]) + 1]
        w, wal = wc[idx[i]], wa[idx2[i]]
        t = [(e0[c] * (64 - w) + e1[c] * w + 32) >> 6 for c in range(3)]
        t.append((e0[3] * (64 - wal) + e1[3] * wal + 32) >> 6)
        if rotation:
            t[3], t[rotation - 1] = t[rotation - 1], t[3]
        out.append(t)
    return out


def decode_blocks(fmt, blocks, w, h):
    """Decodes a w x h tile of format code `fmt` (20 bc1, 21 bc4, 22 bc5, 23 bc7) stored as
    ceil(w / 4) x ceil(h / 4) blocks in rows into w * h texels (RGBA8, one byte, two bytes, RGBA8),
    rows in increasing t; texels of a partial block beyond w or h are dropped. A check's decoder,
    in pure Python: BC7 by the format's definition (exact), BC1, BC4 and BC5 with bcdec's
    arithmetic, so the texels equal the Rust client's decoder's bit for bit (a GPU's BC1, BC4 and
    BC5 palettes may differ from them by 1). Another format code: ValueError."""
    px = {20: 4, 21: 1, 22: 2, 23: 4}.get(fmt)
    if px is None:
        raise ValueError(f"texel format code {fmt}: not block-compressed (expected 20 bc1, 21 bc4, 22 bc5 or 23 bc7)")
    bb, bw, bh = (16 if fmt in (22, 23) else 8), _ceil_div(w, 4), _ceil_div(h, 4)
    if len(blocks) != bw * bh * bb:
        raise ValueError(f"{len(blocks)} bytes for a {w}x{h} tile: expected {bw}x{bh} blocks of {bb} bytes")
    out = bytearray(w * h * px)
    for j in range(bh):
        for i in range(bw):
            b = blocks[(j * bw + i) * bb:(j * bw + i + 1) * bb]
            if fmt == 20:
                texels = [bytes(p) for p in _bc1_texels(b)]
            elif fmt == 21:
                texels = [bytes([v]) for v in _bc4_values(b)]
            elif fmt == 22:
                texels = [bytes([r, g]) for r, g in zip(_bc4_values(b[:8]), _bc4_values(b[8:]))]
            else:
                texels = [bytes(p) for p in _bc7_texels(b)]
            for n, texel in enumerate(texels):
                x, y = 4 * i + n % 4, 4 * j + n // 4
                if x < w and y < h:
                    out[(y * w + x) * px:(y * w + x + 1) * px] = texel
    return bytes(out)


def write_png(path, data, w, h, fmt):
    """Writes `data` (w x h texels of format code `fmt`, rows in increasing t, as read_region
    returns them) as a PNG with t upwards: its top row is the last t row. 16-bit components are
    stored little-endian in the mapping and big-endian in PNG. Raises ValueError for a format
    PNG_FORMATS does not name."""
    if fmt not in PNG_FORMATS:
        name = FORMATS.get(fmt, ("code %d" % fmt,))[0]
        raise ValueError(f"texel format {name} has no exact PNG form here: write OUT.raw instead")
    colour, depth = PNG_FORMATS[fmt]
    pitch = w * FORMATS[fmt][1]
    rows = []
    for y in range(h):
        row = data[(h - 1 - y) * pitch:(h - y) * pitch]
        if depth == 16:
            swapped = bytearray(row)
            swapped[0::2], swapped[1::2] = row[1::2], row[0::2]
            row = bytes(swapped)
        rows.append(b"\0" + row)

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(b"".join(rows), 6)) + chunk(b"IEND", b""))
    with open(path, "wb") as f:
        f.write(png)


def dump(argv, view_name):
    """MAPPING --dump LEVEL S0,T0,S1,T1 OUT [SECONDS] (see the module's text)."""
    usage = f"usage: {argv[0]} MAPPING --dump LEVEL S0,T0,S1,T1 OUT [SECONDS] [--view NAME]"
    try:
        if len(argv) not in (6, 7):
            raise ValueError("expected LEVEL, the region and OUT")
        level = int(argv[3])
        s0, t0, s1, t1 = (int(x) for x in argv[4].split(","))
        seconds = float(argv[6]) if len(argv) > 6 else 5.0
        out = argv[5]
        if not out.endswith((".raw", ".png")):
            raise ValueError(f"OUT {out}: expected a name ending in .raw or .png")
    except ValueError as e:
        print(f"{usage}: {e}", file=sys.stderr)
        return 2
    try:
        m = Mapping(argv[1])
        v = m.view(view_name)
        tm = v.texels()
        if not 0 <= level < tm.count:
            raise Refused(f"--dump level {level}: the texture has levels 0 to {tm.count - 1}")
        d = tm.levels[level]
        if not (0 <= s0 < s1 <= d.size[0] and 0 <= t0 < t1 <= d.size[1]) or (s1 - s0) * (t1 - t0) > 4096 * 4096:
            raise Refused(f"--dump region {s0},{t0},{s1},{t1}: expected 0 <= S0 < S1 <= {d.size[0]} and "
                          f"0 <= T0 < T1 <= {d.size[1]}, at most 4096x4096 texels")
        if out.endswith(".png") and tm.format not in PNG_FORMATS:
            raise Refused(f"texel format {FORMATS.get(tm.format, ('code %d' % tm.format,))[0]} has no exact PNG "
                          f"form here: write OUT.raw instead")
        deadline = time.monotonic() + seconds
        snap = None
        while True:
            try:
                snap = v.snapshot()
                data = v.read_region(level, s0, t0, s1 - s0, t1 - t0, snap)
                break
            except (NotValid, Stale, Busy) as e:
                if time.monotonic() >= deadline:
                    where = ""
                    if snap is not None and not isinstance(e, NotValid):  # NotValid names the region already
                        st = snap.levels[level]
                        where = (f"; the level publishes [{st.valid[0]}, {st.valid[2]}) x [{st.valid[1]}, {st.valid[3]})"
                                 f"{'' if st.enabled else ' (disabled)'}")
                    raise Refused(f"--dump level {level} region [{s0}, {s1}) x [{t0}, {t1}): {e}{where}") from None
                time.sleep(0.01)
        if out.endswith(".png"):
            write_png(out, data, s1 - s0, t1 - t0, tm.format)
        else:
            with open(out, "wb") as f:
                f.write(data)
    except Removed as e:
        print(f"clipmap_shm: {argv[1]}: {e}", file=sys.stderr)
        return 3
    except (ClipmapError, OSError, ValueError) as e:
        print(f"clipmap_shm: {argv[1]}: {e}", file=sys.stderr)
        return 2
    print("level %d region %d %d %d %d bytes %d tick %d" % (level, s0, t0, s1, t1, len(data), snap.tick))
    return 0


def _view_line(v):
    """A view's line of --views and --snapshot (the C reader prints the same)."""
    if v.record is None:
        return f"view {v.name} primary"
    return "view %s record %d incarnation %d weight %.17g%s" % (v.name, v.record, v.incarnation, v.weight,
                                                               " own" if v.own else "")


def main(argv):
    # --view NAME, anywhere after MAPPING: taken out of argv, which then reads as before.
    view_name, rest, i = "main", [], 0
    while i < len(argv):
        if i > 0 and argv[i] == "--view":
            if i + 1 >= len(argv):
                print(f"usage: {argv[0]} MAPPING READS [SEED [SECONDS]] [--view NAME]: --view needs a name",
                      file=sys.stderr)
                return 2
            view_name = argv[i + 1]
            i += 2
            continue
        rest.append(argv[i])
        i += 1
    argv = rest
    if len(argv) == 3 and argv[2] == "--views":
        # python3 clipmap_shm.py MAPPING --views: "view main primary", then "view NAME record R
        # incarnation I weight W" per live view record (the C reader's --views prints the same).
        try:
            with Mapping(argv[1]) as m:
                for v in m.views():
                    print(_view_line(v))
        except (ClipmapError, OSError, ValueError) as e:
            print(f"clipmap_shm: {e}", file=sys.stderr)
            return 2
        return 0
    if len(argv) == 3 and argv[2] == "--snapshot":
        # python3 clipmap_shm.py MAPPING --snapshot [--view NAME]: the view's line, "tick T min_lod X
        # centre S T border B", then "level K centre S T region S0 T0 S1 T1 enabled E tick U" per
        # level (the C reader's --snapshot prints the same).
        try:
            with Mapping(argv[1]) as m:
                v = m.view(view_name)
                snap = v.snapshot()
                print(_view_line(v))
                print("tick %d min_lod %.17g centre %d %d border %d"
                      % (snap.tick, snap.min_lod, snap.centre[0], snap.centre[1], snap.invalid_border))
                for k, st in enumerate(snap.levels):
                    print("level %d centre %d %d region %d %d %d %d enabled %d tick %d"
                          % ((k,) + st.centre + st.valid + (int(st.enabled), st.updated_tick)))
        except Removed as e:
            print(f"clipmap_shm: {argv[1]}: {e}", file=sys.stderr)
            return 3
        except (ClipmapError, OSError, ValueError) as e:
            print(f"clipmap_shm: {argv[1]}: {e}", file=sys.stderr)
            return 2
        return 0
    if len(argv) == 3 and argv[2] == "--request":
        # python3 clipmap_shm.py MAPPING --request: the main request as found, as the C reader's
        # --request prints it: "request count N centre S T kind K[ position X Y]".
        try:
            q = read_request(argv[1][:-4] + ".req" if argv[1].endswith(".map") else argv[1] + ".req")
        except (ClipmapError, OSError) as e:
            print(f"clipmap_shm: {argv[1]}: {e}", file=sys.stderr)
            return 1
        line = "request count %d centre %d %d kind %s" % (q["count"], q["centre"][0], q["centre"][1], q["kind"])
        if q["position"] is not None:
            line += " position %.17g %.17g" % (q["position"][0], q["position"][1])
        print(line)
        return 0
    if len(argv) == 3 and argv[2] == "--georef":
        # python3 clipmap_shm.py MAPPING --georef: the georef block (the C reader's --georef
        # prints the same): "not georeferenced", or "georef epsg CODE|none wraps 0|1 origin X Y",
        # a line "level K A B D E" per level (GDAL terms [1], [2], [4], [5]) and "definition TEXT"
        # (numbers as %.17g).
        try:
            m = Mapping(argv[1])
        except (ClipmapError, OSError, ValueError) as e:
            print(f"clipmap_shm: {e}", file=sys.stderr)
            return 2
        g = m.georef
        if g is None:
            print("not georeferenced")
        else:
            print("georef epsg %s wraps %d origin %.17g %.17g"
                  % ("none" if g["epsg"] is None else g["epsg"], g["wraps"], g["origin"][0], g["origin"][1]))
            for k, t in enumerate(g["levels"]):
                print("level %d %.17g %.17g %.17g %.17g" % ((k,) + tuple(t)))
            sys.stdout.flush()
            sys.stdout.buffer.write(("definition " + g["definition"] + "\n").encode("utf-8"))
            sys.stdout.buffer.flush()
        m.close()
        return 0
    if len(argv) == 6 and argv[2] == "--map-of-texel":
        # python3 clipmap_shm.py MAPPING --map-of-texel LEVEL S T: the map coordinates of the
        # continuous texel position (S, T) of LEVEL, one line "X Y" (%.17g; the C reader's
        # --map-of-texel prints the same), or "not georeferenced".
        try:
            m = Mapping(argv[1])
            level, s, t = int(argv[3]), float(argv[4]), float(argv[5])
        except (ClipmapError, OSError, ValueError) as e:
            print(f"clipmap_shm: {e}", file=sys.stderr)
            return 2
        if not 0 <= level < len(m.levels):
            print(f"clipmap_shm: {argv[1]}: no level {level} (the mapping has {len(m.levels)})", file=sys.stderr)
            m.close()
            return 2
        xy = m.map_of_texel(level, s, t)
        print("not georeferenced" if xy is None else "%.17g %.17g" % xy)
        m.close()
        return 0
    if len(argv) == 3 and argv[2] == "--heights":
        # python3 clipmap_shm.py MAPPING --heights: the heights block, one line (the C reader's
        # --heights prints the same): "not heights", or "heights STORAGE scale S offset O
        # nodata N|none levels RULE" (numbers as %.17g).
        try:
            m = Mapping(argv[1])
        except (ClipmapError, OSError, ValueError) as e:
            print(f"clipmap_shm: {e}", file=sys.stderr)
            return 2
        h = m.heights
        if h is None:
            print("not heights")
        else:
            nodata = "none" if h["nodata"] is None else "%.17g" % h["nodata"]
            print("heights %s scale %.17g offset %.17g nodata %s levels %s"
                  % (h["storage"], h["scale"], h["offset"], nodata, h["levels"]))
        m.close()
        return 0
    if len(argv) == 3 and argv[2] in ("--ranges", "--heights-region"):
        # python3 clipmap_shm.py MAPPING --ranges: the published range of every tile held ready
        # or default, one line each: "LEVEL S T MIN MAX" (metres as %.17g; nan nan: all nodata).
        # --heights-region: every level's published region in metres, per level a line "level L
        # region S0 T0 S1 T1" and then one line per row of the region (increasing t), each
        # texel's metres as %.17g or "nodata". The C reader's options print the same.
        try:
            service = Mapping(argv[1])
            view = service.view(view_name)
            m = view.texels()  # a view with grids of its own: its own mapping
            if m.heights is None:
                raise Refused(f"{argv[1]}: the texels are not heights (heights block all zero)")
            if argv[2] == "--ranges":
                for k, d in enumerate(m.levels):
                    for slot in range(d.slot_count):
                        tag = (d.tags + slot * TAG_BYTES) // 8
                        S, T = _signed(m.q[tag + 1]), _signed(m.q[tag + 2])
                        r = m.tile_range(k, S, T)
                        if r is not None:
                            print("%d %d %d %.17g %.17g" % (k, S, T, r[0], r[1]))
            else:
                snap = view.snapshot()
                for k, st in enumerate(snap.levels):
                    if not st.enabled:
                        continue
                    s0, t0, s1, t1 = st.valid
                    got = m.read_region(k, s0, t0, s1 - s0, t1 - t0, snap)
                    print("level %d region %d %d %d %d" % (k, s0, t0, s1, t1))
                    b, w = m.bpt, s1 - s0
                    for row in range(t1 - t0):
                        hs = (m.metres(got[(row * w + i) * b:(row * w + i + 1) * b]) for i in range(w))
                        print(" ".join("nodata" if v is None else "%.17g" % v for v in hs))
        except Removed as e:
            print(f"clipmap_shm: {argv[1]}: {e}", file=sys.stderr)
            return 3
        except (ClipmapError, OSError, ValueError) as e:
            print(f"clipmap_shm: {e}", file=sys.stderr)
            return 2
        service.close()
        return 0
    if len(argv) >= 3 and argv[2] == "--dump":
        return dump(argv, view_name)
    if len(argv) == 3 and argv[2] == "--growth":
        # python3 clipmap_shm.py MAPPING --growth: the growth block as JSON (null: not growing).
        import json
        try:
            m = Mapping(argv[1])
            print(json.dumps(m.growth(), sort_keys=True))
        except (ClipmapError, OSError, ValueError) as e:
            print(f"clipmap_shm: {e}", file=sys.stderr)
            return 2
        return 0
    if len(argv) < 3:
        print(f"usage: {argv[0]} MAPPING READS [SEED [SECONDS]] [--view NAME]", file=sys.stderr)
        return 2
    try:
        reads = int(argv[2])
        rng = [(int(argv[3]) if len(argv) > 3 else 1) & M64]
        seconds = float(argv[4]) if len(argv) > 4 else 120.0
    except ValueError as e:
        print(f"usage: {argv[0]} MAPPING READS [SEED [SECONDS]] [--view NAME]: {e}", file=sys.stderr)
        return 2
    try:
        m = Mapping(argv[1])
    except (ClipmapError, OSError, ValueError) as e:
        print(f"clipmap_shm: {e}", file=sys.stderr)
        return 2
    try:
        view = m.view(view_name)
    except ClipmapError as e:
        print(f"clipmap_shm: {argv[1]}: {e}", file=sys.stderr)
        m.close()
        return 2
    tm = view.mapping  # the texels the view reads: a view with grids of its own, its own mapping's
    if tm.format in BLOCK_FORMATS:
        print(f"clipmap_shm: {argv[1]}: texel format {FORMATS[tm.format][0]} is block-compressed: its texels have no "
              f"address of their own; read whole tiles (Mapping.read_tile, decode_tile)", file=sys.stderr)
        m.close()
        return 2
    give_up = time.monotonic() + seconds
    passed = failed = busy = stale = missing = moved = idle = blocks = crossing = 0
    bpt = tm.bpt
    snap = None
    removed = False
    it = 0
    while passed + failed < reads and time.monotonic() < give_up:
        it += 1
        if snap is None or it % 256 == 0:
            try:
                snap = view.snapshot()
            except Removed as e:
                print(f"clipmap_shm: {argv[1]}: {e}", file=sys.stderr)
                removed = True
                break
            except Busy:
                busy += 1
                if snap is None:
                    continue
            except Corrupt as e:
                print(f"clipmap_shm: {argv[1]}: {e}", file=sys.stderr)
                m.close()
                return 2
        rng[0] = splitmix64(rng[0])
        level = rng[0] % tm.count
        st = snap.levels[level]
        if not st.enabled:
            idle += 1
            continue
        d = tm.levels[level]
        rng[0] = splitmix64(rng[0])
        mode = rng[0] % 3
        v = st.valid
        s0, w = _pick(rng, mode, v[0], v[2], d.tile[0])
        t0, h = _pick(rng, mode, v[1], v[3], d.tile[1])
        try:
            got = tm.read_region(level, s0, t0, w, h, snap)
        except ReadError as e:
            if isinstance(e, Missing):
                missing += 1
            elif isinstance(e, Busy):
                busy += 1
            elif isinstance(e, Stale):
                stale += 1
            else:
                moved += 1
            snap = None
            continue
        blocks += 1
        if s0 // d.tile[0] != (s0 + w - 1) // d.tile[0] or t0 // d.tile[1] != (t0 + h - 1) // d.tile[1]:
            crossing += 1
        i = 0
        for t in range(t0, t0 + h):
            for s in range(s0, s0 + w):
                # A wrapping texture's region may run past the width: texel s is texel s mod width.
                if got[i:i + bpt] == hash_texel(level, s % d.size[0] if tm.wraps else s, t, bpt):
                    passed += 1
                else:
                    if failed == 0:
                        print(f"clipmap_shm: level {level} texel ({s}, {t}) differs", file=sys.stderr)
                    failed += 1
                i += bpt
    print(f"{passed} passed, {failed} failed ({blocks} blocks, {crossing} across tiles; skipped: {busy} busy, "
          f"{stale} stale, {missing} missing, {moved} moved, {idle} disabled; heartbeat age {tm.heartbeat_age_ms()} ms; "
          f"view {view.name})")
    m.close()
    return 1 if failed else 3 if removed else 0


if sys.byteorder != "little":  # the layout is little-endian; native loads are used for atomics
    raise ImportError("clipmap_shm reads the little-endian clipmap layout on little-endian hosts only")

if __name__ == "__main__":
    sys.exit(main(sys.argv))
