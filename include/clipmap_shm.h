/* clipmap_shm.h: read a clip texture published by clipmapd in shared memory.
 *
 * Layout version 2, documented in docs/SHM.md; this header follows that page alone. Header-only,
 * C99/C11 plus the GCC/Clang __atomic builtins, POSIX mmap, 64-bit little-endian hosts.
 *
 * Use:
 *   struct clipmap_map m;
 *   if (clipmap_open(path, &m) != 0) { fprintf(stderr, "%s\n", m.error); ... }
 *   struct clipmap_snapshot snap;
 *   int rc = clipmap_snapshot(&m, &snap);         // CLIPMAP_OK, _BUSY or _CORRUPT (snap.error)
 *   if (rc == CLIPMAP_OK && snap.levels[k].enabled) {
 *       rc = clipmap_read_region(&m, &snap, k, s0, t0, w, h, buf);   // buf: w * h * bpt bytes
 *       // CLIPMAP_OK: a consistent copy. _NOT_VALID: outside the level's published region.
 *       // _MISSING: a tile could not be read (use a coarser level). _STALE: take a new snapshot.
 *       // _BUSY: the writer kept a tag locked (try again later or use a coarser level).
 *   }
 *   clipmap_close(&m);
 *
 * A block-compressed mapping (m.block == 4: BC1, BC4, BC5, BC7; docs/SHM.md, "Block-compressed
 * formats") is read in whole tiles, its blocks as the GPU takes them; clipmap_read_region refuses it
 * (CLIPMAP_BLOCKS):
 *   rc = clipmap_read_tile(&m, k, S, T, buf);     // buf: m.levels[k].slot_bytes bytes, the tile's
 *                                                 // blocks[0] x blocks[1] blocks (codes as above)
 *   rc = clipmap_decode_blocks(m.texel_format, buf, m.levels[k].slot_bytes, m.levels[k].tile[0],
 *                              m.levels[k].tile[1], texels);  // BC1, BC4, BC5, BC7 for checks
 *
 * A renderer asks for a centre through the request mapping: clipmap_request_open(req_path, &m,
 * &r), then clipmap_request_centre(&r, s, t, vs, vt).
 *
 * Views (docs/SHM.md, "Views"): a mapping may publish further views beside the primary one,
 * `main` (the snapshot above), each with its own snapshot over the same slots:
 *   struct clipmap_view v;
 *   rc = clipmap_view_find(&m, "north", &v);     // CLIPMAP_OK, _NO_VIEW (v.error lists the views),
 *                                                 // _BUSY or _CORRUPT ("main" is always found)
 *   rc = clipmap_view_snapshot(&m, &v, &snap);    // as clipmap_snapshot, or CLIPMAP_REMOVED: the
 *                                                 // view was removed since it was found
 *   rc = clipmap_read_region(&m, &snap, k, ...);  // texels under the view's snapshot, as above
 *   rc = clipmap_request_view_centre(&r, &v, s, t, vs, vt);
 * clipmap_views(&m, &list) lists the views that exist.
 *
 * A view with grids of its own (views block version 2, docs/SHM.md "A view with grids of its
 * own"): clipmap_view_find sets v.own, and the view's texels, snapshot and requests are those of
 * `main` of another mapping of the service, DIR/clipmap-NAME@VIEW.map. m must have been opened
 * under the service's own name, DIR/clipmap-NAME.map. Open that mapping and read it as any `main`:
 *   struct clipmap_map own;
 *   if (v.own) {
 *       if (clipmap_view_open_own(&m, &v, &own) != 0) { fprintf(stderr, "%s\n", own.error); ... }
 *       rc = clipmap_view_own_snapshot(&m, &v, &own, &snap); // own's `main` snapshot, or _REMOVED
 *       rc = clipmap_read_region(&own, &snap, k, ...);       // texels of own, as for any `main`
 *       char req[4096];                                      // its requests: the own mapping's
 *       if (clipmap_request_path(&own, req, sizeof req) == 0 && clipmap_request_open(req, &own, &r) == 0)
 *           rc = clipmap_request_centre(&r, s, t, vs, vt);
 *       clipmap_close(&own);
 *   }
 * (clipmap_view_snapshot and the view request functions refuse such a view: CLIPMAP_NOT_VALID.)
 *
 * Every value read from the mapping is checked before it is used in address arithmetic, so a
 * corrupt or hostile mapping gives an error, never an out-of-bounds access. (A file truncated
 * after it was mapped still raises SIGBUS on access, as with any mmap.)
 */
#ifndef CLIPMAP_SHM_H
#define CLIPMAP_SHM_H

/* POSIX names (clock_gettime, O_CLOEXEC) under a strict -std=c99/c11; only effective when this
 * header comes before any system header. */
#if !defined(_POSIX_C_SOURCE) && !defined(_GNU_SOURCE) && !defined(_DEFAULT_SOURCE)
#define _POSIX_C_SOURCE 200809L
#endif

#include <errno.h>
#include <fcntl.h>
#include <float.h>
#include <math.h>
#include <sched.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "the clipmap shared-memory layout is little-endian"
#endif
#if defined(__SIZEOF_POINTER__) && __SIZEOF_POINTER__ < 8
#error "clipmap_shm.h needs a 64-bit host (64-bit atomic loads, 64-bit offsets)"
#endif

#define CLIPMAP_MAGIC "CLIPMAP2"
#define CLIPMAP_REQUEST_MAGIC "CLIPREQ2"
#define CLIPMAP_VERSION 2u
#define CLIPMAP_PAGE 4096u
#define CLIPMAP_MAX_LEVELS 32u
#define CLIPMAP_MAX_RETRIES 64           /* attempts at one seqlocked read (snapshot or tag) */
#define CLIPMAP_REQUEST_BYTES 4096u      /* size of the request mapping */

/* Texel mapping header (byte offsets from the start of the mapping). */
#define CLIPMAP_H_MAGIC 0                /* u8[8] "CLIPMAP2" */
#define CLIPMAP_H_VERSION 8              /* u32: 2 */
#define CLIPMAP_H_HEADER_BYTES 12        /* u32: offset of level 0's tags (multiple of 4096) */
#define CLIPMAP_H_TOTAL_BYTES 16         /* u64: size of the mapping (= the file size) */
#define CLIPMAP_H_TEXEL_FORMAT 24        /* u32: CLIPMAP_FORMAT_* */
#define CLIPMAP_H_BYTES_PER_TEXEL 28     /* u32: 1..64 */
#define CLIPMAP_H_CLIP_SIZE 32           /* u32 */
#define CLIPMAP_H_LEVEL_COUNT 36         /* u32: 1..32 */
#define CLIPMAP_H_LEVEL0_S 40            /* u64: level-0 width */
#define CLIPMAP_H_LEVEL0_T 48            /* u64: level-0 height */
#define CLIPMAP_H_WRITER_PID 56          /* u32 */
#define CLIPMAP_H_HEARTBEAT 64           /* u64 atomic: incremented every tick */
#define CLIPMAP_H_HEARTBEAT_MS 72        /* u64 atomic: ms since the Unix epoch of the last tick */
#define CLIPMAP_H_GENERATION 80          /* u64: unique to each start of the writer */
#define CLIPMAP_H_FLAGS 88               /* u64 atomic: bit 0 clean shutdown */
#define CLIPMAP_H_TICK_PERIOD_NS 96      /* u64 */
#define CLIPMAP_H_VIEWS_OFFSET 104       /* u64: the views block (multiple of 4096, after every level's slots); 0: none */
#define CLIPMAP_H_SNAPSHOT 128           /* the snapshot, 2112 bytes */
#define CLIPMAP_H_LEVEL_DESCS 2240       /* 32 level descriptors of CLIPMAP_DESC_BYTES */
#define CLIPMAP_H_GROWTH 6336            /* the growth block, CLIPMAP_GROWTH_BYTES (growing textures) */
#define CLIPMAP_H_HEIGHTS 6464           /* the heights block, CLIPMAP_HEIGHTS_BYTES (static; all zero: not heights) */
#define CLIPMAP_H_GEOREF 6528            /* the georef block, CLIPMAP_GEOREF_BYTES (static; all zero: no georeferencing) */
#define CLIPMAP_H_END 7616               /* end of the fixed header */
/* Snapshot fields as absolute offsets (the names layout 1 gave them). */
#define CLIPMAP_H_GLOBAL_SEQ 128         /* = CLIPMAP_H_SNAPSHOT + CLIPMAP_SNAP_SEQ */
#define CLIPMAP_H_MIN_LOD 136            /* = CLIPMAP_H_SNAPSHOT + CLIPMAP_SNAP_MIN_LOD */
#define CLIPMAP_H_TICK 144               /* = CLIPMAP_H_SNAPSHOT + CLIPMAP_SNAP_TICK */
#define CLIPMAP_H_LEVEL_STATES 192       /* = CLIPMAP_H_SNAPSHOT + CLIPMAP_SNAP_LEVELS */

/* Snapshot fields (relative to CLIPMAP_H_SNAPSHOT), all u64-sized and atomic, one seqlock. */
#define CLIPMAP_SNAP_SEQ 0               /* u64: odd while the writer changes the snapshot */
#define CLIPMAP_SNAP_MIN_LOD 8           /* f64 bits */
#define CLIPMAP_SNAP_TICK 16             /* u64: 0 before the first publication */
#define CLIPMAP_SNAP_INVALID_BORDER 24   /* u64 */
#define CLIPMAP_SNAP_CENTRE_S 32         /* i64: level-0 centre applied by that tick */
#define CLIPMAP_SNAP_CENTRE_T 40         /* i64 */
#define CLIPMAP_SNAP_LEVELS 64           /* level states, CLIPMAP_STATE_BYTES each */
#define CLIPMAP_SNAPSHOT_BYTES 2112

/* Level state fields (relative to the state). */
#define CLIPMAP_STATE_BYTES 64
#define CLIPMAP_S_CENTRE_S 0             /* i64: level centre, level texels */
#define CLIPMAP_S_CENTRE_T 8             /* i64 */
#define CLIPMAP_S_VALID_S0 16            /* i64: valid region s0 <= s < s1, t0 <= t < t1 */
#define CLIPMAP_S_VALID_T0 24            /* i64 */
#define CLIPMAP_S_VALID_S1 32            /* i64 */
#define CLIPMAP_S_VALID_T1 40            /* i64 */
#define CLIPMAP_S_ENABLED 48             /* u64: 1 usable (region non-empty), 0 not */
#define CLIPMAP_S_UPDATED_TICK 56        /* u64 */

/* Level descriptor fields (relative to the descriptor), static u64s. */
#define CLIPMAP_DESC_BYTES 128
#define CLIPMAP_D_SIZE_S 0               /* level width: level 0's halved k times, at least 1 */
#define CLIPMAP_D_SIZE_T 8               /* level height */
#define CLIPMAP_D_TILE_S 16              /* tile width TW */
#define CLIPMAP_D_TILE_T 24              /* tile height TH */
#define CLIPMAP_D_GRID_S 32              /* grid width GW (slots per row) */
#define CLIPMAP_D_GRID_T 40              /* grid height GH */
#define CLIPMAP_D_SLOT_BYTES 48          /* TW * TH * bytes per texel */
#define CLIPMAP_D_TAGS_OFFSET 56         /* multiple of 4096 */
#define CLIPMAP_D_SLOTS_OFFSET 64        /* multiple of 4096 */
#define CLIPMAP_D_KIND 72                /* 0 stack, 1 pyramid */
#define CLIPMAP_D_RANGES_OFFSET 80       /* multiple of 4096 between tags and slots; 0: not heights */
#define CLIPMAP_D_GEOREF 88              /* f64 x 4: the level's GDAL geotransform [1], [2], [4], [5]; 0: none */

/* Tile range entries (heights only): one per slot at ranges_offset + CLIPMAP_RANGE_BYTES * slot,
 * f64 bits stored atomically, read under the slot's tag like texels (clipmap_tile_range). */
#define CLIPMAP_RANGE_BYTES 16
#define CLIPMAP_R_MIN 0                  /* f64 bits: least height in metres, nodata excluded (NaN: all nodata) */
#define CLIPMAP_R_MAX 8                  /* f64 bits: greatest height in metres (NaN: all nodata) */

/* Growth block fields (relative to CLIPMAP_H_GROWTH), all u64-sized and atomic, one seqlock.
 * All zero for a texture that does not grow. A growing texture is served in a fixed frame, so
 * addresses never move as it grows: read this block again (no reattaching) to follow it. */
#define CLIPMAP_GROWTH_BYTES 128
#define CLIPMAP_G_SEQ 0                  /* u64: odd while the writer changes the block */
#define CLIPMAP_G_GROWING 8              /* u64: 1 for a growing texture, else 0 */
#define CLIPMAP_G_EXTENT_S0 16           /* i64: data extent, level-0 texels: s0 <= s < s1 */
#define CLIPMAP_G_EXTENT_T0 24           /* i64: t0 <= t < t1 (all 0: no data yet) */
#define CLIPMAP_G_EXTENT_S1 32           /* i64 */
#define CLIPMAP_G_EXTENT_T1 40           /* i64 */
#define CLIPMAP_G_DATA_LEVELS 48         /* u64: levels the data has grown */
#define CLIPMAP_G_PATCHES 56             /* u64: patches accepted */
#define CLIPMAP_G_TILES_REBUILT 64       /* u64 */
#define CLIPMAP_G_TILES_PENDING 72       /* u64 */
#define CLIPMAP_G_TILES_REPLACED 80      /* u64: rebuilt tiles replaced in their slots */
#define CLIPMAP_G_WORLD_S0 88            /* f64 bits: world x of level-0 texel (0, 0)'s lower-left corner */
#define CLIPMAP_G_WORLD_T0 96            /* f64 bits: world y of it */
#define CLIPMAP_G_TEXELS_PER_UNIT 104    /* f64 bits: level-0 texels per world unit */
#define CLIPMAP_G_OUTSIDE_FRAME 112      /* u64: patches lying (partly) outside the frame */

/* Slot tag fields (relative to the tag at tags_offset + CLIPMAP_TAG_BYTES * slot), atomic. */
#define CLIPMAP_TAG_BYTES 32
#define CLIPMAP_T_SEQ 0                  /* u64: odd while the writer changes the tag */
#define CLIPMAP_T_TILE_S 8               /* i64: tile S the slot holds */
#define CLIPMAP_T_TILE_T 16              /* i64: tile T */
#define CLIPMAP_T_STATE 24               /* u64: CLIPMAP_SLOT_* */

/* Slot states (CLIPMAP_T_STATE). */
#define CLIPMAP_SLOT_EMPTY 0u
#define CLIPMAP_SLOT_LOADING 1u
#define CLIPMAP_SLOT_READY 2u
#define CLIPMAP_SLOT_MISSING 3u
#define CLIPMAP_SLOT_DEFAULT 4u

/* Request mapping fields (DIR/clipmap-NAME.req, CLIPMAP_REQUEST_BYTES bytes). */
#define CLIPMAP_R_MAGIC 0                /* u8[8] "CLIPREQ2" */
#define CLIPMAP_R_VERSION 8              /* u32: 2 */
#define CLIPMAP_R_GENERATION 16          /* u64: equals CLIPMAP_H_GENERATION of its texel mapping */
#define CLIPMAP_R_SEQ 64                 /* u64 atomic lock word (renderers take it by CAS; odd: holder pid in bits 1..31) */
#define CLIPMAP_R_CENTRE_S 72            /* i64: requested level-0 centre */
#define CLIPMAP_R_CENTRE_T 80            /* i64 */
#define CLIPMAP_R_VEL_S 88               /* f64 bits: level-0 texels per second */
#define CLIPMAP_R_VEL_T 96               /* f64 bits */
#define CLIPMAP_R_CLIENT_PID 104         /* u64 */
#define CLIPMAP_R_COUNT 112              /* u64: requests made */
#define CLIPMAP_R_VIEWS 512              /* view request record r at CLIPMAP_R_VIEWS + CLIPMAP_VIEW_REQUEST_BYTES * r */

/* Views (docs/SHM.md, "Views"). The primary view, `main`, is the snapshot at CLIPMAP_H_SNAPSHOT;
 * further views are view records of the views block at CLIPMAP_H_VIEWS_OFFSET (0: no block). */
#define CLIPMAP_VIEWS_MAGIC "CLIPVIEW"
#define CLIPMAP_VIEWS_VERSION 2u         /* the views block version of this header; it reads versions 1 and 2 */
#define CLIPMAP_VIEWS_VERSION_MIN 1u     /* the oldest views block version it reads (no record in state 2) */
#define CLIPMAP_MAX_VIEWS 64u            /* view records N: 1..64 */
#define CLIPMAP_VIEW_RECORD_BYTES 2240u
#define CLIPMAP_VIEW_NAME_BYTES 32u      /* u8[32], NUL-padded: 1..31 of A-Z a-z 0-9 - _ . (never "main") */
#define CLIPMAP_VIEW_NAME_MAX 31u
#define CLIPMAP_VIEW_MAIN 0xFFFFFFFFu    /* struct clipmap_view's record for the primary view */
#define CLIPMAP_NAME_MAX 64u             /* a service's name: 1..64 of A-Z a-z 0-9 - _ . (DIR/clipmap-NAME.map) */
#define CLIPMAP_OWN_SEPARATOR "@"        /* a view's own grids: DIR/clipmap-NAME@VIEW.map (and .req) */
/* Views block fields (relative to the block), static. */
#define CLIPMAP_VB_MAGIC 0               /* u8[8] "CLIPVIEW" */
#define CLIPMAP_VB_VERSION 8             /* u32: 1 or 2 (2: records may be in state CLIPMAP_VIEW_OWN) */
#define CLIPMAP_VB_RECORD_COUNT 12       /* u32: view records N, 1..64 */
#define CLIPMAP_VB_RECORD_BYTES 16       /* u32: 2240 */
#define CLIPMAP_VB_RECORDS 64            /* record r at CLIPMAP_VB_RECORDS + CLIPMAP_VIEW_RECORD_BYTES * r */
/* View record fields (relative to the record), atomic; 0..128 under the record's seqlock. */
#define CLIPMAP_V_SEQ 0                  /* u64: odd while the writer gives the record to a view or takes it back */
#define CLIPMAP_V_STATE 8                /* u64: CLIPMAP_VIEW_FREE, _LIVE or (version 2) _OWN */
#define CLIPMAP_V_INCARNATION 16         /* u64: incremented each time the record is given to a view */
#define CLIPMAP_V_WEIGHT 24              /* f64 bits: positive, finite */
#define CLIPMAP_V_NAME 64                /* u8[32] name, read as four u64 words */
#define CLIPMAP_V_SNAPSHOT 128           /* the view's snapshot, CLIPMAP_SNAPSHOT_BYTES, laid out as CLIPMAP_H_SNAPSHOT's */
#define CLIPMAP_VIEW_FREE 0u
#define CLIPMAP_VIEW_LIVE 1u
#define CLIPMAP_VIEW_OWN 2u              /* live, with grids of its own (version 2): name, weight and incarnation
                                            mean something, the record's snapshot is unused */
/* View request records (relative to CLIPMAP_R_VIEWS + CLIPMAP_VIEW_REQUEST_BYTES * r, r < 24): the
 * main request's fields at the same distances from their lock word, and the view's incarnation. */
#define CLIPMAP_VIEW_REQUEST_BYTES 64u
#define CLIPMAP_MAX_VIEW_REQUESTS 24u    /* request records for view records 0..23 (the LOD records follow) */
#define CLIPMAP_VR_SEQ 0                 /* u64 atomic lock word (as CLIPMAP_R_SEQ) */
#define CLIPMAP_VR_CENTRE_S 8            /* i64: requested level-0 centre */
#define CLIPMAP_VR_CENTRE_T 16           /* i64 */
#define CLIPMAP_VR_VEL_S 24              /* f64 bits: level-0 texels per second */
#define CLIPMAP_VR_VEL_T 32              /* f64 bits */
#define CLIPMAP_VR_CLIENT_PID 40         /* u64 */
#define CLIPMAP_VR_COUNT 48              /* u64: requests made */
#define CLIPMAP_VR_INCARNATION 56        /* u64: the incarnation of the view the request is for */
/* LOD request records (docs/SHM.md, "Asking for a view's levels"): record i at CLIPMAP_R_LOD +
 * CLIPMAP_LOD_RECORD_BYTES * i, i = 0 for `main` (under CLIPMAP_R_SEQ), 1 + r for view record r
 * (under its request record's lock word). */
#define CLIPMAP_R_LOD 2048
#define CLIPMAP_LOD_RECORD_BYTES 32u
#define CLIPMAP_LOD_HEIGHT 0             /* f64 bits: height above the texture, level-0 texels (0: none) */
#define CLIPMAP_LOD_PIXEL_ANGLE 8        /* f64 bits: radians one screen pixel spans */
#define CLIPMAP_LOD_EFFECTIVE 16         /* u64: levels the renderer addresses at once (0: all) */
#define CLIPMAP_LOD_COUNT 24             /* u64: LOD requests made */
/* Position records (docs/SHM.md, "Positions in longitude / latitude or map coordinates"): record i
 * at CLIPMAP_R_POSITION + CLIPMAP_POSITION_RECORD_BYTES * i, i = 0 for `main`, 1 + r for view record
 * r, under the same lock word as its request. A request's centre is the record's position when
 * CLIPMAP_POS_FOR_COUNT equals the request's count (CLIPMAP_VR_COUNT) and the kind is not texels;
 * else the request's texel centre (an older renderer writes no record: its requests are texels). */
#define CLIPMAP_R_POSITION 3072
#define CLIPMAP_POSITION_RECORD_BYTES 32u
#define CLIPMAP_POS_KIND 0               /* u64: CLIPMAP_KIND_* */
#define CLIPMAP_POS_X 8                  /* f64 bits: longitude (degrees) or map x */
#define CLIPMAP_POS_Y 16                 /* f64 bits: latitude (degrees) or map y */
#define CLIPMAP_POS_FOR_COUNT 24         /* u64: the request count the position belongs to */
#define CLIPMAP_KIND_TEXELS 0u           /* the request's CLIPMAP_VR_CENTRE_S / _T, level-0 texels */
#define CLIPMAP_KIND_LONLAT 1u           /* WGS 84 longitude / latitude, degrees */
#define CLIPMAP_KIND_MAP 2u              /* map coordinates of the texture's CRS (the georef block's) */

/* Texel format codes (CLIPMAP_H_TEXEL_FORMAT); 16-bit components are little-endian. */
#define CLIPMAP_FORMAT_OTHER 0u
#define CLIPMAP_FORMAT_L8 1u
#define CLIPMAP_FORMAT_RGB8 3u
#define CLIPMAP_FORMAT_RGBA8 4u
#define CLIPMAP_FORMAT_RGB565 5u
#define CLIPMAP_FORMAT_RGBA5551 6u
#define CLIPMAP_FORMAT_L16 7u
#define CLIPMAP_FORMAT_LA16 8u
#define CLIPMAP_FORMAT_RGB16 9u
#define CLIPMAP_FORMAT_RGBA16 10u
/* One IEEE 754 32-bit float, and one signed 16-bit integer, little-endian (heights: docs/ELEVATION.md). */
#define CLIPMAP_FORMAT_L32F 11u
#define CLIPMAP_FORMAT_L16I 12u
/* Block-compressed (docs/SHM.md, "Block-compressed formats"): slots hold the tile's 4 x 4 blocks,
 * the header's bytes per texel are the bytes of one block; read them whole (clipmap_read_tile) and
 * decode them for a check (clipmap_decode_blocks: BC1, BC4, BC5 and BC7). */
#define CLIPMAP_FORMAT_BC1 20u           /* RGB, 8 bytes a block (Direct3D BC1_UNORM) */
#define CLIPMAP_FORMAT_BC4 21u           /* one channel, 8 bytes a block (BC4_UNORM) */
#define CLIPMAP_FORMAT_BC5 22u           /* two channels, 16 bytes a block (BC5_UNORM) */
#define CLIPMAP_FORMAT_BC7 23u           /* RGBA, 16 bytes a block (BC7_UNORM) */

/* Heights block fields (relative to CLIPMAP_H_HEIGHTS), static. All zero for a texture whose
 * texels are not heights (a colour texture, or a writer from before the block). clipmap_open
 * checks them and fills struct clipmap_map's height_* fields. */
#define CLIPMAP_HEIGHTS_BYTES 64
#define CLIPMAP_HT_IS_HEIGHTS 0          /* u32: 1 the texels are heights, 0 not */
#define CLIPMAP_HT_RULE 4                /* u32: CLIPMAP_RULE_* */
#define CLIPMAP_HT_SCALE 8               /* f64: metres of one stored step (1 for l32f) */
#define CLIPMAP_HT_OFFSET 16             /* f64: metres of a stored 0 (0 for l32f) */
#define CLIPMAP_HT_NODATA 24             /* f64: the stored value (not metres) marking no data; NaN: none */
/* Level rules (CLIPMAP_HT_RULE): how each coarser level of heights is made from the finer one. */
#define CLIPMAP_RULE_MEAN 0u
#define CLIPMAP_RULE_POINT 1u
#define CLIPMAP_RULE_MIN 2u
#define CLIPMAP_RULE_MAX 3u
/* Every height a format holds lies within this many metres of zero (10,000 km). */
#define CLIPMAP_HEIGHT_LIMIT_M 1.0e7

/* Georef block fields (relative to CLIPMAP_H_GEOREF), static (docs/SHM.md, "Georef block"). All
 * zero for a texture without georeferencing (or a writer from before the block). Each level's own
 * terms are at CLIPMAP_D_GEOREF of its descriptor. clipmap_open checks them and fills struct
 * clipmap_map's georef_* fields. */
#define CLIPMAP_GR_PRESENT 0             /* u32: 1 georeferenced, 0 not */
#define CLIPMAP_GR_EPSG 4                /* u32: the CRS's EPSG code; 0: none known */
#define CLIPMAP_GR_FLAGS 8               /* u32: CLIPMAP_GR_WRAPS */
#define CLIPMAP_GR_DEFINITION_LEN 12     /* u32: bytes of the definition (at most CLIPMAP_GEOREF_DEFINITION_MAX) */
#define CLIPMAP_GR_ORIGIN_X 16           /* f64: GDAL geotransform [0], map x of the west edge of column 0 */
#define CLIPMAP_GR_ORIGIN_Y 24           /* f64: GDAL geotransform [3], map y of the north edge */
#define CLIPMAP_GR_TERMS 32              /* f64 x 4: level 0's GDAL geotransform [1], [2], [4], [5] */
#define CLIPMAP_GR_DEFINITION 64         /* the CRS definition: UTF-8 (PROJ string or WKT), not NUL-terminated */
#define CLIPMAP_GEOREF_DEFINITION_MAX 1024
#define CLIPMAP_GEOREF_BYTES 1088         /* CLIPMAP_GR_DEFINITION + CLIPMAP_GEOREF_DEFINITION_MAX */
#define CLIPMAP_GR_WRAPS 1u              /* flag: the texture spans 360 degrees of longitude (s wraps) */
#define CLIPMAP_GR_KNOWN_FLAGS 1u        /* every flag this header knows: CLIPMAP_GR_WRAPS */

#if defined(__STDC_VERSION__) && __STDC_VERSION__ >= 201112L
_Static_assert(CLIPMAP_H_GROWTH + CLIPMAP_GROWTH_BYTES == CLIPMAP_H_HEIGHTS, "growth block");
_Static_assert(CLIPMAP_H_HEIGHTS + CLIPMAP_HEIGHTS_BYTES == CLIPMAP_H_GEOREF, "heights block");
_Static_assert(CLIPMAP_H_GEOREF + CLIPMAP_GEOREF_BYTES == CLIPMAP_H_END, "georef block");
_Static_assert(CLIPMAP_GR_DEFINITION + CLIPMAP_GEOREF_DEFINITION_MAX == CLIPMAP_GEOREF_BYTES, "georef definition");
_Static_assert(CLIPMAP_H_SNAPSHOT + CLIPMAP_SNAPSHOT_BYTES == CLIPMAP_H_LEVEL_DESCS, "snapshot size");
_Static_assert(CLIPMAP_SNAP_LEVELS + CLIPMAP_MAX_LEVELS * CLIPMAP_STATE_BYTES == CLIPMAP_SNAPSHOT_BYTES, "states");
_Static_assert(CLIPMAP_H_LEVEL_DESCS + CLIPMAP_MAX_LEVELS * CLIPMAP_DESC_BYTES == CLIPMAP_H_GROWTH, "descs");
_Static_assert(CLIPMAP_H_GLOBAL_SEQ == CLIPMAP_H_SNAPSHOT + CLIPMAP_SNAP_SEQ &&
                   CLIPMAP_H_MIN_LOD == CLIPMAP_H_SNAPSHOT + CLIPMAP_SNAP_MIN_LOD &&
                   CLIPMAP_H_TICK == CLIPMAP_H_SNAPSHOT + CLIPMAP_SNAP_TICK &&
                   CLIPMAP_H_LEVEL_STATES == CLIPMAP_H_SNAPSHOT + CLIPMAP_SNAP_LEVELS,
               "absolute snapshot offsets");
_Static_assert(CLIPMAP_V_SNAPSHOT + CLIPMAP_SNAPSHOT_BYTES == CLIPMAP_VIEW_RECORD_BYTES, "view record size");
_Static_assert(CLIPMAP_R_VIEWS + CLIPMAP_MAX_VIEW_REQUESTS * CLIPMAP_VIEW_REQUEST_BYTES == CLIPMAP_R_LOD,
               "view request records end where the LOD records begin");
_Static_assert(CLIPMAP_R_LOD + (CLIPMAP_MAX_VIEW_REQUESTS + 1) * CLIPMAP_LOD_RECORD_BYTES <= CLIPMAP_R_POSITION,
               "LOD request records");
_Static_assert(CLIPMAP_R_POSITION + (CLIPMAP_MAX_VIEW_REQUESTS + 1) * CLIPMAP_POSITION_RECORD_BYTES <=
                   CLIPMAP_REQUEST_BYTES,
               "position records");
_Static_assert(CLIPMAP_R_SEQ + CLIPMAP_VR_CENTRE_S == CLIPMAP_R_CENTRE_S &&
                   CLIPMAP_R_SEQ + CLIPMAP_VR_CENTRE_T == CLIPMAP_R_CENTRE_T &&
                   CLIPMAP_R_SEQ + CLIPMAP_VR_VEL_S == CLIPMAP_R_VEL_S &&
                   CLIPMAP_R_SEQ + CLIPMAP_VR_VEL_T == CLIPMAP_R_VEL_T &&
                   CLIPMAP_R_SEQ + CLIPMAP_VR_CLIENT_PID == CLIPMAP_R_CLIENT_PID &&
                   CLIPMAP_R_SEQ + CLIPMAP_VR_COUNT == CLIPMAP_R_COUNT,
               "a view request record's fields lie as the main request's");
#endif

/* Return codes of clipmap_snapshot, clipmap_read_region, clipmap_tag_try and the view functions. */
enum {
    CLIPMAP_OK = 0,
    CLIPMAP_NOT_VALID = 1, /* no such level, level disabled, or not inside its published region */
    CLIPMAP_MISSING = 2,   /* a tile of the region could not be read: use a coarser level */
    CLIPMAP_BUSY = 3,      /* CLIPMAP_MAX_RETRIES attempts found the writer mid-change */
    CLIPMAP_STALE = 4,     /* a slot holds another tile (or is loading): take a new snapshot */
    CLIPMAP_CORRUPT = 5,   /* published state outside its bounds */
    CLIPMAP_REMOVED = 6,   /* the view was removed (its record freed or given to another view) */
    CLIPMAP_NO_VIEW = 7,   /* no view of that name (the error lists the views that exist) */
    CLIPMAP_BLOCKS = 8     /* the format is block-compressed: read whole tiles (clipmap_read_tile) */
};

/* One level's static description, checked by clipmap_open. */
struct clipmap_level_desc {
    uint64_t size[2];     /* level size in texels */
    uint64_t tile[2];     /* TW, TH */
    uint64_t grid[2];     /* GW, GH */
    uint64_t slot_bytes;  /* TW * TH * bytes per texel; block formats: blocks[0] * blocks[1] * bytes per block */
    uint64_t blocks[2];   /* a slot's units a row and its rows: ceil(TW / 4), ceil(TH / 4) blocks for a block
                             format (clipmap_map.block 4), TW, TH texels otherwise */
    uint64_t slot_count;  /* GW * GH */
    uint64_t tags_offset; /* byte offset of slot 0's tag */
    uint64_t slots_offset;/* byte offset of slot 0 */
    int pyramid;          /* 1: the grid holds every tile of the level */
    uint64_t ranges_offset;/* byte offset of slot 0's tile range entry (0: none, not heights) */
};

struct clipmap_map {
    const unsigned char *base; /* the read-only mapping */
    size_t len;
    uint32_t bytes_per_texel;  /* for a block format (block 4): the bytes of one 4 x 4 block, 8 or 16 */
    uint32_t block;            /* texels a side of a slot's unit of storage: 1, or 4 for a block format */
    uint32_t clip_size;
    uint32_t level_count;
    uint32_t texel_format;     /* CLIPMAP_FORMAT_* */
    uint32_t writer_pid;
    uint64_t header_bytes;
    uint64_t size[2];          /* level-0 size */
    uint64_t generation;
    uint64_t tick_period_ns;
    int heights;               /* 1: the texels are heights (the height_* fields mean something) */
    uint32_t height_rule;      /* CLIPMAP_RULE_* */
    double height_scale;       /* metres = stored x scale + offset */
    double height_offset;
    int height_has_nodata;     /* 1: height_nodata marks texels without data */
    double height_nodata;      /* a stored value, not metres */
    int georef;                /* 1: georeferenced (the georef_* fields mean something) */
    uint32_t georef_epsg;      /* the CRS's EPSG code; 0: none known */
    int georef_wraps;          /* 1: the texture spans 360 degrees of longitude */
    double georef_origin[2];   /* level 0's GDAL geotransform [0] and [3]: its north-west corner */
    double georef_terms[CLIPMAP_MAX_LEVELS][4]; /* per level GDAL geotransform [1], [2], [4], [5] */
    uint32_t georef_definition_len;             /* bytes of the CRS definition */
    char georef_definition[CLIPMAP_GEOREF_DEFINITION_MAX + 1]; /* UTF-8, NUL-terminated here */
    struct clipmap_level_desc levels[CLIPMAP_MAX_LEVELS];
    uint64_t views_offset;     /* the views block (CLIPMAP_H_VIEWS_OFFSET); 0: none, only `main` */
    uint32_t view_records;     /* its view records N (0: no block, or one of a magic or version not known) */
    uint32_t views_version;    /* the block's version (1 or 2; 0: no usable block) */
    char views_error[320];     /* "": the block is usable (or absent); else why views other than `main`
                                  cannot be read (a magic or version this header does not know) */
    char error[320];           /* why clipmap_open failed */
    uid_t uid;                 /* the file's owner (a view's own mapping must have the same) */
    char path[4096];           /* the path it was opened by (a view's own mapping is found beside it) */
};

/* One level's published state. */
struct clipmap_level_state {
    int64_t centre[2];
    int64_t valid[4]; /* s0, t0, s1, t1: s0 <= s < s1, t0 <= t < t1 */
    int enabled;
    uint64_t updated_tick;
};

/* A consistent copy of the snapshot. */
struct clipmap_snapshot {
    uint64_t seq;            /* the (even) sequence it was read at */
    double min_lod;
    uint64_t tick;           /* 0: nothing published yet */
    uint64_t invalid_border;
    int64_t centre[2];       /* level-0 centre */
    uint32_t level_count;
    struct clipmap_level_state levels[CLIPMAP_MAX_LEVELS];
    char error[200];         /* why clipmap_snapshot last returned CLIPMAP_BUSY or CLIPMAP_CORRUPT */
};

/* A growing texture's growth block (clipmap_growth). */
struct clipmap_growth {
    int growing;            /* 0: the texture does not grow (the rest is zero) */
    int64_t extent[4];      /* s0, t0, s1, t1 of the data, level-0 texels (all 0: none yet) */
    uint64_t data_levels, patches, tiles_rebuilt, tiles_pending, tiles_replaced, outside_frame;
    double world_origin[2]; /* world coordinates of level-0 texel (0, 0)'s lower-left corner */
    double texels_per_unit;
    char error[200];        /* why clipmap_growth returned CLIPMAP_BUSY or CLIPMAP_CORRUPT */
};

/* A view, bound by clipmap_view_find: the primary view `main` (record CLIPMAP_VIEW_MAIN) or the view
 * record `record` while it keeps the incarnation it had when it was found. */
struct clipmap_view {
    char name[CLIPMAP_VIEW_NAME_BYTES];
    uint32_t record;         /* its view record; CLIPMAP_VIEW_MAIN for `main` */
    uint64_t incarnation;    /* the record's incarnation when found (0 for `main`) */
    double weight;           /* the view's weight (0 for `main`: the mapping does not publish it) */
    size_t snapshot_offset;  /* byte offset of its snapshot in the mapping (0 for a view with grids of its own) */
    int own;                 /* 1: the view has grids of its own (record state CLIPMAP_VIEW_OWN): read `main`
                                of the mapping clipmap_view_open_own opens, not this one */
    char error[2400];        /* why clipmap_view_find failed (CLIPMAP_NO_VIEW: with every view's name) */
};

/* The views that exist (clipmap_views): `main` first, then every live record's, in record order. */
struct clipmap_view_info {
    char name[CLIPMAP_VIEW_NAME_BYTES];
    uint32_t record;         /* CLIPMAP_VIEW_MAIN for `main` */
    uint64_t incarnation;
    double weight;
    int own;                 /* 1: grids of its own (see struct clipmap_view) */
};
struct clipmap_view_list {
    uint32_t count;
    struct clipmap_view_info views[1 + CLIPMAP_MAX_VIEWS];
    char error[320];         /* why clipmap_views returned CLIPMAP_BUSY or CLIPMAP_CORRUPT */
};

static inline uint64_t clipmap_splitmix64(uint64_t x) {
    uint64_t z = x + 0x9E3779B97F4A7C15ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/* The verification texture's 64-bit value at (level, s, t); texel byte i is byte i % 8 of it,
 * little-endian. */
static inline uint64_t clipmap_hash_value(uint32_t level, uint64_t s, uint64_t t) {
    return clipmap_splitmix64(((uint64_t)level << 58) | (t << 29) | s);
}

/* Bytes per texel of a known format code; 0 for CLIPMAP_FORMAT_OTHER or an unknown code. */
static inline uint32_t clipmap_format_bytes(uint32_t code) {
    switch (code) {
    case CLIPMAP_FORMAT_L8: return 1;
    case CLIPMAP_FORMAT_RGB8: return 3;
    case CLIPMAP_FORMAT_RGBA8: return 4;
    case CLIPMAP_FORMAT_RGB565: return 2;
    case CLIPMAP_FORMAT_RGBA5551: return 2;
    case CLIPMAP_FORMAT_L16: return 2;
    case CLIPMAP_FORMAT_LA16: return 4;
    case CLIPMAP_FORMAT_RGB16: return 6;
    case CLIPMAP_FORMAT_RGBA16: return 8;
    case CLIPMAP_FORMAT_L32F: return 4;
    case CLIPMAP_FORMAT_L16I: return 2;
    case CLIPMAP_FORMAT_BC1: return 8; /* the block formats: bytes of one 4 x 4 block */
    case CLIPMAP_FORMAT_BC4: return 8;
    case CLIPMAP_FORMAT_BC5: return 16;
    case CLIPMAP_FORMAT_BC7: return 16;
    default: return 0;
    }
}

/* Texels a side of the unit a slot stores of format `code`: 4 for a block format, else 1. */
static inline uint32_t clipmap_format_block(uint32_t code) {
    return code >= CLIPMAP_FORMAT_BC1 && code <= CLIPMAP_FORMAT_BC7 ? 4u : 1u;
}

static inline uint32_t clipmap_u32(const struct clipmap_map *m, size_t off) {
    uint32_t v;
    memcpy(&v, m->base + off, 4);
    return v;
}

static inline uint64_t clipmap_u64(const struct clipmap_map *m, size_t off) {
    uint64_t v;
    memcpy(&v, m->base + off, 8);
    return v;
}

/* Atomic 8-byte load of a field the writer changes (off must be 8-aligned and inside). */
static inline uint64_t clipmap_load(const struct clipmap_map *m, size_t off, int order) {
    return __atomic_load_n((const uint64_t *)(const void *)(m->base + off), order);
}

static inline void clipmap_pause(void) {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#elif defined(__aarch64__)
    __asm__ __volatile__("yield");
#endif
}

/* Between attempts at the snapshot or the growth block: give the processor away. The writer holds
 * those locks for microseconds, but for longer when it is descheduled meanwhile; 64 attempts of
 * a bare spin can run out in that time, 64 yields let it finish. */
static inline void clipmap_yield_(void) { sched_yield(); }

/* Overflow-checked a + b and a * b: 0 on overflow. */
static inline int clipmap_add(uint64_t a, uint64_t b, uint64_t *r) { return !__builtin_add_overflow(a, b, r); }
static inline int clipmap_mul(uint64_t a, uint64_t b, uint64_t *r) { return !__builtin_mul_overflow(a, b, r); }

static inline uint64_t clipmap_div_ceil(uint64_t a, uint64_t b) { return a / b + (a % b != 0); }

/* Euclidean a mod n (n > 0). */
static inline uint64_t clipmap_mod(int64_t a, uint64_t n) {
    if (a >= 0) return (uint64_t)a % n;
    uint64_t r = (uint64_t)(-(a + 1)) % n; /* -(a+1) cannot overflow */
    return n - 1 - r;
}

/* Slot index of tile (S, T): (T mod GH) * GW + (S mod GW), Euclidean. */
static inline uint64_t clipmap_slot_index(const struct clipmap_level_desc *d, int64_t S, int64_t T) {
    return clipmap_mod(T, d->grid[1]) * d->grid[0] + clipmap_mod(S, d->grid[0]);
}

static inline double clipmap_f64_(uint64_t bits) {
    double v;
    memcpy(&v, &bits, 8);
    return v;
}

/* Checks the heights block (docs/SHM.md, "Heights block") against the texel format and fills the
 * height_* fields of m. 0 on success, else -1 with m->error saying where, what and what was
 * expected. */
static inline int clipmap_check_heights_(struct clipmap_map *m, const char *path) {
#define CLIPMAP_REFUSE(...)                                                          \
    do {                                                                             \
        int n_ = snprintf(m->error, sizeof m->error, "%s: ", path);                  \
        if (n_ < 0 || (size_t)n_ >= sizeof m->error) n_ = 0;                         \
        snprintf(m->error + n_, sizeof m->error - (size_t)n_, __VA_ARGS__);          \
        return -1;                                                                   \
    } while (0)
    const size_t b = CLIPMAP_H_HEIGHTS;
    uint32_t flag = clipmap_u32(m, b + CLIPMAP_HT_IS_HEIGHTS), rule = clipmap_u32(m, b + CLIPMAP_HT_RULE);
    uint64_t sb = clipmap_u64(m, b + CLIPMAP_HT_SCALE), ob = clipmap_u64(m, b + CLIPMAP_HT_OFFSET);
    uint64_t nb = clipmap_u64(m, b + CLIPMAP_HT_NODATA);
    double scale = clipmap_f64_(sb), offset = clipmap_f64_(ob), nodata = clipmap_f64_(nb);
    m->heights = 0;
    m->height_rule = 0;
    m->height_scale = m->height_offset = m->height_nodata = 0.0;
    m->height_has_nodata = 0;
    if (flag == 0) {
        if (rule != 0 || sb != 0 || ob != 0 || nb != 0)
            CLIPMAP_REFUSE("heights block, byte %zu (heights flag): the texels are not heights but the block is not "
                           "all zero; expected all zero", b + CLIPMAP_HT_IS_HEIGHTS);
        return 0;
    }
    if (flag != 1)
        CLIPMAP_REFUSE("heights block, byte %zu (heights flag): found %u, expected 0 (not heights) or 1 (heights)",
                       b + CLIPMAP_HT_IS_HEIGHTS, flag);
    uint32_t f = m->texel_format;
    if (f != CLIPMAP_FORMAT_L32F && f != CLIPMAP_FORMAT_L16 && f != CLIPMAP_FORMAT_L16I)
        CLIPMAP_REFUSE("heights block, byte %zu (heights flag): heights on texel format code %u, expected a height "
                       "format: 11 (l32f), 7 (l16) or 12 (l16i)", b + CLIPMAP_HT_IS_HEIGHTS, f);
    if (rule > CLIPMAP_RULE_MAX)
        CLIPMAP_REFUSE("heights block, byte %zu (level rule): found %u, expected 0 (mean), 1 (point), 2 (min) or 3 (max)",
                       b + CLIPMAP_HT_RULE, rule);
    if (!isfinite(scale) || !(scale > 0.0))
        CLIPMAP_REFUSE("heights block, byte %zu (scale): found %g, expected a finite number above zero",
                       b + CLIPMAP_HT_SCALE, scale);
    if (!isfinite(offset))
        CLIPMAP_REFUSE("heights block, byte %zu (offset): found %g, expected a finite number", b + CLIPMAP_HT_OFFSET,
                       offset);
    if (f == CLIPMAP_FORMAT_L32F && (scale != 1.0 || offset != 0.0))
        CLIPMAP_REFUSE("heights block, byte %zu (scale): l32f stores metres: found scale %g, offset %g, expected 1 and 0",
                       b + CLIPMAP_HT_SCALE, scale, offset);
    if (f != CLIPMAP_FORMAT_L32F) {
        /* What HeightFormat::new refuses (crates/clipmap-base/src/height.rs): heights past 10,000 km from zero, and
         * steps too fine to be told apart at the heights' distance from zero. */
        double lo = f == CLIPMAP_FORMAT_L16 ? 0.0 : -32768.0, hi = f == CLIPMAP_FORMAT_L16 ? 65535.0 : 32767.0;
        double m_lo = lo * scale + offset, m_hi = hi * scale + offset;
        if (fabs(m_lo) > CLIPMAP_HEIGHT_LIMIT_M || fabs(m_hi) > CLIPMAP_HEIGHT_LIMIT_M) {
            int at_offset = fabs(offset) > CLIPMAP_HEIGHT_LIMIT_M;
            CLIPMAP_REFUSE("heights block, byte %zu (%s): found scale %.17g, offset %.17g: %s then holds %.17g m to "
                           "%.17g m, expected every height within 10000000 m of zero",
                           b + (at_offset ? CLIPMAP_HT_OFFSET : CLIPMAP_HT_SCALE), at_offset ? "offset" : "scale",
                           scale, offset, f == CLIPMAP_FORMAT_L16 ? "l16" : "l16i", m_lo, m_hi);
        }
        double big = fabs(m_lo) > fabs(m_hi) ? fabs(m_lo) : fabs(m_hi); /* no fmax: needs no -lm */
        if (fabs(offset) > big) big = fabs(offset);
        if (scale < big * DBL_EPSILON * 64.0)
            CLIPMAP_REFUSE("heights block, byte %zu (scale): found %.17g, expected a step of at least %.17g: steps that "
                           "small cannot be told apart at %.17g m from zero in 64-bit arithmetic",
                           b + CLIPMAP_HT_SCALE, scale, big * DBL_EPSILON * 64.0, big);
    }
    if (!isnan(nodata)) {
        if (f == CLIPMAP_FORMAT_L32F) {
            if (!isfinite(nodata) || fabs(nodata) > FLT_MAX || (double)(float)nodata != nodata)
                CLIPMAP_REFUSE("heights block, byte %zu (nodata): found %g, expected a finite 32-bit float or NaN (none)",
                               b + CLIPMAP_HT_NODATA, nodata);
        } else {
            double lo = f == CLIPMAP_FORMAT_L16 ? 0.0 : -32768.0, hi = f == CLIPMAP_FORMAT_L16 ? 65535.0 : 32767.0;
            if (!isfinite(nodata) || nodata < lo || nodata > hi || nodata != (double)(long)nodata)
                CLIPMAP_REFUSE("heights block, byte %zu (nodata): found %g, expected a whole number in %g..%g or NaN (none)",
                               b + CLIPMAP_HT_NODATA, nodata, lo, hi);
        }
        m->height_has_nodata = 1;
        m->height_nodata = nodata;
    }
    m->heights = 1;
    m->height_rule = rule;
    m->height_scale = scale;
    m->height_offset = offset;
    return 0;
#undef CLIPMAP_REFUSE
}

/* The length of the longest prefix of the n bytes at p that is valid UTF-8 (n: all of it), as Rust's
 * str::from_utf8 and Python's decode judge: no overlong forms, surrogates or code points past
 * U+10FFFF. */
static inline size_t clipmap_utf8_valid_(const unsigned char *p, size_t n) {
    size_t i = 0;
    while (i < n) {
        unsigned c = p[i], lo = 0x80, hi = 0xBF;
        size_t len;
        if (c < 0x80) {
            i++;
            continue;
        } else if (c >= 0xC2 && c <= 0xDF) {
            len = 2;
        } else if (c >= 0xE0 && c <= 0xEF) {
            len = 3;
            if (c == 0xE0) lo = 0xA0;
            if (c == 0xED) hi = 0x9F;
        } else if (c >= 0xF0 && c <= 0xF4) {
            len = 4;
            if (c == 0xF0) lo = 0x90;
            if (c == 0xF4) hi = 0x8F;
        } else {
            return i;
        }
        if (i + 1 >= n || p[i + 1] < lo || p[i + 1] > hi) return i;
        for (size_t j = 2; j < len; j++)
            if (i + j >= n || p[i + j] < 0x80 || p[i + j] > 0xBF) return i;
        i += len;
    }
    return n;
}

/* The field of byte `at` of the georef block, for messages. */
static inline const char *clipmap_georef_field_(size_t at) {
    static const char *const names[] = {"present", "EPSG code", "flags", "definition length", "origin x", "origin x",
                                        "origin y", "origin y", "geotransform [1]", "geotransform [1]",
                                        "geotransform [2]", "geotransform [2]", "geotransform [4]",
                                        "geotransform [4]", "geotransform [5]", "geotransform [5]"};
    return at < CLIPMAP_GR_DEFINITION ? names[at / 4] : "definition";
}

/* Checks the georef block and every level's affine terms (docs/SHM.md, "Georef block") and fills the
 * georef_* fields of m (m->level_count must be checked). 0 on success, else -1 with m->error saying
 * where, what and what was expected. */
static inline int clipmap_check_georef_(struct clipmap_map *m, const char *path) {
#define CLIPMAP_REFUSE(...)                                                          \
    do {                                                                             \
        int n_ = snprintf(m->error, sizeof m->error, "%s: ", path);                  \
        if (n_ < 0 || (size_t)n_ >= sizeof m->error) n_ = 0;                         \
        snprintf(m->error + n_, sizeof m->error - (size_t)n_, __VA_ARGS__);          \
        return -1;                                                                   \
    } while (0)
    static const char *const terms[4] = {"[1]", "[2]", "[4]", "[5]"};
    const size_t b = CLIPMAP_H_GEOREF;
    const unsigned char *blk = m->base + b;
    m->georef = 0;
    m->georef_epsg = 0;
    m->georef_wraps = 0;
    m->georef_origin[0] = m->georef_origin[1] = 0.0;
    memset(m->georef_terms, 0, sizeof m->georef_terms);
    m->georef_definition_len = 0;
    m->georef_definition[0] = 0;
#define CLIPMAP_DESC_GEOREF_AT(k, i) \
    (CLIPMAP_H_LEVEL_DESCS + (size_t)(k) * CLIPMAP_DESC_BYTES + CLIPMAP_D_GEOREF + 8 * (size_t)(i))
    uint32_t present = clipmap_u32(m, b + CLIPMAP_GR_PRESENT);
    if (present == 0) {
        for (size_t i = 0; i < CLIPMAP_GEOREF_BYTES; i++)
            if (blk[i] != 0)
                CLIPMAP_REFUSE("georef block, byte %zu (%s): found byte 0x%02x, expected 0: the block says the texture "
                               "has no georeferencing (present 0), so it must be all zero",
                               b + i, clipmap_georef_field_(i), blk[i]);
        for (uint32_t k = 0; k < m->level_count; k++)
            for (int i = 0; i < 4; i++) {
                uint64_t w = clipmap_u64(m, CLIPMAP_DESC_GEOREF_AT(k, i));
                if (w != 0)
                    CLIPMAP_REFUSE("level %u descriptor, byte %zu (georef %s): found %.17g, expected 0: the texture has "
                                   "no georeferencing (georef block all zero)",
                                   k, CLIPMAP_DESC_GEOREF_AT(k, i), terms[i], clipmap_f64_(w));
            }
        return 0;
    }
    if (present != 1)
        CLIPMAP_REFUSE("georef block, byte %zu (present): found %u, expected 0 (no georeferencing) or 1 (georeferenced)",
                       b + CLIPMAP_GR_PRESENT, present);
    uint32_t flags = clipmap_u32(m, b + CLIPMAP_GR_FLAGS);
    if (flags & ~CLIPMAP_GR_KNOWN_FLAGS)
        CLIPMAP_REFUSE("georef block, byte %zu (flags): found 0x%x, expected only bit 0 (wraps in longitude): a bit "
                       "this reader does not know", b + CLIPMAP_GR_FLAGS, flags);
    uint32_t n = clipmap_u32(m, b + CLIPMAP_GR_DEFINITION_LEN);
    if (n > CLIPMAP_GEOREF_DEFINITION_MAX)
        CLIPMAP_REFUSE("georef block, byte %zu (definition length): found %u, expected at most %d",
                       b + CLIPMAP_GR_DEFINITION_LEN, n, CLIPMAP_GEOREF_DEFINITION_MAX);
    double v[6];
    for (int i = 0; i < 6; i++) {
        size_t o = i < 2 ? CLIPMAP_GR_ORIGIN_X + 8 * (size_t)i : CLIPMAP_GR_TERMS + 8 * (size_t)(i - 2);
        v[i] = clipmap_f64_(clipmap_u64(m, b + o));
        if (!isfinite(v[i]))
            CLIPMAP_REFUSE("georef block, byte %zu (%s): found %.17g, expected a finite number", b + o,
                           clipmap_georef_field_(o), v[i]);
    }
    double det = v[2] * v[5] - v[3] * v[4];
    if (!isfinite(det) || det == 0.0)
        CLIPMAP_REFUSE("georef block, byte %zu (geotransform [1]): [1] x [5] - [2] x [4] = %.17g, expected a finite "
                       "number other than 0 (texels must span an area)", b + CLIPMAP_GR_TERMS, det);
    const unsigned char *text = blk + CLIPMAP_GR_DEFINITION;
    size_t ok = clipmap_utf8_valid_(text, n);
    if (ok < n)
        CLIPMAP_REFUSE("georef block, byte %zu (definition): byte %zu of the definition (0x%02x) is not UTF-8, "
                       "expected UTF-8 text (a PROJ string or WKT)", b + CLIPMAP_GR_DEFINITION + ok, ok, text[ok]);
    for (size_t i = 0; i < n; i++)
        if (text[i] == 0)
            CLIPMAP_REFUSE("georef block, byte %zu (definition): a NUL at byte %zu of the %u-byte definition, "
                           "expected text without NUL", b + CLIPMAP_GR_DEFINITION + i, i, n);
    for (size_t i = n; i < CLIPMAP_GEOREF_DEFINITION_MAX; i++)
        if (text[i] != 0)
            CLIPMAP_REFUSE("georef block, byte %zu (definition): found byte 0x%02x after the definition's %u bytes, "
                           "expected 0", b + CLIPMAP_GR_DEFINITION + i, text[i], n);
    for (uint32_t k = 0; k < m->level_count; k++) {
        double t[4];
        for (int i = 0; i < 4; i++) {
            uint64_t w = clipmap_u64(m, CLIPMAP_DESC_GEOREF_AT(k, i));
            t[i] = clipmap_f64_(w);
            if (!isfinite(t[i]))
                CLIPMAP_REFUSE("level %u descriptor, byte %zu (georef %s): found %.17g, expected a finite number", k,
                               CLIPMAP_DESC_GEOREF_AT(k, i), terms[i], t[i]);
        }
        double d = t[0] * t[3] - t[1] * t[2];
        if (!isfinite(d) || d == 0.0)
            CLIPMAP_REFUSE("level %u descriptor, byte %zu (georef [1]): [1] x [5] - [2] x [4] = %.17g, expected a finite "
                           "number other than 0 (the level's texels must span an area)", k, CLIPMAP_DESC_GEOREF_AT(k, 0), d);
        if (k == 0)
            for (int i = 0; i < 4; i++)
                if (clipmap_u64(m, CLIPMAP_DESC_GEOREF_AT(0, i)) != clipmap_u64(m, b + CLIPMAP_GR_TERMS + 8 * (size_t)i))
                    CLIPMAP_REFUSE("level 0 descriptor, byte %zu (georef %s): found %.17g, expected %.17g, the georef "
                                   "block's level-0 term (byte %zu)", CLIPMAP_DESC_GEOREF_AT(0, i), terms[i], t[i],
                                   v[2 + i], b + CLIPMAP_GR_TERMS + 8 * (size_t)i);
        memcpy(m->georef_terms[k], t, sizeof t);
    }
#undef CLIPMAP_DESC_GEOREF_AT
    m->georef = 1;
    m->georef_epsg = clipmap_u32(m, b + CLIPMAP_GR_EPSG);
    m->georef_wraps = (flags & CLIPMAP_GR_WRAPS) != 0;
    m->georef_origin[0] = v[0];
    m->georef_origin[1] = v[1];
    m->georef_definition_len = n;
    memcpy(m->georef_definition, text, n);
    m->georef_definition[n] = 0;
    return 0;
#undef CLIPMAP_REFUSE
}

/* The map coordinates (out[0], out[1]) of the continuous texel position (s, t) of level k (t counting
 * up from the south). Every level is anchored at the south-west corner SW = origin + H0 * ([2], [5])
 * of level 0 (H0 the level-0 height, header offset 48; a level whose height was rounded down drops
 * level 0's northmost rows), so the position is SW + s * ([1], [4]) - t * ([2], [5]) of level k's
 * terms; level k's own GDAL geotransform is [SWx - height_k * [2], [1], [2], SWy - height_k * [5],
 * [4], [5]]. -1 without georeferencing or for a level past the level count. */
static inline int clipmap_map_of_texel(const struct clipmap_map *m, uint32_t k, double s, double t, double out[2]) {
    if (!m->georef || k >= m->level_count) return -1;
    const double *g0 = m->georef_terms[0], *g = m->georef_terms[k];
    double h0 = (double)m->size[1];
    double sw[2] = {m->georef_origin[0] + h0 * g0[1], m->georef_origin[1] + h0 * g0[3]};
    out[0] = sw[0] + g[0] * s - g[1] * t;
    out[1] = sw[1] + g[2] * s - g[3] * t;
    return 0;
}

/* Writes the n bytes at p into out (len bytes) as text: printable ASCII as it is, any other byte (and
 * the quote and backslash) as \xNN. */
static inline void clipmap_show_(const unsigned char *p, size_t n, char *out, size_t len) {
    size_t k = 0;
    out[0] = 0;
    for (size_t i = 0; i < n && k + 5 <= len; i++) {
        unsigned c = p[i];
        k += (size_t)snprintf(out + k, len - k, c >= 32 && c < 127 && c != '"' && c != '\\' ? "%c" : "\\x%02x", c);
    }
}

/* Whether `c` may appear in a view's name: A-Z a-z 0-9 - _ . */
static inline int clipmap_view_char_(unsigned char c) {
    return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '-' || c == '_' ||
           c == '.';
}

/* 1 when `name` (NUL-terminated) is a name a view record may carry: 1 to 31 of A-Z a-z 0-9 - _ .,
 * not "main" (the primary view's). */
static inline int clipmap_view_name_ok(const char *name) {
    size_t n = 0;
    for (; n <= CLIPMAP_VIEW_NAME_MAX && name[n] != 0; n++)
        if (!clipmap_view_char_((unsigned char)name[n])) return 0;
    return n >= 1 && n <= CLIPMAP_VIEW_NAME_MAX && strcmp(name, "main") != 0;
}

/* View record r's fields 0..128, as clipmap_view_record_ read and checked them. */
struct clipmap_view_record_ {
    uint64_t state;        /* CLIPMAP_VIEW_FREE, CLIPMAP_VIEW_LIVE or CLIPMAP_VIEW_OWN */
    uint64_t incarnation;
    double weight;         /* checked for a live record only */
    char name[CLIPMAP_VIEW_NAME_BYTES + 1]; /* NUL-terminated; checked for a live record only */
};

/* Reads the fields 0..128 of view record r (r < m->view_records) under the record's seqlock, at
 * most CLIPMAP_MAX_RETRIES attempts with a yield between them, and checks them (docs/SHM.md,
 * "Checks of the block"): a state 0 or 1, or 2 in a version-2 block; for a live record (state 1
 * or 2), a weight finite and above 0 and a name of 1 to 31 allowed characters followed by NULs
 * only (never "main"). CLIPMAP_OK,
 * CLIPMAP_BUSY or CLIPMAP_CORRUPT, with `error` (len bytes) naming the record, byte and field. */
static inline int clipmap_view_record_(const struct clipmap_map *m, uint32_t r, struct clipmap_view_record_ *rec,
                                       char *error, size_t len) {
    const size_t b = (size_t)m->views_offset + CLIPMAP_VB_RECORDS + (size_t)r * CLIPMAP_VIEW_RECORD_BYTES;
    uint64_t state = 0, inc = 0, wbits = 0, name[4] = {0, 0, 0, 0};
    int got = 0;
    for (int attempt = 0; attempt < CLIPMAP_MAX_RETRIES && !got; attempt++) {
        uint64_t s1 = clipmap_load(m, b + CLIPMAP_V_SEQ, __ATOMIC_ACQUIRE);
        if (s1 & 1) {
            clipmap_yield_();
            continue;
        }
        state = clipmap_load(m, b + CLIPMAP_V_STATE, __ATOMIC_RELAXED);
        inc = clipmap_load(m, b + CLIPMAP_V_INCARNATION, __ATOMIC_RELAXED);
        wbits = clipmap_load(m, b + CLIPMAP_V_WEIGHT, __ATOMIC_RELAXED);
        for (int i = 0; i < 4; i++) name[i] = clipmap_load(m, b + CLIPMAP_V_NAME + 8 * (size_t)i, __ATOMIC_RELAXED);
        __atomic_thread_fence(__ATOMIC_ACQUIRE);
        got = clipmap_load(m, b + CLIPMAP_V_SEQ, __ATOMIC_RELAXED) == s1;
    }
    if (!got) {
        snprintf(error, len, "view record %u: the writer kept it locked for %d attempts", r, CLIPMAP_MAX_RETRIES);
        return CLIPMAP_BUSY;
    }
    unsigned char raw[CLIPMAP_VIEW_NAME_BYTES];
    memcpy(raw, name, sizeof raw); /* little-endian: the words' bytes in order */
    const unsigned long long at = (unsigned long long)b;
    if (state > (m->views_version >= 2 ? CLIPMAP_VIEW_OWN : CLIPMAP_VIEW_LIVE)) {
        if (m->views_version >= 2)
            snprintf(error, len, "views block at %llu, record %u, byte %llu (state): found %llu, expected 0 (free), 1 "
                     "(live) or 2 (live with grids of its own)", (unsigned long long)m->views_offset, r,
                     at + CLIPMAP_V_STATE, (unsigned long long)state);
        else
            snprintf(error, len, "views block at %llu, record %u, byte %llu (state): found %llu, expected 0 (free) or "
                     "1 (live) in a views block of version %u (state 2 comes with version 2)",
                     (unsigned long long)m->views_offset, r, at + CLIPMAP_V_STATE, (unsigned long long)state,
                     m->views_version);
        return CLIPMAP_CORRUPT;
    }
    memset(rec, 0, sizeof *rec);
    rec->state = state;
    rec->incarnation = inc;
    rec->weight = clipmap_f64_(wbits);
    memcpy(rec->name, raw, sizeof raw);
    if (state == CLIPMAP_VIEW_FREE) return CLIPMAP_OK;
    if (!isfinite(rec->weight) || !(rec->weight > 0.0)) {
        snprintf(error, len, "views block at %llu, record %u, byte %llu (weight): found %g (bits %016llx), expected a "
                 "finite number above 0", (unsigned long long)m->views_offset, r, at + CLIPMAP_V_WEIGHT, rec->weight,
                 (unsigned long long)wbits);
        return CLIPMAP_CORRUPT;
    }
    size_t n = 0;
    while (n < sizeof raw && raw[n] != 0) n++;
    int ok = n >= 1 && n <= CLIPMAP_VIEW_NAME_MAX && !(n == 4 && memcmp(raw, "main", 4) == 0);
    for (size_t i = 0; i < sizeof raw; i++)
        if (i < n ? !clipmap_view_char_(raw[i]) : raw[i] != 0) ok = 0;
    if (!ok) {
        char shown[4 * CLIPMAP_VIEW_NAME_BYTES + 1];
        clipmap_show_(raw, sizeof raw, shown, sizeof shown);
        snprintf(error, len, "views block at %llu, record %u, byte %llu (name): found \"%s\", expected 1 to %u of "
                 "A-Z a-z 0-9 - _ . followed by NULs only (never \"main\")", (unsigned long long)m->views_offset, r,
                 at + CLIPMAP_V_NAME, shown, CLIPMAP_VIEW_NAME_MAX);
        return CLIPMAP_CORRUPT;
    }
    return CLIPMAP_OK;
}

/* Checks the views block (docs/SHM.md, "Checks of the block") and sets m->views_offset,
 * m->view_records and m->views_error; `slots_end` is the end of the last level's slots. 0 when
 * the mapping may be used; -1 with m->error set when it is corrupt: an offset that is not 0, not a
 * multiple of 4096, before `slots_end` or with the block past the end of the mapping; a block of
 * version 1 or 2 with N outside 1..64, record bytes other than 2240, or a record that fails
 * clipmap_view_record_'s checks (a record the writer keeps locked is checked when it is read). A
 * magic or version this header does not know leaves `main` readable and every other view not
 * (m->views_error says why), as a reader of layout 2 that ignores the block would. */
static inline int clipmap_check_views_(struct clipmap_map *m, const char *path, uint64_t slots_end) {
#define CLIPMAP_REFUSE(...)                                                          \
    do {                                                                             \
        int n_ = snprintf(m->error, sizeof m->error, "%s: ", path);                  \
        if (n_ < 0 || (size_t)n_ >= sizeof m->error) n_ = 0;                         \
        snprintf(m->error + n_, sizeof m->error - (size_t)n_, __VA_ARGS__);          \
        return -1;                                                                   \
    } while (0)
    const uint64_t off = clipmap_u64(m, CLIPMAP_H_VIEWS_OFFSET), total = (uint64_t)m->len;
    uint64_t head_end = 0, bytes, end = 0;
    m->views_offset = 0;
    m->view_records = 0;
    m->views_version = 0;
    m->views_error[0] = 0;
    if (off == 0) return 0;
    if (off % CLIPMAP_PAGE != 0 || off < slots_end || !clipmap_add(off, CLIPMAP_VB_RECORDS, &head_end) ||
        head_end > total)
        CLIPMAP_REFUSE("header byte %d (views block offset): found %llu, expected 0 (no views) or a multiple of %u at "
                       "or after the end of the last level's slots (%llu), the block inside the %llu-byte mapping",
                       CLIPMAP_H_VIEWS_OFFSET, (unsigned long long)off, CLIPMAP_PAGE, (unsigned long long)slots_end,
                       (unsigned long long)total);
    m->views_offset = off;
    const unsigned char *vb = m->base + off;
    uint32_t version = clipmap_u32(m, (size_t)off + CLIPMAP_VB_VERSION);
    if (memcmp(vb + CLIPMAP_VB_MAGIC, CLIPMAP_VIEWS_MAGIC, 8) != 0) {
        char shown[40];
        clipmap_show_(vb + CLIPMAP_VB_MAGIC, 8, shown, sizeof shown);
        snprintf(m->views_error, sizeof m->views_error, "views block at %llu, byte %llu (magic): found \"%s\", "
                 "expected \"%s\"", (unsigned long long)off, (unsigned long long)off + CLIPMAP_VB_MAGIC, shown,
                 CLIPMAP_VIEWS_MAGIC);
        return 0;
    }
    if (version < CLIPMAP_VIEWS_VERSION_MIN || version > CLIPMAP_VIEWS_VERSION) {
        snprintf(m->views_error, sizeof m->views_error, "views block at %llu, byte %llu (version): found %u, this "
                 "reader reads views block versions %u to %u only (main still reads; for other views use a reader "
                 "of the service's release)", (unsigned long long)off, (unsigned long long)off + CLIPMAP_VB_VERSION,
                 version, CLIPMAP_VIEWS_VERSION_MIN, CLIPMAP_VIEWS_VERSION);
        return 0;
    }
    uint32_t n = clipmap_u32(m, (size_t)off + CLIPMAP_VB_RECORD_COUNT);
    uint32_t rb = clipmap_u32(m, (size_t)off + CLIPMAP_VB_RECORD_BYTES);
    if (n < 1 || n > CLIPMAP_MAX_VIEWS)
        CLIPMAP_REFUSE("views block at %llu, byte %llu (view records): found %u, expected 1 to %u",
                       (unsigned long long)off, (unsigned long long)off + CLIPMAP_VB_RECORD_COUNT, n, CLIPMAP_MAX_VIEWS);
    if (rb != CLIPMAP_VIEW_RECORD_BYTES)
        CLIPMAP_REFUSE("views block at %llu, byte %llu (record bytes): found %u, expected %u", (unsigned long long)off,
                       (unsigned long long)off + CLIPMAP_VB_RECORD_BYTES, rb, CLIPMAP_VIEW_RECORD_BYTES);
    bytes = CLIPMAP_VB_RECORDS + (uint64_t)n * CLIPMAP_VIEW_RECORD_BYTES; /* at most 143424: no overflow */
    bytes = clipmap_div_ceil(bytes, CLIPMAP_PAGE) * CLIPMAP_PAGE;
    if (!clipmap_add(off, bytes, &end) || end > total)
        CLIPMAP_REFUSE("header byte %d (views block offset): found %llu, but the views block of %u records (%llu "
                       "bytes) then ends at %llu, past the end of the %llu-byte mapping", CLIPMAP_H_VIEWS_OFFSET,
                       (unsigned long long)off, n, (unsigned long long)bytes, (unsigned long long)end,
                       (unsigned long long)total);
    m->view_records = n;
    m->views_version = version;
    for (uint32_t r = 0; r < n; r++) {
        struct clipmap_view_record_ rec;
        char why[300];
        if (clipmap_view_record_(m, r, &rec, why, sizeof why) == CLIPMAP_CORRUPT) CLIPMAP_REFUSE("%s", why);
    }
    return 0;
#undef CLIPMAP_REFUSE
}

/* Checks the static fields of the mapping at m->base (m->len bytes) as docs/SHM.md, "What a
 * reader checks", lists them; fills m. 0 on success, else -1 with m->error set. */
static inline int clipmap_check_static(struct clipmap_map *m, const char *path) {
#define CLIPMAP_REFUSE(...)                                                          \
    do {                                                                             \
        int n_ = snprintf(m->error, sizeof m->error, "%s: ", path);                  \
        if (n_ < 0 || (size_t)n_ >= sizeof m->error) n_ = 0;                         \
        snprintf(m->error + n_, sizeof m->error - (size_t)n_, __VA_ARGS__);          \
        return -1;                                                                   \
    } while (0)
    if (m->len < CLIPMAP_H_END)
        CLIPMAP_REFUSE("truncated: %zu bytes, a mapping has at least %d", m->len, CLIPMAP_H_END);
    if (memcmp(m->base + CLIPMAP_H_MAGIC, CLIPMAP_MAGIC, 7) != 0) {
        char shown[40];
        size_t k = 0;
        for (int i = 0; i < 8; i++) {
            unsigned c = m->base[i];
            k += (size_t)snprintf(shown + k, sizeof shown - k, c >= 32 && c < 127 && c != '"' && c != '\\' ? "%c" : "\\x%02x", c);
        }
        CLIPMAP_REFUSE("wrong magic \"%s\": not a clipmap mapping (expected \"%s\")", shown, CLIPMAP_MAGIC);
    }
    uint32_t version = clipmap_u32(m, CLIPMAP_H_VERSION);
    if (m->base[7] != '2' || version != CLIPMAP_VERSION)
        CLIPMAP_REFUSE("layout version %u (magic \"CLIPMAP%c\"); this reader reads layout version %u only",
                       version, m->base[7] >= 32 && m->base[7] < 127 ? m->base[7] : '?', CLIPMAP_VERSION);
    uint64_t total = clipmap_u64(m, CLIPMAP_H_TOTAL_BYTES);
    if (total != (uint64_t)m->len)
        CLIPMAP_REFUSE("the header says %llu bytes but the file has %zu (truncated or padded)",
                       (unsigned long long)total, m->len);
    uint64_t hb = clipmap_u32(m, CLIPMAP_H_HEADER_BYTES);
    if (hb % CLIPMAP_PAGE != 0 || hb < CLIPMAP_H_END || hb > total)
        CLIPMAP_REFUSE("header bytes %llu: expected a multiple of %u, at least %d and at most the %llu bytes of the mapping",
                       (unsigned long long)hb, CLIPMAP_PAGE, CLIPMAP_H_END, (unsigned long long)total);
    m->header_bytes = hb;
    m->bytes_per_texel = clipmap_u32(m, CLIPMAP_H_BYTES_PER_TEXEL);
    m->clip_size = clipmap_u32(m, CLIPMAP_H_CLIP_SIZE);
    m->level_count = clipmap_u32(m, CLIPMAP_H_LEVEL_COUNT);
    m->texel_format = clipmap_u32(m, CLIPMAP_H_TEXEL_FORMAT);
    m->writer_pid = clipmap_u32(m, CLIPMAP_H_WRITER_PID);
    m->size[0] = clipmap_u64(m, CLIPMAP_H_LEVEL0_S);
    m->size[1] = clipmap_u64(m, CLIPMAP_H_LEVEL0_T);
    m->generation = clipmap_u64(m, CLIPMAP_H_GENERATION);
    m->tick_period_ns = clipmap_u64(m, CLIPMAP_H_TICK_PERIOD_NS);
    uint64_t bpt = m->bytes_per_texel, clip = m->clip_size;
    m->block = clipmap_format_block(m->texel_format);
    if (bpt < 1 || bpt > 64) CLIPMAP_REFUSE("%llu bytes per texel: expected 1 to 64", (unsigned long long)bpt);
    uint32_t fb = clipmap_format_bytes(m->texel_format);
    if (fb != 0 && fb != bpt)
        CLIPMAP_REFUSE("texel format %u has %u bytes per texel, the header says %llu", m->texel_format, fb,
                       (unsigned long long)bpt);
    if (clipmap_check_heights_(m, path) != 0) return -1;
    if (clip == 0) CLIPMAP_REFUSE("clip size 0: expected at least 1");
    if (m->level_count < 1 || m->level_count > CLIPMAP_MAX_LEVELS)
        CLIPMAP_REFUSE("%u levels: expected 1 to %u", m->level_count, CLIPMAP_MAX_LEVELS);
    if (clipmap_check_georef_(m, path) != 0) return -1;
    if (m->size[0] == 0 || m->size[1] == 0)
        CLIPMAP_REFUSE("level 0 is %llux%llu: expected a non-zero size", (unsigned long long)m->size[0],
                       (unsigned long long)m->size[1]);
    uint64_t prev_end = hb;
    for (uint32_t k = 0; k < m->level_count; k++) {
        size_t b = CLIPMAP_H_LEVEL_DESCS + (size_t)k * CLIPMAP_DESC_BYTES;
        struct clipmap_level_desc *d = &m->levels[k];
        d->size[0] = clipmap_u64(m, b + CLIPMAP_D_SIZE_S);
        d->size[1] = clipmap_u64(m, b + CLIPMAP_D_SIZE_T);
        d->tile[0] = clipmap_u64(m, b + CLIPMAP_D_TILE_S);
        d->tile[1] = clipmap_u64(m, b + CLIPMAP_D_TILE_T);
        d->grid[0] = clipmap_u64(m, b + CLIPMAP_D_GRID_S);
        d->grid[1] = clipmap_u64(m, b + CLIPMAP_D_GRID_T);
        d->slot_bytes = clipmap_u64(m, b + CLIPMAP_D_SLOT_BYTES);
        d->tags_offset = clipmap_u64(m, b + CLIPMAP_D_TAGS_OFFSET);
        d->slots_offset = clipmap_u64(m, b + CLIPMAP_D_SLOTS_OFFSET);
        d->ranges_offset = clipmap_u64(m, b + CLIPMAP_D_RANGES_OFFSET);
        uint64_t kind = clipmap_u64(m, b + CLIPMAP_D_KIND);
        for (int a = 0; a < 2; a++) {
            uint64_t want = m->size[a] >> k;
            if (want == 0) want = 1;
            if (d->size[a] != want)
                CLIPMAP_REFUSE("level %u is %llux%llu: expected level 0's %llux%llu halved %u times", k,
                               (unsigned long long)d->size[0], (unsigned long long)d->size[1],
                               (unsigned long long)m->size[0], (unsigned long long)m->size[1], k);
        }
        if (d->tile[0] == 0 || d->tile[1] == 0 || d->grid[0] == 0 || d->grid[1] == 0)
            CLIPMAP_REFUSE("level %u: tile %llux%llu, grid %llux%llu: expected non-zero tiles and grids", k,
                           (unsigned long long)d->tile[0], (unsigned long long)d->tile[1],
                           (unsigned long long)d->grid[0], (unsigned long long)d->grid[1]);
        int pyramid = d->size[0] <= clip && d->size[1] <= clip;
        for (int a = 0; a < 2; a++) {
            uint64_t n = clipmap_div_ceil(d->size[a], d->tile[a]);
            uint64_t win = d->size[a] < clip ? d->size[a] : clip;
            uint64_t least = clipmap_div_ceil(win, d->tile[a]) + 1;
            if (least > n) least = n;
            if (d->grid[a] > n)
                CLIPMAP_REFUSE("level %u: grid %llux%llu is larger than the level's %llu tiles along axis %d", k,
                               (unsigned long long)d->grid[0], (unsigned long long)d->grid[1],
                               (unsigned long long)n, a);
            if (d->grid[a] < least)
                CLIPMAP_REFUSE("level %u: grid %llux%llu cannot hold a %llu-texel window (needs %llu along axis %d)", k,
                               (unsigned long long)d->grid[0], (unsigned long long)d->grid[1],
                               (unsigned long long)clip, (unsigned long long)least, a);
            if (pyramid && d->grid[a] != n)
                CLIPMAP_REFUSE("level %u: a pyramid level's grid %llux%llu must hold all its %llu tiles along axis %d",
                               k, (unsigned long long)d->grid[0], (unsigned long long)d->grid[1],
                               (unsigned long long)n, a);
        }
        if (kind != (uint64_t)pyramid)
            CLIPMAP_REFUSE("level %u (%llux%llu, clip %llu): kind %llu, expected %d (%s)", k,
                           (unsigned long long)d->size[0], (unsigned long long)d->size[1], (unsigned long long)clip,
                           (unsigned long long)kind, pyramid, pyramid ? "pyramid" : "stack");
        d->pyramid = pyramid;
        uint64_t sb, count, tags_bytes, tags_end, slots_bytes, slots_end;
        d->blocks[0] = clipmap_div_ceil(d->tile[0], m->block);
        d->blocks[1] = clipmap_div_ceil(d->tile[1], m->block);
        int sb_ok = clipmap_mul(d->blocks[0], d->blocks[1], &sb) && clipmap_mul(sb, bpt, &sb);
        if ((!sb_ok || sb != d->slot_bytes) && m->block == 1)
            CLIPMAP_REFUSE("level %u: slot bytes %llu, expected tile %llux%llu x %llu bytes per texel%s", k,
                           (unsigned long long)d->slot_bytes, (unsigned long long)d->tile[0],
                           (unsigned long long)d->tile[1], (unsigned long long)bpt, sb_ok ? "" : " (overflows 64 bits)");
        if (!sb_ok || sb != d->slot_bytes)
            CLIPMAP_REFUSE("level %u: slot bytes %llu, expected tile %llux%llu in 4 x 4 blocks (%llux%llu) x %llu "
                           "bytes per block (texel format %u)%s", k, (unsigned long long)d->slot_bytes,
                           (unsigned long long)d->tile[0], (unsigned long long)d->tile[1],
                           (unsigned long long)d->blocks[0], (unsigned long long)d->blocks[1], (unsigned long long)bpt,
                           m->texel_format, sb_ok ? "" : " (overflows 64 bits)");
        if (!clipmap_mul(d->grid[0], d->grid[1], &count) || !clipmap_mul(count, CLIPMAP_TAG_BYTES, &tags_bytes) ||
            !clipmap_mul(count, d->slot_bytes, &slots_bytes))
            CLIPMAP_REFUSE("level %u: grid %llux%llu of %llu-byte slots overflows", k, (unsigned long long)d->grid[0],
                           (unsigned long long)d->grid[1], (unsigned long long)d->slot_bytes);
        d->slot_count = count;
        if (d->tags_offset % CLIPMAP_PAGE != 0 || d->tags_offset < prev_end ||
            !clipmap_add(d->tags_offset, tags_bytes, &tags_end) || tags_end > total)
            CLIPMAP_REFUSE("level %u: tags at %llu (%llu bytes): expected a page-aligned offset at or after %llu, "
                           "ending inside the %llu-byte mapping", k, (unsigned long long)d->tags_offset,
                           (unsigned long long)tags_bytes, (unsigned long long)prev_end, (unsigned long long)total);
        if (d->slots_offset % CLIPMAP_PAGE != 0 || d->slots_offset < tags_end ||
            !clipmap_add(d->slots_offset, slots_bytes, &slots_end) || slots_end > total)
            CLIPMAP_REFUSE("level %u: slots at %llu (%llu bytes): expected a page-aligned offset at or after the tags' "
                           "end %llu, ending inside the %llu-byte mapping", k, (unsigned long long)d->slots_offset,
                           (unsigned long long)slots_bytes, (unsigned long long)tags_end, (unsigned long long)total);
        if (d->ranges_offset != 0) {
            uint64_t ranges_bytes, ranges_end;
            if (!m->heights)
                CLIPMAP_REFUSE("level %u descriptor, byte %zu (tile ranges offset): found %llu, expected 0: the texels "
                               "are not heights (heights block all zero)", k, b + CLIPMAP_D_RANGES_OFFSET,
                               (unsigned long long)d->ranges_offset);
            if (d->ranges_offset % CLIPMAP_PAGE != 0 || d->ranges_offset < tags_end ||
                !clipmap_mul(count, CLIPMAP_RANGE_BYTES, &ranges_bytes) ||
                !clipmap_add(d->ranges_offset, ranges_bytes, &ranges_end) || ranges_end > d->slots_offset)
                CLIPMAP_REFUSE("level %u descriptor, byte %zu (tile ranges offset): found %llu, expected 0 or a multiple "
                               "of 4096 at or after the tags' end (%llu) whose %llu entries of %d bytes end at or "
                               "before the slots (%llu)", k, b + CLIPMAP_D_RANGES_OFFSET,
                               (unsigned long long)d->ranges_offset, (unsigned long long)tags_end,
                               (unsigned long long)count, CLIPMAP_RANGE_BYTES, (unsigned long long)d->slots_offset);
        }
        prev_end = slots_end;
    }
#undef CLIPMAP_REFUSE
    return clipmap_check_views_(m, path, prev_end); /* prev_end: the end of the last level's slots */
}

/* clipmap_open, with `flags` added to open's (O_NOFOLLOW for a name the reader derived itself). */
static inline int clipmap_open_(const char *path, struct clipmap_map *m, int flags) {
    memset(m, 0, sizeof *m);
    if (strlen(path) >= sizeof m->path) {
        snprintf(m->error, sizeof m->error, "%.200s...: a path of %zu bytes, expected at most %zu", path, strlen(path),
                 sizeof m->path - 1);
        return -1;
    }
    /* O_NONBLOCK: a FIFO given as the path must not block the open (it is refused below). */
#ifdef O_CLOEXEC
    int fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC | flags);
#else
    int fd = open(path, O_RDONLY | O_NONBLOCK | flags);
#endif
    if (fd < 0) {
        const int e = errno;
        if (e == ELOOP && (flags & O_NOFOLLOW))
            snprintf(m->error, sizeof m->error, "%s: a symbolic link: expected the mapping itself (a name the "
                     "service publishes is never a link)", path);
        else
            snprintf(m->error, sizeof m->error, "%s: %s", path, strerror(e));
        errno = e;
        return -1;
    }
    struct stat st;
    if (fstat(fd, &st) != 0) {
        snprintf(m->error, sizeof m->error, "%s: %s", path, strerror(errno));
        close(fd);
        return -1;
    }
    if (!S_ISREG(st.st_mode)) {
        snprintf(m->error, sizeof m->error, "%s: not a regular file", path);
        close(fd);
        return -1;
    }
    if ((uint64_t)st.st_size < CLIPMAP_H_END) {
        snprintf(m->error, sizeof m->error, "%s: truncated: %lld bytes, a mapping has at least %d", path,
                 (long long)st.st_size, CLIPMAP_H_END);
        close(fd);
        return -1;
    }
    void *p = mmap(NULL, (size_t)st.st_size, PROT_READ, MAP_SHARED, fd, 0);
    close(fd);
    if (p == MAP_FAILED) {
        snprintf(m->error, sizeof m->error, "%s: mmap: %s", path, strerror(errno));
        return -1;
    }
    m->base = (const unsigned char *)p;
    m->len = (size_t)st.st_size;
    m->uid = st.st_uid;
    memcpy(m->path, path, strlen(path) + 1);
    __atomic_thread_fence(__ATOMIC_ACQUIRE);
    if (clipmap_check_static(m, path) != 0) {
        munmap((void *)m->base, m->len);
        m->base = NULL;
        m->len = 0;
        return -1;
    }
    return 0;
}

/* Maps `path` read-only and checks every static field. 0 on success; else -1 with m->error
 * naming what was found and what was expected (and nothing left mapped). */
static inline int clipmap_open(const char *path, struct clipmap_map *m) { return clipmap_open_(path, m, 0); }

static inline void clipmap_close(struct clipmap_map *m) {
    if (m->base) munmap((void *)m->base, m->len);
    m->base = NULL;
    m->len = 0;
}

/* Whether level `d`'s region may run past its width: the texture wraps in longitude (the georef
 * block's flag, `wraps`) and the level's width is a whole number of tiles (docs/SHM.md, "How a
 * region wraps"). */
static inline int clipmap_region_may_wrap(const struct clipmap_level_desc *d, int wraps) {
    return wraps && d->tile[0] > 0 && d->size[0] % d->tile[0] == 0;
}

/* Whether an enabled level's region is one a writer publishes: inside the level (on a level that
 * may wrap, clipmap_region_may_wrap: 0 <= s0 < width and s0 < s1 <= s0 + width, texel s being
 * texel s mod width), non-empty, and spanning at most GW x GH tiles. */
static inline int clipmap_region_ok_wrapping(const struct clipmap_level_desc *d, const int64_t v[4], int wraps) {
    for (int a = 0; a < 2; a++) {
        int64_t lo = v[a], hi = v[a + 2];
        if (a == 0 && clipmap_region_may_wrap(d, wraps)) {
            if (lo < 0 || (uint64_t)lo >= d->size[0] || hi <= lo || (uint64_t)hi - (uint64_t)lo > d->size[0]) return 0;
        } else if (lo < 0 || hi <= lo || (uint64_t)hi > d->size[a]) {
            return 0;
        }
        uint64_t tiles = ((uint64_t)hi - 1) / d->tile[a] - (uint64_t)lo / d->tile[a] + 1;
        if (tiles > d->grid[a]) return 0;
    }
    return 1;
}

/* clipmap_region_ok_wrapping of a texture that does not wrap. */
static inline int clipmap_region_ok(const struct clipmap_level_desc *d, const int64_t v[4]) {
    return clipmap_region_ok_wrapping(d, v, 0);
}

/* Takes a consistent copy of the snapshot at byte offset b (CLIPMAP_H_SNAPSHOT for `main`, a view
 * record's CLIPMAP_V_SNAPSHOT for another view; every snapshot is laid out the same) and checks
 * it, as clipmap_snapshot says. `b` must lie CLIPMAP_SNAPSHOT_BYTES inside the mapping. */
static inline int clipmap_snapshot_at_(const struct clipmap_map *m, size_t b, struct clipmap_snapshot *snap) {
    const uint32_t n = m->level_count;
    struct clipmap_snapshot x;
    uint64_t enabled[CLIPMAP_MAX_LEVELS], lod_bits = 0;
    int got = 0;
    memset(&x, 0, sizeof x);
    for (int attempt = 0; attempt < CLIPMAP_MAX_RETRIES && !got; attempt++) {
        uint64_t s1 = clipmap_load(m, b + CLIPMAP_SNAP_SEQ, __ATOMIC_ACQUIRE);
        if (s1 & 1) {
            clipmap_yield_();
            continue;
        }
        lod_bits = clipmap_load(m, b + CLIPMAP_SNAP_MIN_LOD, __ATOMIC_RELAXED);
        x.tick = clipmap_load(m, b + CLIPMAP_SNAP_TICK, __ATOMIC_RELAXED);
        x.invalid_border = clipmap_load(m, b + CLIPMAP_SNAP_INVALID_BORDER, __ATOMIC_RELAXED);
        x.centre[0] = (int64_t)clipmap_load(m, b + CLIPMAP_SNAP_CENTRE_S, __ATOMIC_RELAXED);
        x.centre[1] = (int64_t)clipmap_load(m, b + CLIPMAP_SNAP_CENTRE_T, __ATOMIC_RELAXED);
        for (uint32_t k = 0; k < n; k++) {
            size_t l = b + CLIPMAP_SNAP_LEVELS + (size_t)k * CLIPMAP_STATE_BYTES;
            struct clipmap_level_state *s = &x.levels[k];
            s->centre[0] = (int64_t)clipmap_load(m, l + CLIPMAP_S_CENTRE_S, __ATOMIC_RELAXED);
            s->centre[1] = (int64_t)clipmap_load(m, l + CLIPMAP_S_CENTRE_T, __ATOMIC_RELAXED);
            for (int i = 0; i < 4; i++)
                s->valid[i] = (int64_t)clipmap_load(m, l + CLIPMAP_S_VALID_S0 + 8 * (size_t)i, __ATOMIC_RELAXED);
            enabled[k] = clipmap_load(m, l + CLIPMAP_S_ENABLED, __ATOMIC_RELAXED);
            s->updated_tick = clipmap_load(m, l + CLIPMAP_S_UPDATED_TICK, __ATOMIC_RELAXED);
        }
        __atomic_thread_fence(__ATOMIC_ACQUIRE);
        if (clipmap_load(m, b + CLIPMAP_SNAP_SEQ, __ATOMIC_RELAXED) == s1) {
            got = 1;
            x.seq = s1;
        }
    }
    if (!got) {
        snprintf(snap->error, sizeof snap->error, "the writer kept the snapshot locked for %d attempts",
                 CLIPMAP_MAX_RETRIES);
        return CLIPMAP_BUSY;
    }
    x.level_count = n;
    memcpy(&x.min_lod, &lod_bits, 8);
    if (!(x.min_lod >= 0.0 && x.min_lod <= (double)n)) { /* refuses NaN too; infinities are out of range */
        snprintf(snap->error, sizeof snap->error, "published min LOD %g (bits %016llx): expected a finite value in 0..=%u",
                 x.min_lod, (unsigned long long)lod_bits, n);
        return CLIPMAP_CORRUPT;
    }
    for (uint32_t k = 0; k < n; k++) {
        struct clipmap_level_state *s = &x.levels[k];
        const struct clipmap_level_desc *d = &m->levels[k];
        if (enabled[k] > 1) {
            snprintf(snap->error, sizeof snap->error, "level %u: published enabled flag %llu: expected 0 or 1", k,
                     (unsigned long long)enabled[k]);
            return CLIPMAP_CORRUPT;
        }
        s->enabled = enabled[k] == 1;
        if (s->enabled && !clipmap_region_ok_wrapping(d, s->valid, m->georef_wraps)) {
            snprintf(snap->error, sizeof snap->error,
                     "level %u: published region [%lld, %lld) x [%lld, %lld): expected a non-empty rectangle "
                     "inside the %llux%llu level spanning at most %llux%llu tiles%s", k, (long long)s->valid[0],
                     (long long)s->valid[2], (long long)s->valid[1], (long long)s->valid[3],
                     (unsigned long long)d->size[0], (unsigned long long)d->size[1],
                     (unsigned long long)d->grid[0], (unsigned long long)d->grid[1],
                     clipmap_region_may_wrap(d, m->georef_wraps) ? " (it wraps: s0 inside the level, s1 - s0 at most its width)" : "");
            return CLIPMAP_CORRUPT;
        }
    }
    memcpy(snap, &x, sizeof x);
    return CLIPMAP_OK;
}

/* Takes a consistent copy of the primary view's snapshot (seqlock, at most CLIPMAP_MAX_RETRIES
 * attempts) and checks it. CLIPMAP_OK: *snap is the new snapshot. CLIPMAP_BUSY (the writer kept it
 * locked) or CLIPMAP_CORRUPT (published state outside its bounds): *snap keeps what it held,
 * except that snap->error says why. */
static inline int clipmap_snapshot(const struct clipmap_map *m, struct clipmap_snapshot *snap) {
    return clipmap_snapshot_at_(m, CLIPMAP_H_SNAPSHOT, snap);
}

/* Lists the views that exist into *list: `main` first, then each live view record's in record
 * order (each record read under its seqlock; a view with grids of its own, own = 1, as well). CLIPMAP_OK; CLIPMAP_BUSY (a record stayed locked);
 * CLIPMAP_CORRUPT (a record fails its checks, or the views block has a magic or version this
 * header does not read). On anything but CLIPMAP_OK the list holds `main` alone and list->error
 * says why. */
static inline int clipmap_views(const struct clipmap_map *m, struct clipmap_view_list *list) {
    memset(list, 0, sizeof *list);
    memcpy(list->views[0].name, "main", 5);
    list->views[0].record = CLIPMAP_VIEW_MAIN;
    list->count = 1;
    if (m->views_error[0]) {
        snprintf(list->error, sizeof list->error, "%s", m->views_error);
        return CLIPMAP_CORRUPT;
    }
    for (uint32_t r = 0; r < m->view_records; r++) {
        struct clipmap_view_record_ rec;
        int rc = clipmap_view_record_(m, r, &rec, list->error, sizeof list->error);
        if (rc != CLIPMAP_OK) {
            list->count = 1;
            return rc;
        }
        if (rec.state == CLIPMAP_VIEW_FREE) continue;
        struct clipmap_view_info *v = &list->views[list->count++];
        memcpy(v->name, rec.name, sizeof v->name);
        v->record = r;
        v->incarnation = rec.incarnation;
        v->weight = rec.weight;
        v->own = rec.state == CLIPMAP_VIEW_OWN;
    }
    return CLIPMAP_OK;
}

/* Binds *v to the view called `name` (docs/SHM.md, "Finding a view by name"): "main" is the
 * primary view (the snapshot at CLIPMAP_H_SNAPSHOT, always there); any other name is looked for
 * among the live view records, read under their seqlocks, and the record and its incarnation are
 * kept. A record in state CLIPMAP_VIEW_OWN binds with v->own = 1: the view has grids of its own,
 * read through clipmap_view_open_own (nothing is opened here). CLIPMAP_OK; CLIPMAP_NO_VIEW (not a view name, or no live record carries it: v->error
 * names the views that exist); CLIPMAP_BUSY (no record carries it but one stayed locked: try
 * again); CLIPMAP_CORRUPT (a record fails its checks, or the views block has a magic or version
 * this header does not read). v->error says why on anything but CLIPMAP_OK. */
static inline int clipmap_view_find(const struct clipmap_map *m, const char *name, struct clipmap_view *v) {
    memset(v, 0, sizeof *v);
    if (strcmp(name, "main") == 0) {
        memcpy(v->name, "main", 5);
        v->record = CLIPMAP_VIEW_MAIN;
        v->snapshot_offset = CLIPMAP_H_SNAPSHOT;
        return CLIPMAP_OK;
    }
    if (!clipmap_view_name_ok(name)) {
        char shown[4 * 40 + 1];
        clipmap_show_((const unsigned char *)name, strnlen(name, 40), shown, sizeof shown);
        snprintf(v->error, sizeof v->error, "\"%s\" is not a view name: expected \"main\" or 1 to %u of "
                 "A-Z a-z 0-9 - _ .", shown, CLIPMAP_VIEW_NAME_MAX);
        return CLIPMAP_NO_VIEW;
    }
    if (m->views_error[0]) {
        snprintf(v->error, sizeof v->error, "%s", m->views_error);
        return CLIPMAP_CORRUPT;
    }
    /* The names met on the way, for the error: "main, a, b" (at most 64 x 33 bytes). */
    char names[CLIPMAP_MAX_VIEWS * (CLIPMAP_VIEW_NAME_BYTES + 2) + 8] = "main";
    size_t k = 4;
    int busy = -1;
    for (uint32_t r = 0; r < m->view_records; r++) {
        struct clipmap_view_record_ rec;
        char why[300];
        int rc = clipmap_view_record_(m, r, &rec, why, sizeof why);
        if (rc == CLIPMAP_BUSY) {
            busy = (int)r;
            continue;
        }
        if (rc != CLIPMAP_OK) {
            snprintf(v->error, sizeof v->error, "%s", why);
            return rc;
        }
        if (rec.state == CLIPMAP_VIEW_FREE) continue;
        if (strcmp(rec.name, name) == 0) {
            memcpy(v->name, rec.name, sizeof v->name);
            v->record = r;
            v->incarnation = rec.incarnation;
            v->weight = rec.weight;
            v->own = rec.state == CLIPMAP_VIEW_OWN;
            v->snapshot_offset = v->own ? 0 : (size_t)m->views_offset + CLIPMAP_VB_RECORDS +
                                                  (size_t)r * CLIPMAP_VIEW_RECORD_BYTES + CLIPMAP_V_SNAPSHOT;
            return CLIPMAP_OK;
        }
        k += (size_t)snprintf(names + k, sizeof names - k, ", %s", rec.name); /* fits: 64 names of <= 31 */
    }
    if (busy >= 0) {
        snprintf(v->error, sizeof v->error, "no live view record is called \"%s\" but view record %d stayed locked "
                 "for %d attempts", name, busy, CLIPMAP_MAX_RETRIES);
        return CLIPMAP_BUSY;
    }
    snprintf(v->error, sizeof v->error, "no view \"%s\"%s; the views are: %s", name,
             m->views_offset == 0 ? " (the mapping has no views block)" : "", names);
    return CLIPMAP_NO_VIEW;
}

/* Whether the view *v is still the one clipmap_view_find bound: its record live with the same
 * incarnation (read under the record's seqlock). CLIPMAP_OK (always for `main`); CLIPMAP_REMOVED
 * (the record was freed or given to another view); CLIPMAP_BUSY (the record stayed locked);
 * CLIPMAP_CORRUPT (it fails its checks); CLIPMAP_NOT_VALID (*v was not bound to a record of this
 * mapping). `error` (len bytes) says why on anything but CLIPMAP_OK. */
static inline int clipmap_view_alive(const struct clipmap_map *m, const struct clipmap_view *v, char *error,
                                     size_t len) {
    if (v->record == CLIPMAP_VIEW_MAIN) return CLIPMAP_OK;
    if (v->record >= m->view_records) {
        snprintf(error, len, "view \"%s\" (record %u) is not a view record of this mapping (%u records)", v->name,
                 v->record, m->view_records);
        return CLIPMAP_NOT_VALID;
    }
    struct clipmap_view_record_ rec;
    int rc = clipmap_view_record_(m, v->record, &rec, error, len);
    if (rc != CLIPMAP_OK) return rc;
    if (rec.state == CLIPMAP_VIEW_FREE) {
        snprintf(error, len, "view \"%s\" was removed: its record %u is free", v->name, v->record);
        return CLIPMAP_REMOVED;
    }
    if (rec.incarnation != v->incarnation || (rec.state == CLIPMAP_VIEW_OWN) != (v->own != 0)) {
        snprintf(error, len, "view \"%s\" was removed: its record %u went from incarnation %llu to %llu (view \"%s\")",
                 v->name, v->record, (unsigned long long)v->incarnation, (unsigned long long)rec.incarnation, rec.name);
        return CLIPMAP_REMOVED;
    }
    return CLIPMAP_OK;
}

/* Takes a consistent, checked copy of view *v's snapshot (docs/SHM.md, "Reading a view's
 * snapshot"): for `main`, clipmap_snapshot; for a view record, its snapshot under its own sequence
 * counter, then the record's state and incarnation under the record's seqlock. CLIPMAP_OK: *snap is
 * the view's new snapshot (read texels under it with clipmap_read_region). CLIPMAP_REMOVED: the
 * view was removed (the copy is not used). CLIPMAP_BUSY, CLIPMAP_CORRUPT as clipmap_snapshot's (a
 * record that fails its checks is CLIPMAP_CORRUPT too); CLIPMAP_NOT_VALID: *v is not bound to
 * this mapping, or it is a view with grids of its own (v->own: its snapshot is `main`'s of the
 * mapping clipmap_view_open_own opens). On anything but CLIPMAP_OK, *snap keeps what it held
 * except that snap->error says why. A snapshot whose tick is 0 means the view has published
 * nothing yet. */
static inline int clipmap_view_snapshot(const struct clipmap_map *m, const struct clipmap_view *v,
                                        struct clipmap_snapshot *snap) {
    if (v->record == CLIPMAP_VIEW_MAIN) return clipmap_snapshot(m, snap);
    if (v->own) {
        snprintf(snap->error, sizeof snap->error, "view \"%s\" has grids of its own: open them with "
                 "clipmap_view_open_own and read that mapping's main (clipmap_snapshot)", v->name);
        return CLIPMAP_NOT_VALID;
    }
    if (v->record >= m->view_records) return clipmap_view_alive(m, v, snap->error, sizeof snap->error);
    struct clipmap_snapshot x;
    memset(&x, 0, sizeof x);
    int rc = clipmap_snapshot_at_(m, v->snapshot_offset, &x);
    /* Removed comes first: a record given to another view may be mid-way through its new snapshot. */
    int alive = clipmap_view_alive(m, v, snap->error, sizeof snap->error);
    if (alive != CLIPMAP_OK) return alive;
    if (rc != CLIPMAP_OK) {
        int n_ = snprintf(snap->error, sizeof snap->error, "view \"%s\": ", v->name);
        if (n_ < 0 || (size_t)n_ >= sizeof snap->error) n_ = 0;
        snprintf(snap->error + n_, sizeof snap->error - (size_t)n_, "%s", x.error);
        return rc;
    }
    memcpy(snap, &x, sizeof x);
    return CLIPMAP_OK;
}

/* snprintf into out (len bytes), cut at its end (its return value too): for a message that may be
 * longer than its buffer (it names a path). */
#if defined(__GNUC__)
__attribute__((format(printf, 3, 4)))
#endif
static inline int clipmap_fmt_(char *out, size_t len, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(out, len, fmt, ap);
    va_end(ap);
    return n;
}

/* The path of the mapping of view `view`'s grids of its own (docs/SHM.md, "A view with grids of its
 * own"): DIR/clipmap-NAME@VIEW.map beside m's DIR/clipmap-NAME.map, derived from m's path and the
 * view's name alone (never from bytes of a mapping). 0 with the path in out (len bytes); -1 when
 * `view` is no view name, m was not opened as DIR/clipmap-NAME.map (NAME 1 to 64 of A-Z a-z 0-9
 * - _ .) or the path does not fit, with why in out (when len > 0). */
static inline int clipmap_view_own_path(const struct clipmap_map *m, const char *view, char *out, size_t len) {
    static const char prefix[] = "clipmap-", suffix[] = ".map";
    const char *base = strrchr(m->path, '/');
    base = base ? base + 1 : m->path;
    const size_t dir = (size_t)(base - m->path), n = strlen(base);
    size_t name = 0;
    int ok = n > sizeof prefix - 1 + sizeof suffix - 1 && memcmp(base, prefix, sizeof prefix - 1) == 0 &&
             strcmp(base + n - (sizeof suffix - 1), suffix) == 0;
    if (ok) {
        name = n - (sizeof prefix - 1) - (sizeof suffix - 1);
        ok = name >= 1 && name <= CLIPMAP_NAME_MAX;
        for (size_t i = 0; ok && i < name; i++) ok = clipmap_view_char_((unsigned char)base[sizeof prefix - 1 + i]);
    }
    if (len == 0) return -1;
    if (!clipmap_view_name_ok(view)) {
        clipmap_fmt_(out, len, "\"%.40s\" is not a view name: expected 1 to %u of A-Z a-z 0-9 - _ . (not \"main\")", view,
                 CLIPMAP_VIEW_NAME_MAX);
        return -1;
    }
    if (!ok) {
        clipmap_fmt_(out, len, "view \"%s\" has grids of its own in DIR/clipmap-NAME%sVIEW.map, named after the "
                 "service's mapping, but the service's mapping was opened as %s, not DIR/clipmap-NAME.map (NAME 1 to "
                 "%u of A-Z a-z 0-9 - _ .): open it by its published name", view, CLIPMAP_OWN_SEPARATOR, m->path,
                 CLIPMAP_NAME_MAX);
        return -1;
    }
    int w = clipmap_fmt_(out, len, "%.*s%s%.*s%s%s%s", (int)dir, m->path, prefix, (int)name, base + sizeof prefix - 1,
                     CLIPMAP_OWN_SEPARATOR, view, suffix);
    if (w < 0 || (size_t)w >= len) {
        clipmap_fmt_(out, len, "%s: the path of view \"%s\"'s own mapping does not fit in %zu bytes", m->path, view, len);
        return -1;
    }
    return 0;
}

/* Opens the mapping of view *v's grids of its own (v->own, as clipmap_view_find bound it on the
 * service's mapping *m) into *own, exactly as clipmap_open opens any mapping (every check of
 * docs/SHM.md "What a reader checks"), the name not followed when it is a symbolic link and the
 * file owned by the owner of m's file. Read the view then as `main` of *own (clipmap_snapshot, or
 * clipmap_view_own_snapshot, which also says when the view was removed; clipmap_read_region;
 * clipmap_request_centre on its request mapping: clipmap_request_path). 0 on success; else -1 with
 * own->error naming the path and why (and nothing left open). */
static inline int clipmap_view_open_own(const struct clipmap_map *m, const struct clipmap_view *v,
                                        struct clipmap_map *own) {
    char path[sizeof own->path + 64];
    if (!v->own || v->record == CLIPMAP_VIEW_MAIN) {
        memset(own, 0, sizeof *own);
        clipmap_fmt_(own->error, sizeof own->error, "%.200s: view \"%s\" has no grids of its own: read it in this mapping "
                 "(clipmap_view_snapshot)", m->path, v->name);
        return -1;
    }
    if (clipmap_view_own_path(m, v->name, path, sizeof path) != 0) {
        memset(own, 0, sizeof *own);
        clipmap_fmt_(own->error, sizeof own->error, "%s", path);
        return -1;
    }
    errno = 0;
    if (clipmap_open_(path, own, O_NOFOLLOW) != 0) {
        char why[sizeof own->error];
        int gone = errno == ENOENT;
        memcpy(why, own->error, sizeof why);
        clipmap_fmt_(own->error, sizeof own->error, "view \"%s\" has grids of its own: %s%s", v->name, why,
                 gone ? " (expected the mapping the service publishes for the view: it was removed or is not "
                        "published yet; look the view up again)" : "");
        return -1;
    }
    if (own->uid != m->uid) {
        unsigned long got = (unsigned long)own->uid, want = (unsigned long)m->uid;
        clipmap_close(own);
        clipmap_fmt_(own->error, sizeof own->error, "%.200s: owned by uid %lu, expected uid %lu, the owner of the "
                 "service's mapping: not a file the service published (remove it, or ask its owner)", path, got, want);
        return -1;
    }
    /* It carries the generation of the service's start that published it (docs/SHM.md, "A view
     * with grids of its own"): another one is a mapping of another start, under a reused name. */
    if (own->generation != m->generation) {
        unsigned long long got = (unsigned long long)own->generation, want = (unsigned long long)m->generation;
        clipmap_close(own);
        clipmap_fmt_(own->error, sizeof own->error, "%.200s: view \"%s\" has grids of its own, but this mapping carries "
                 "generation %llu, expected %llu (the service's mapping's): it belongs to another start of the "
                 "service; open the service's mapping again and look the view up there", path, v->name, got, want);
        return -1;
    }
    return 0;
}

/* The snapshot of view *v with grids of its own, bound on the service's mapping *m and opened as
 * *own (clipmap_view_open_own): `main`'s snapshot of *own (clipmap_snapshot), then the view's record
 * in *m (clipmap_view_alive). CLIPMAP_OK: *snap is the view's new snapshot (read texels under it
 * with clipmap_read_region(own, ...)). CLIPMAP_REMOVED: the view was removed (the copy is not
 * used). CLIPMAP_BUSY, CLIPMAP_CORRUPT as clipmap_snapshot's; CLIPMAP_NOT_VALID: *v has no grids of
 * its own. On anything but CLIPMAP_OK, *snap keeps what it held except that snap->error says why. */
static inline int clipmap_view_own_snapshot(const struct clipmap_map *m, const struct clipmap_view *v,
                                            const struct clipmap_map *own, struct clipmap_snapshot *snap) {
    if (!v->own || v->record == CLIPMAP_VIEW_MAIN) {
        snprintf(snap->error, sizeof snap->error, "view \"%s\" has no grids of its own: clipmap_view_snapshot",
                 v->name);
        return CLIPMAP_NOT_VALID;
    }
    struct clipmap_snapshot x;
    memset(&x, 0, sizeof x);
    int rc = clipmap_snapshot(own, &x);
    int alive = clipmap_view_alive(m, v, snap->error, sizeof snap->error);
    if (alive != CLIPMAP_OK) return alive;
    if (rc != CLIPMAP_OK) {
        int n_ = snprintf(snap->error, sizeof snap->error, "view \"%s\" (grids of its own): ", v->name);
        if (n_ < 0 || (size_t)n_ >= sizeof snap->error) n_ = 0;
        snprintf(snap->error + n_, sizeof snap->error - (size_t)n_, "%s", x.error);
        return rc;
    }
    memcpy(snap, &x, sizeof x);
    return CLIPMAP_OK;
}

/* The request mapping's path of the mapping *m: its path with ".map" changed to ".req". 0 with the
 * path in out (len bytes); -1 when m's path does not end in ".map" or does not fit, with why in out
 * (when len > 0). */
static inline int clipmap_request_path(const struct clipmap_map *m, char *out, size_t len) {
    const size_t n = strlen(m->path);
    if (len == 0) return -1;
    if (n < 4 || strcmp(m->path + n - 4, ".map") != 0) {
        clipmap_fmt_(out, len, "%s: not named *.map: the request mapping is found by the name DIR/clipmap-NAME.req",
                 m->path);
        return -1;
    }
    if (n + 1 > len) {
        clipmap_fmt_(out, len, "the request mapping's path does not fit in %zu bytes", len);
        return -1;
    }
    memcpy(out, m->path, n - 4);
    memcpy(out + n - 4, ".req", 5);
    return 0;
}

/* Reads the growth block consistently into *g and checks it: CLIPMAP_OK, CLIPMAP_BUSY (the writer
 * kept it locked for CLIPMAP_MAX_RETRIES attempts) or CLIPMAP_CORRUPT (an extent outside the
 * frame, a world origin or resolution that is not finite and positive); g->error says why. */
static inline int clipmap_growth(const struct clipmap_map *m, struct clipmap_growth *g) {
    const size_t b = CLIPMAP_H_GROWTH;
    uint64_t v[16];
    int got = 0;
    for (int attempt = 0; attempt < CLIPMAP_MAX_RETRIES && !got; attempt++) {
        uint64_t s1 = clipmap_load(m, b + CLIPMAP_G_SEQ, __ATOMIC_ACQUIRE);
        if (s1 & 1) {
            clipmap_yield_();
            continue;
        }
        for (int i = 1; i < 15; i++) v[i] = clipmap_load(m, b + 8 * (size_t)i, __ATOMIC_RELAXED);
        __atomic_thread_fence(__ATOMIC_ACQUIRE);
        got = clipmap_load(m, b + CLIPMAP_G_SEQ, __ATOMIC_RELAXED) == s1;
    }
    if (!got) {
        snprintf(g->error, sizeof g->error, "the writer kept the growth block locked for %d attempts", CLIPMAP_MAX_RETRIES);
        return CLIPMAP_BUSY;
    }
    memset(g, 0, sizeof *g);
    if (v[CLIPMAP_G_GROWING / 8] > 1) {
        snprintf(g->error, sizeof g->error, "growth block: growing is %llu, expected 0 or 1",
                 (unsigned long long)v[CLIPMAP_G_GROWING / 8]);
        return CLIPMAP_CORRUPT;
    }
    g->growing = v[CLIPMAP_G_GROWING / 8] == 1;
    if (!g->growing) return CLIPMAP_OK;
    for (int i = 0; i < 4; i++) g->extent[i] = (int64_t)v[CLIPMAP_G_EXTENT_S0 / 8 + i];
    g->data_levels = v[CLIPMAP_G_DATA_LEVELS / 8];
    g->patches = v[CLIPMAP_G_PATCHES / 8];
    g->tiles_rebuilt = v[CLIPMAP_G_TILES_REBUILT / 8];
    g->tiles_pending = v[CLIPMAP_G_TILES_PENDING / 8];
    g->tiles_replaced = v[CLIPMAP_G_TILES_REPLACED / 8];
    g->outside_frame = v[CLIPMAP_G_OUTSIDE_FRAME / 8];
    memcpy(&g->world_origin[0], &v[CLIPMAP_G_WORLD_S0 / 8], 8);
    memcpy(&g->world_origin[1], &v[CLIPMAP_G_WORLD_T0 / 8], 8);
    memcpy(&g->texels_per_unit, &v[CLIPMAP_G_TEXELS_PER_UNIT / 8], 8);
    const int64_t *e = g->extent;
    int empty = !e[0] && !e[1] && !e[2] && !e[3];
    if (!empty && !(e[0] >= 0 && e[0] < e[2] && (uint64_t)e[2] <= m->size[0] && e[1] >= 0 && e[1] < e[3] &&
                    (uint64_t)e[3] <= m->size[1])) {
        snprintf(g->error, sizeof g->error, "growth block: extent [%lld, %lld) x [%lld, %lld) is not inside the %llux%llu frame",
                 (long long)e[0], (long long)e[2], (long long)e[1], (long long)e[3], (unsigned long long)m->size[0],
                 (unsigned long long)m->size[1]);
        return CLIPMAP_CORRUPT;
    }
    /* isfinite without <math.h>: x - x is 0 only for finite x. */
    double w0 = g->world_origin[0], w1 = g->world_origin[1], r = g->texels_per_unit;
    if (!(w0 - w0 == 0.0 && w1 - w1 == 0.0 && r - r == 0.0 && r > 0.0) || g->data_levels > 64) {
        snprintf(g->error, sizeof g->error, "growth block: world origin (%g, %g), %g texels a unit, %llu data levels: "
                 "expected finite numbers, a resolution above 0 and at most 64 levels", w0, w1, r,
                 (unsigned long long)g->data_levels);
        return CLIPMAP_CORRUPT;
    }
    return CLIPMAP_OK;
}

/* The address of texel (s, t) of `level` in the slot its tile maps to, or NULL when the level
 * does not exist, (s, t) is outside it or the format is block-compressed (a texel has no address
 * of its own there: clipmap_read_tile). It says nothing about what the slot holds: use the
 * tag protocol (clipmap_tag_try / clipmap_tag_end) around any copy. */
static inline const unsigned char *clipmap_texel_ptr(const struct clipmap_map *m, uint32_t level, int64_t s,
                                                     int64_t t) {
    if (level >= m->level_count || s < 0 || t < 0 || m->block != 1) return NULL;
    const struct clipmap_level_desc *d = &m->levels[level];
    if ((uint64_t)s >= d->size[0] || (uint64_t)t >= d->size[1]) return NULL;
    uint64_t S = (uint64_t)s / d->tile[0], T = (uint64_t)t / d->tile[1];
    uint64_t slot = (T % d->grid[1]) * d->grid[0] + S % d->grid[0];
    uint64_t in = ((uint64_t)t - T * d->tile[1]) * d->tile[0] + ((uint64_t)s - S * d->tile[0]);
    return m->base + d->slots_offset + slot * d->slot_bytes + in * m->bytes_per_texel;
}

/* One attempt at step 2 of reading a tile (docs/SHM.md, "Reading consistently"): loads the tag
 * of tile (S, T)'s slot. CLIPMAP_OK (ready or default; *seq set: copy, then clipmap_tag_end),
 * CLIPMAP_MISSING, CLIPMAP_STALE (another tile, loading, empty or an unknown state), or
 * CLIPMAP_BUSY (the tag was odd or changed while read: try again). `level` must exist. */
static inline int clipmap_tag_try(const struct clipmap_map *m, uint32_t level, int64_t S, int64_t T, uint64_t *seq) {
    const struct clipmap_level_desc *d = &m->levels[level];
    size_t tag = (size_t)(d->tags_offset + clipmap_slot_index(d, S, T) * CLIPMAP_TAG_BYTES);
    uint64_t s1 = clipmap_load(m, tag + CLIPMAP_T_SEQ, __ATOMIC_ACQUIRE);
    if (s1 & 1) return CLIPMAP_BUSY;
    int64_t ts = (int64_t)clipmap_load(m, tag + CLIPMAP_T_TILE_S, __ATOMIC_RELAXED);
    int64_t tt = (int64_t)clipmap_load(m, tag + CLIPMAP_T_TILE_T, __ATOMIC_RELAXED);
    uint64_t state = clipmap_load(m, tag + CLIPMAP_T_STATE, __ATOMIC_RELAXED);
    if (ts == S && tt == T && (state == CLIPMAP_SLOT_READY || state == CLIPMAP_SLOT_DEFAULT)) {
        *seq = s1; /* confirmed by clipmap_tag_end after the copy */
        return CLIPMAP_OK;
    }
    /* Any other verdict stands only if the tag did not change while it was read. */
    __atomic_thread_fence(__ATOMIC_ACQUIRE);
    if (clipmap_load(m, tag + CLIPMAP_T_SEQ, __ATOMIC_RELAXED) != s1) return CLIPMAP_BUSY;
    return ts == S && tt == T && state == CLIPMAP_SLOT_MISSING ? CLIPMAP_MISSING : CLIPMAP_STALE;
}

/* Step 4: 1 when the tag of tile (S, T)'s slot still has sequence `seq` after the copy (the copy
 * stands), 0 when the slot changed meanwhile (discard the copy and retry from clipmap_tag_try). */
static inline int clipmap_tag_end(const struct clipmap_map *m, uint32_t level, int64_t S, int64_t T, uint64_t seq) {
    const struct clipmap_level_desc *d = &m->levels[level];
    size_t tag = (size_t)(d->tags_offset + clipmap_slot_index(d, S, T) * CLIPMAP_TAG_BYTES);
    __atomic_thread_fence(__ATOMIC_ACQUIRE);
    return clipmap_load(m, tag + CLIPMAP_T_SEQ, __ATOMIC_RELAXED) == seq;
}

/* The range of heights of tile (S, T) of `level` as the service published it beside the slot's
 * tag (docs/SHM.md, "Tile ranges"), in metres, nodata excluded, read under the tag like texels.
 * CLIPMAP_OK: *min and *max set (both NaN when every texel of the tile is nodata).
 * CLIPMAP_NOT_VALID: no such level, or the mapping has no ranges (not heights).
 * CLIPMAP_MISSING / CLIPMAP_STALE: the slot does not hold the tile ready or default.
 * CLIPMAP_BUSY: the tag stayed locked or kept changing for CLIPMAP_MAX_RETRIES attempts. */
static inline int clipmap_tile_range(const struct clipmap_map *m, uint32_t level, int64_t S, int64_t T, double *min,
                                     double *max) {
    if (level >= m->level_count || m->levels[level].ranges_offset == 0) return CLIPMAP_NOT_VALID;
    const struct clipmap_level_desc *d = &m->levels[level];
    size_t e = (size_t)(d->ranges_offset + clipmap_slot_index(d, S, T) * CLIPMAP_RANGE_BYTES);
    for (int attempt = 0; attempt < CLIPMAP_MAX_RETRIES; attempt++) {
        uint64_t seq;
        int rc = clipmap_tag_try(m, level, S, T, &seq);
        if (rc == CLIPMAP_BUSY) {
            clipmap_pause();
            continue;
        }
        if (rc != CLIPMAP_OK) return rc;
        uint64_t lo = clipmap_load(m, e + CLIPMAP_R_MIN, __ATOMIC_RELAXED);
        uint64_t hi = clipmap_load(m, e + CLIPMAP_R_MAX, __ATOMIC_RELAXED);
        if (clipmap_tag_end(m, level, S, T, seq)) {
            *min = clipmap_f64_(lo);
            *max = clipmap_f64_(hi);
            return CLIPMAP_OK;
        }
    }
    return CLIPMAP_BUSY;
}

/* Copies the w x h texels of level `level` whose first is (s0, t0), inside the level, into `out`
 * at column `col` of rows `pitch` texels long, tile by tile, each tile under its tag protocol
 * (clipmap_read_region's codes). */
static inline int clipmap_copy_texels_(const struct clipmap_map *m, uint32_t level, uint64_t us0, uint64_t ut0,
                                       uint64_t w, uint64_t h, unsigned char *out, uint64_t pitch, uint64_t col) {
    const struct clipmap_level_desc *d = &m->levels[level];
    const uint64_t bpt = m->bytes_per_texel, tw = d->tile[0], th = d->tile[1];
    const uint64_t us1 = us0 + w, ut1 = ut0 + h;
    for (uint64_t T = ut0 / th; T <= (ut1 - 1) / th; T++) {
        uint64_t ta = T * th > ut0 ? T * th : ut0, tb = (T + 1) * th < ut1 ? (T + 1) * th : ut1;
        for (uint64_t S = us0 / tw; S <= (us1 - 1) / tw; S++) {
            uint64_t sa = S * tw > us0 ? S * tw : us0, sbnd = (S + 1) * tw < us1 ? (S + 1) * tw : us1;
            const unsigned char *slot =
                m->base + d->slots_offset + clipmap_slot_index(d, (int64_t)S, (int64_t)T) * d->slot_bytes;
            int done = 0; /* one budget of CLIPMAP_MAX_RETRIES attempts per tile */
            for (int attempt = 0; attempt < CLIPMAP_MAX_RETRIES && !done; attempt++) {
                uint64_t seq;
                int rc = clipmap_tag_try(m, level, (int64_t)S, (int64_t)T, &seq);
                if (rc == CLIPMAP_BUSY) {
                    clipmap_pause();
                    continue;
                }
                if (rc != CLIPMAP_OK) return rc;
                for (uint64_t t = ta; t < tb; t++)
                    memcpy(out + ((t - ut0) * pitch + col + (sa - us0)) * bpt,
                           slot + ((t - T * th) * tw + (sa - S * tw)) * bpt, (size_t)((sbnd - sa) * bpt));
                done = clipmap_tag_end(m, level, (int64_t)S, (int64_t)T, seq);
            }
            if (!done) return CLIPMAP_BUSY;
        }
    }
    return CLIPMAP_OK;
}

/* Copies the w x h texels of `level` from (s0, t0) into `out` (row-major, rows in increasing t,
 * row pitch w * bytes per texel), tile by tile across tile edges and the toroidal wrap, each
 * tile under its tag protocol. The rectangle must lie inside the level's region in `snap`; on a
 * texture that wraps in longitude (m->georef_wraps) texel s is texel s mod width, and the
 * rectangle must lie inside the region taken modulo the width (docs/SHM.md, "How a region
 * wraps"), at most the width wide.
 * CLIPMAP_OK: a consistent copy. CLIPMAP_NOT_VALID: no such level, disabled, or outside the
 * region. CLIPMAP_MISSING: a tile could not be read (use a coarser level). CLIPMAP_STALE: a
 * slot holds another tile (take a new snapshot). CLIPMAP_BUSY: a tag stayed locked or kept
 * changing for CLIPMAP_MAX_RETRIES attempts. CLIPMAP_CORRUPT: `snap` was not accepted by
 * clipmap_snapshot. CLIPMAP_BLOCKS: the format is block-compressed (m->block 4): read whole tiles
 * with clipmap_read_tile. On anything but CLIPMAP_OK, `out` holds unspecified bytes. */
static inline int clipmap_read_region(const struct clipmap_map *m, const struct clipmap_snapshot *snap,
                                      uint32_t level, int64_t s0, int64_t t0, uint64_t w, uint64_t h,
                                      unsigned char *out) {
    if (level >= m->level_count || level >= snap->level_count) return CLIPMAP_NOT_VALID;
    if (m->block != 1) return CLIPMAP_BLOCKS;
    const struct clipmap_level_desc *d = &m->levels[level];
    const struct clipmap_level_state *st = &snap->levels[level];
    if (st->enabled != 1) return st->enabled == 0 ? CLIPMAP_NOT_VALID : CLIPMAP_CORRUPT;
    if (!clipmap_region_ok_wrapping(d, st->valid, m->georef_wraps)) return CLIPMAP_CORRUPT;
    if (w == 0 || h == 0) return CLIPMAP_OK;
    if (t0 < st->valid[1] || t0 >= st->valid[3] || h > (uint64_t)(st->valid[3] - t0)) return CLIPMAP_NOT_VALID;
    if (!m->georef_wraps) {
        /* Inside [v0, v1): s0 >= v0, s0 < v1 and w <= v1 - s0 (no overflow: v1 - s0 > 0). */
        if (s0 < st->valid[0] || s0 >= st->valid[2] || w > (uint64_t)(st->valid[2] - s0)) return CLIPMAP_NOT_VALID;
        return clipmap_copy_texels_(m, level, (uint64_t)s0, (uint64_t)t0, w, h, out, w, 0);
    }
    /* Wraps: s0 taken to its column in [v0, v0 + width); the rectangle must end by v1. The
     * region check bounds v0 and v1 - v0 by the width (at most 2^40), so nothing overflows. */
    const int64_t width = (int64_t)d->size[0];
    if (w > d->size[0] || s0 < -((int64_t)1 << 62) || s0 > ((int64_t)1 << 62)) return CLIPMAP_NOT_VALID;
    int64_t at = st->valid[0] + (((s0 - st->valid[0]) % width) + width) % width;
    if ((uint64_t)(st->valid[2] - at) < w || at >= st->valid[2]) return CLIPMAP_NOT_VALID;
    uint64_t col = 0, real = (uint64_t)(((s0 % width) + width) % width);
    while (col < w) {
        uint64_t n = w - col < d->size[0] - real ? w - col : d->size[0] - real;
        int rc = clipmap_copy_texels_(m, level, real, (uint64_t)t0, n, h, out, w, col);
        if (rc != CLIPMAP_OK) return rc;
        col += n;
        real = 0;
    }
    return CLIPMAP_OK;
}

/* Copies tile (S, T) of `level` whole into `out` (m->levels[level].slot_bytes bytes): its slot's
 * bytes as they are, under the slot's tag protocol. For a block format (m->block 4) those are the
 * tile's blocks[0] x blocks[1] blocks in rows of increasing t, blocks along s fastest: block (i, j)
 * holds texels S*TW + 4i .. and T*TH + 4j .., at byte (j * blocks[0] + i) * bytes_per_texel; a
 * partial block (a tile spanning an odd-sized level's side) repeats the tile's last column and row.
 * For any other format, the tile's TW x TH texels in rows. The blocks are the standard BCn blocks:
 * upload them as they are (Direct3D BC1_UNORM ... BC7_UNORM, Vulkan's VK_FORMAT_BC*_UNORM_BLOCK).
 * CLIPMAP_OK: a consistent copy. CLIPMAP_NOT_VALID: no such level or tile (0 <= S < ceil(width / TW),
 * 0 <= T < ceil(height / TH)). CLIPMAP_MISSING: the tile could not be read. CLIPMAP_STALE: its slot
 * holds another tile, or is loading or empty. CLIPMAP_BUSY: the tag stayed locked or kept changing
 * for CLIPMAP_MAX_RETRIES attempts. */
static inline int clipmap_read_tile(const struct clipmap_map *m, uint32_t level, int64_t S, int64_t T,
                                    unsigned char *out) {
    if (level >= m->level_count) return CLIPMAP_NOT_VALID;
    const struct clipmap_level_desc *d = &m->levels[level];
    if (S < 0 || T < 0 || (uint64_t)S >= clipmap_div_ceil(d->size[0], d->tile[0]) ||
        (uint64_t)T >= clipmap_div_ceil(d->size[1], d->tile[1]))
        return CLIPMAP_NOT_VALID;
    const unsigned char *slot = m->base + d->slots_offset + clipmap_slot_index(d, S, T) * d->slot_bytes;
    for (int attempt = 0; attempt < CLIPMAP_MAX_RETRIES; attempt++) {
        uint64_t seq;
        int rc = clipmap_tag_try(m, level, S, T, &seq);
        if (rc == CLIPMAP_BUSY) {
            clipmap_pause();
            continue;
        }
        if (rc != CLIPMAP_OK) return rc;
        memcpy(out, slot, (size_t)d->slot_bytes);
        if (clipmap_tag_end(m, level, S, T, seq)) return CLIPMAP_OK;
    }
    return CLIPMAP_BUSY;
}

/* Bytes of one texel clipmap_decode_blocks gives for format `code`: 4 (RGBA8) for BC1 and BC7, 1
 * for BC4, 2 for BC5; 0 for a format it does not decode (every texel format). */
static inline uint32_t clipmap_decoded_bytes(uint32_t code) {
    switch (code) {
    case CLIPMAP_FORMAT_BC1: return 4;
    case CLIPMAP_FORMAT_BC4: return 1;
    case CLIPMAP_FORMAT_BC5: return 2;
    case CLIPMAP_FORMAT_BC7: return 4;
    default: return 0;
    }
}

/* One BC1 block into 4 x 4 RGBA8 texels at `out`, rows `pitch` bytes apart. The arithmetic is
 * bcdec's (public domain; the Rust client's decoder), so the texels equal its bit for bit: 5:6:5
 * endpoints widened to 8 bits, two colours between them when colour 0 > colour 1, else their mean
 * and transparent black. */
static inline void clipmap_bc1_block(const unsigned char *b, unsigned char *out, size_t pitch) {
    uint32_t c0 = (uint32_t)b[0] | (uint32_t)b[1] << 8, c1 = (uint32_t)b[2] | (uint32_t)b[3] << 8;
    uint32_t r0 = (c0 >> 11) & 31, g0 = (c0 >> 5) & 63, b0 = c0 & 31;
    uint32_t r1 = (c1 >> 11) & 31, g1 = (c1 >> 5) & 63, b1 = c1 & 31;
    unsigned char pal[4][4] = {
        {(unsigned char)((r0 * 527 + 23) >> 6), (unsigned char)((g0 * 259 + 33) >> 6), (unsigned char)((b0 * 527 + 23) >> 6), 255},
        {(unsigned char)((r1 * 527 + 23) >> 6), (unsigned char)((g1 * 259 + 33) >> 6), (unsigned char)((b1 * 527 + 23) >> 6), 255},
        {0, 0, 0, 255},
        {0, 0, 0, 0}};
    if (c0 > c1) {
        pal[2][0] = (unsigned char)(((2 * r0 + r1) * 351 + 61) >> 7);
        pal[2][1] = (unsigned char)(((2 * g0 + g1) * 2763 + 1039) >> 11);
        pal[2][2] = (unsigned char)(((2 * b0 + b1) * 351 + 61) >> 7);
        pal[3][0] = (unsigned char)(((r0 + 2 * r1) * 351 + 61) >> 7);
        pal[3][1] = (unsigned char)(((g0 + 2 * g1) * 2763 + 1039) >> 11);
        pal[3][2] = (unsigned char)(((b0 + 2 * b1) * 351 + 61) >> 7);
        pal[3][3] = 255;
    } else {
        pal[2][0] = (unsigned char)(((r0 + r1) * 1053 + 125) >> 8);
        pal[2][1] = (unsigned char)(((g0 + g1) * 4145 + 1019) >> 11);
        pal[2][2] = (unsigned char)(((b0 + b1) * 1053 + 125) >> 8);
    }
    uint32_t idx = (uint32_t)b[4] | (uint32_t)b[5] << 8 | (uint32_t)b[6] << 16 | (uint32_t)b[7] << 24;
    for (int y = 0; y < 4; y++)
        for (int x = 0; x < 4; x++, idx >>= 2) memcpy(out + (size_t)y * pitch + (size_t)x * 4, pal[idx & 3], 4);
}

/* One BC4 block (8 bytes) into 4 x 4 one-byte values at `out`, `px` bytes apart along a row and
 * rows `pitch` bytes apart (BC5 is two of them, px 2). bcdec's arithmetic, as clipmap_bc1_block. */
static inline void clipmap_bc4_block(const unsigned char *b, unsigned char *out, size_t pitch, size_t px) {
    static const uint32_t w4[4] = {13107, 26215, 39321, 52429};
    static const uint32_t w6[6] = {9363, 18724, 28086, 37450, 46812, 56173};
    uint32_t a[8];
    a[0] = b[0];
    a[1] = b[1];
    if (a[0] > a[1]) {
        for (int i = 0; i < 6; i++) a[2 + i] = (w6[5 - i] * a[0] + w6[i] * a[1] + 32768) >> 16;
    } else {
        for (int i = 0; i < 4; i++) a[2 + i] = (w4[3 - i] * a[0] + w4[i] * a[1] + 32768) >> 16;
        a[6] = 0;
        a[7] = 255;
    }
    uint64_t idx = 0;
    for (int i = 7; i >= 2; i--) idx = idx << 8 | b[i];
    for (int y = 0; y < 4; y++)
        for (int x = 0; x < 4; x++, idx >>= 3) out[(size_t)y * pitch + (size_t)x * px] = (unsigned char)a[idx & 7];
}

/* BC7's partitions (docs/SHM.md, "Block-compressed formats"): texel i's subset (i = 4 * row +
 * column) is bit i of a two-subset partition and bits 2i, 2i + 1 of a three-subset one. */
static const uint16_t clipmap_bc7_partitions2[64] = {
    0xcccc, 0x8888, 0xeeee, 0xecc8, 0xc880, 0xfeec, 0xfec8, 0xec80, 0xc800, 0xffec, 0xfe80, 0xe800, 0xffe8,
    0xff00, 0xfff0, 0xf000, 0xf710, 0x008e, 0x7100, 0x08ce, 0x008c, 0x7310, 0x3100, 0x8cce, 0x088c, 0x3110,
    0x6666, 0x366c, 0x17e8, 0x0ff0, 0x718e, 0x399c, 0xaaaa, 0xf0f0, 0x5a5a, 0x33cc, 0x3c3c, 0x55aa, 0x9696,
    0xa55a, 0x73ce, 0x13c8, 0x324c, 0x3bdc, 0x6996, 0xc33c, 0x9966, 0x0660, 0x0272, 0x04e4, 0x4e40, 0x2720,
    0xc936, 0x936c, 0x39c6, 0x639c, 0x9336, 0x9cc6, 0x817e, 0xe718, 0xccf0, 0x0fcc, 0x7744, 0xee22};
static const uint32_t clipmap_bc7_partitions3[64] = {
    0xaa685050u, 0x6a5a5040u, 0x5a5a4200u, 0x5450a0a8u, 0xa5a50000u, 0xa0a05050u, 0x5555a0a0u, 0x5a5a5050u,
    0xaa550000u, 0xaa555500u, 0xaaaa5500u, 0x90909090u, 0x94949494u, 0xa4a4a4a4u, 0xa9a59450u, 0x2a0a4250u,
    0xa5945040u, 0x0a425054u, 0xa5a5a500u, 0x55a0a0a0u, 0xa8a85454u, 0x6a6a4040u, 0xa4a45000u, 0x1a1a0500u,
    0x0050a4a4u, 0xaaa59090u, 0x14696914u, 0x69691400u, 0xa08585a0u, 0xaa821414u, 0x50a4a450u, 0x6a5a0200u,
    0xa9a58000u, 0x5090a0a8u, 0xa8a09050u, 0x24242424u, 0x00aa5500u, 0x24924924u, 0x24499224u, 0x50a50a50u,
    0x500aa550u, 0xaaaa4444u, 0x66660000u, 0xa5a0a5a0u, 0x50a050a0u, 0x69286928u, 0x44aaaa44u, 0x66666600u,
    0xaa444444u, 0x54a854a8u, 0x95809580u, 0x96969600u, 0xa85454a8u, 0x80959580u, 0xaa141414u, 0x96960000u,
    0xaaaa1414u, 0xa05050a0u, 0xa0a5a5a0u, 0x96000000u, 0x40804080u, 0xa9a8a9a8u, 0xaaaaaa44u, 0x2a4a5254u};
/* The anchors: the texel whose index of subset 1 (and 2) is stored with one bit less (subset 0's
 * is texel 0). */
static const unsigned char clipmap_bc7_anchors2[64] = {
    15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 2, 8, 2, 2, 8, 8, 15, 2, 8, 2, 2, 8, 8, 2, 2,
    15, 15, 6, 8, 2, 8, 15, 15, 2, 8, 2, 2, 2, 15, 15, 6, 6, 2, 6, 8, 15, 15, 2, 2, 15, 15, 15, 15, 15, 2, 2, 15};
static const unsigned char clipmap_bc7_anchors3[64][2] = {
    {3, 15}, {3, 8}, {15, 8}, {15, 3}, {8, 15}, {3, 15}, {15, 3}, {15, 8}, {8, 15}, {8, 15}, {6, 15}, {6, 15},
    {6, 15}, {5, 15}, {3, 15}, {3, 8}, {3, 15}, {3, 8}, {8, 15}, {15, 3}, {3, 15}, {3, 8}, {6, 15}, {10, 8},
    {5, 3}, {8, 15}, {8, 6}, {6, 10}, {8, 15}, {5, 15}, {15, 10}, {15, 8}, {8, 15}, {15, 3}, {3, 15}, {5, 10},
    {6, 10}, {10, 8}, {8, 9}, {15, 10}, {15, 6}, {3, 15}, {15, 8}, {5, 15}, {15, 3}, {15, 6}, {15, 6}, {15, 8},
    {3, 15}, {15, 3}, {5, 15}, {5, 15}, {5, 15}, {8, 15}, {5, 15}, {10, 15}, {5, 15}, {10, 15}, {8, 15}, {13, 15},
    {15, 3}, {12, 15}, {3, 15}, {3, 8}};
/* Per mode 0..7: subsets, partition bits, rotation bits, index selection bits, colour bits, alpha
 * bits, p-bits per endpoint, shared p-bits per subset, index bits, secondary index bits. */
static const unsigned char clipmap_bc7_modes[8][10] = {
    {3, 4, 0, 0, 4, 0, 1, 0, 3, 0}, {2, 6, 0, 0, 6, 0, 0, 1, 3, 0}, {3, 6, 0, 0, 5, 0, 0, 0, 2, 0},
    {2, 6, 0, 0, 7, 0, 1, 0, 2, 0}, {1, 0, 2, 1, 5, 6, 0, 0, 2, 3}, {1, 0, 2, 0, 7, 8, 0, 0, 2, 2},
    {1, 0, 0, 0, 7, 7, 1, 0, 4, 0}, {2, 6, 0, 0, 5, 5, 1, 0, 2, 0}};
/* The interpolation weights (of 64) of 2-, 3- and 4-bit indices, at [bits - 2]. */
static const unsigned char clipmap_bc7_weights[3][16] = {
    {0, 21, 43, 64},
    {0, 9, 18, 27, 37, 46, 55, 64},
    {0, 4, 9, 13, 17, 21, 26, 30, 34, 38, 43, 47, 51, 55, 60, 64}};

/* The next `n` bits (n <= 8) of BC7 block `b` from bit *at (bit 0: the lowest of byte 0), *at
 * advanced past them; bits past the block's 128 read as 0. */
static inline uint32_t clipmap_bc7_take(const unsigned char *b, uint32_t *at, uint32_t n) {
    uint32_t x = 0;
    for (uint32_t i = 0; i < n; i++, (*at)++)
        if (*at < 128) x |= (uint32_t)((b[*at >> 3] >> (*at & 7)) & 1) << i;
    return x;
}

/* One BC7 block (16 bytes) into 4 x 4 RGBA8 texels at `out`, rows `pitch` bytes apart, every mode
 * 0..7 by the format's definition (Direct3D 11's BC7 decoding: partitions, anchors, p-bits,
 * endpoints widened by repeating their top bits, ((64 - w) * e0 + w * e1 + 32) >> 6 with the 2-,
 * 3- and 4-bit weight tables, mode 4's index selection and modes 4 and 5's rotation). Exact, so the
 * texels equal any conforming decoder's, bcdec's among them. A block whose first byte is 0 (no
 * mode) decodes to transparent black. */
static inline void clipmap_bc7_block(const unsigned char *b, unsigned char *out, size_t pitch) {
    uint32_t mode = 0;
    while (mode < 8 && !((b[0] >> mode) & 1)) mode++;
    if (mode == 8) {
        for (int y = 0; y < 4; y++) memset(out + (size_t)y * pitch, 0, 16);
        return;
    }
    const unsigned char *md = clipmap_bc7_modes[mode];
    const uint32_t ns = md[0], cb = md[4], ab = md[5], epb = md[6], spb = md[7], ib = md[8], ib2 = md[9];
    uint32_t at = mode + 1;
    const uint32_t partition = clipmap_bc7_take(b, &at, md[1]);
    const uint32_t rotation = clipmap_bc7_take(b, &at, md[2]);
    const uint32_t selection = clipmap_bc7_take(b, &at, md[3]);
    const uint32_t ends = 2 * ns;
    /* Endpoints: red of every endpoint, then green, blue and alpha (subset 0's two first). */
    uint32_t ep[6][4], pbits[6] = {0, 0, 0, 0, 0, 0};
    for (uint32_t c = 0; c < 3; c++)
        for (uint32_t e = 0; e < ends; e++) ep[e][c] = clipmap_bc7_take(b, &at, cb);
    for (uint32_t e = 0; e < ends; e++) ep[e][3] = ab ? clipmap_bc7_take(b, &at, ab) : 255;
    /* P-bits: one per endpoint, or one per subset shared by its two endpoints. */
    if (epb) {
        for (uint32_t e = 0; e < ends; e++) pbits[e] = clipmap_bc7_take(b, &at, 1);
    } else if (spb) {
        for (uint32_t s = 0; s < ns; s++) pbits[2 * s] = pbits[2 * s + 1] = clipmap_bc7_take(b, &at, 1);
    }
    for (uint32_t e = 0; e < ends; e++) {
        for (uint32_t c = 0; c < 4; c++) {
            uint32_t n = c < 3 ? cb : ab, x = ep[e][c];
            if (n == 0) continue;
            if (epb || spb) {
                x = x << 1 | pbits[e];
                n++;
            }
            x <<= 8 - n;
            ep[e][c] = (x | x >> n) & 255;
        }
    }
    /* Indices: each texel's in turn, an anchor's with one bit less; then mode 4 and 5's secondary
     * (alpha) indices, texel 0's with one bit less. */
    const uint32_t a1 = ns == 2 ? clipmap_bc7_anchors2[partition] : ns == 3 ? clipmap_bc7_anchors3[partition][0] : 0;
    const uint32_t a2 = ns == 3 ? clipmap_bc7_anchors3[partition][1] : 0;
    uint32_t idx[16], idx2[16];
    for (uint32_t i = 0; i < 16; i++) {
        uint32_t anchor = i == 0 || (ns > 1 && i == a1) || (ns > 2 && i == a2);
        idx[i] = clipmap_bc7_take(b, &at, ib - anchor);
    }
    for (uint32_t i = 0; i < 16; i++) idx2[i] = ib2 ? clipmap_bc7_take(b, &at, ib2 - (i == 0)) : idx[i];
    const unsigned char *wc = clipmap_bc7_weights[ib - 2], *wa = clipmap_bc7_weights[(ib2 ? ib2 : ib) - 2];
    const uint32_t *ic = idx, *ia = idx2;
    if (selection) { /* mode 4: the colour takes the secondary indices, alpha the primary ones */
        const unsigned char *tw = wc;
        wc = wa;
        wa = tw;
        ic = idx2;
        ia = idx;
    }
    for (uint32_t i = 0; i < 16; i++) {
        uint32_t s = ns == 2 ? (clipmap_bc7_partitions2[partition] >> i) & 1
                   : ns == 3 ? (clipmap_bc7_partitions3[partition] >> (2 * i)) & 3
                             : 0;
        const uint32_t *e0 = ep[2 * s], *e1 = ep[2 * s + 1], w = wc[ic[i]], wal = wa[ia[i]];
        unsigned char t[4];
        for (int c = 0; c < 3; c++) t[c] = (unsigned char)((e0[c] * (64 - w) + e1[c] * w + 32) >> 6);
        t[3] = (unsigned char)((e0[3] * (64 - wal) + e1[3] * wal + 32) >> 6);
        if (rotation) {
            unsigned char r = t[3];
            t[3] = t[rotation - 1];
            t[rotation - 1] = r;
        }
        memcpy(out + (size_t)(i / 4) * pitch + (size_t)(i % 4) * 4, t, 4);
    }
}

/* Decodes `blocks` (`len` bytes), a w x h-texel tile of format `code` stored as ceil(w / 4) x
 * ceil(h / 4) blocks in rows (as clipmap_read_tile copies it), into `out`: w * h texels of
 * clipmap_decoded_bytes(code) bytes, rows in increasing t, s fastest; the texels of a partial block
 * beyond w or h are dropped. A decoder for checks and for renderers without the GPU formats; it
 * gives bcdec's texels (the Rust client's decode_tile) bit for bit: BC1, BC4 and BC5 with bcdec's
 * arithmetic, BC7 (RGBA8) by the format's definition, which is exact.
 * CLIPMAP_OK; CLIPMAP_NOT_VALID: a format it does not decode (a texel format), or `len` is
 * not ceil(w / 4) x ceil(h / 4) blocks of the format's bytes. */
static inline int clipmap_decode_blocks(uint32_t code, const unsigned char *blocks, size_t len, uint64_t w,
                                        uint64_t h, unsigned char *out) {
    const uint64_t px = clipmap_decoded_bytes(code), bb = clipmap_format_bytes(code);
    const uint64_t bw = clipmap_div_ceil(w, 4), bh = clipmap_div_ceil(h, 4);
    uint64_t n;
    if (px == 0 || !clipmap_mul(bw, bh, &n) || !clipmap_mul(n, bb, &n) || n != (uint64_t)len) return CLIPMAP_NOT_VALID;
    unsigned char texels[4 * 4 * 4];
    for (uint64_t j = 0; j < bh; j++) {
        for (uint64_t i = 0; i < bw; i++) {
            const unsigned char *b = blocks + (j * bw + i) * bb;
            if (code == CLIPMAP_FORMAT_BC1) {
                clipmap_bc1_block(b, texels, 16);
            } else if (code == CLIPMAP_FORMAT_BC4) {
                clipmap_bc4_block(b, texels, 4, 1);
            } else if (code == CLIPMAP_FORMAT_BC7) {
                clipmap_bc7_block(b, texels, 16);
            } else {
                clipmap_bc4_block(b, texels, 8, 2);
                clipmap_bc4_block(b + 8, texels + 1, 8, 2);
            }
            for (uint64_t y = 0; y < 4 && 4 * j + y < h; y++) {
                uint64_t cols = w - 4 * i < 4 ? w - 4 * i : 4;
                memcpy(out + ((4 * j + y) * w + 4 * i) * px, texels + y * 4 * px, (size_t)(cols * px));
            }
        }
    }
    return CLIPMAP_OK;
}

/* Milliseconds since the writer's last heartbeat (0 if it is in the future). */
static inline uint64_t clipmap_heartbeat_age_ms(const struct clipmap_map *m) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    uint64_t now = (uint64_t)ts.tv_sec * 1000u + (uint64_t)ts.tv_nsec / 1000000u;
    uint64_t beat = clipmap_load(m, CLIPMAP_H_HEARTBEAT_MS, __ATOMIC_ACQUIRE);
    return now > beat ? now - beat : 0;
}

/* 1 when the writer shut down cleanly (flag bit 0). */
static inline int clipmap_closed(const struct clipmap_map *m) {
    return (int)(clipmap_load(m, CLIPMAP_H_FLAGS, __ATOMIC_ACQUIRE) & 1);
}

/* The request mapping (DIR/clipmap-NAME.req), mapped read-write: how a renderer asks for a
 * centre. */
struct clipmap_request {
    unsigned char *base;
    size_t len;
    char error[4608]; /* room for a path of PATH_MAX and the message around it */
};

/* Maps the request mapping `path` read-write and checks its magic, version, size and that its
 * generation equals the texel mapping's `m` (else the files belong to different starts of the
 * service: open both again). 0 on success, else -1 with r->error set. */
static inline int clipmap_request_open(const char *path, const struct clipmap_map *m, struct clipmap_request *r) {
    memset(r, 0, sizeof *r);
#ifdef O_CLOEXEC
    int fd = open(path, O_RDWR | O_NONBLOCK | O_CLOEXEC);
#else
    int fd = open(path, O_RDWR | O_NONBLOCK);
#endif
    struct stat st;
    if (fd < 0 || fstat(fd, &st) != 0) {
        snprintf(r->error, sizeof r->error, "%s: %s", path, strerror(errno));
        if (fd >= 0) close(fd);
        return -1;
    }
    if (!S_ISREG(st.st_mode) || (uint64_t)st.st_size != CLIPMAP_REQUEST_BYTES) {
        snprintf(r->error, sizeof r->error, "%s: %lld bytes: expected a regular file of %u bytes", path,
                 (long long)st.st_size, CLIPMAP_REQUEST_BYTES);
        close(fd);
        return -1;
    }
    void *p = mmap(NULL, CLIPMAP_REQUEST_BYTES, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    close(fd);
    if (p == MAP_FAILED) {
        snprintf(r->error, sizeof r->error, "%s: mmap: %s", path, strerror(errno));
        return -1;
    }
    r->base = (unsigned char *)p;
    r->len = CLIPMAP_REQUEST_BYTES;
    uint32_t version;
    uint64_t generation;
    memcpy(&version, r->base + CLIPMAP_R_VERSION, 4);
    memcpy(&generation, r->base + CLIPMAP_R_GENERATION, 8);
    char magic[9];
    for (int i = 0; i < 8; i++) magic[i] = r->base[i] >= 32 && r->base[i] < 127 ? (char)r->base[i] : '?';
    magic[8] = 0;
    if (memcmp(r->base + CLIPMAP_R_MAGIC, CLIPMAP_REQUEST_MAGIC, 8) != 0 || version != CLIPMAP_VERSION)
        snprintf(r->error, sizeof r->error, "%s: magic \"%s\", version %u: expected \"%s\", version %u", path, magic,
                 version, CLIPMAP_REQUEST_MAGIC, CLIPMAP_VERSION);
    else if (generation != m->generation)
        snprintf(r->error, sizeof r->error,
                 "%s: generation %llu, the texel mapping's is %llu: they belong to different starts of the service",
                 path, (unsigned long long)generation, (unsigned long long)m->generation);
    else
        return 0;
    munmap(r->base, r->len);
    r->base = NULL;
    return -1;
}

static inline uint64_t clipmap_now_ms_(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000u + (uint64_t)ts.tv_nsec / 1000000u;
}

/* Whether `pid` names a live process (kill with signal 0: EPERM means it exists). */
static inline int clipmap_process_alive_(uint32_t pid) {
    if (pid == 0) return 0;
    return kill((pid_t)pid, 0) == 0 || errno == EPERM;
}

/* The request lock word (CLIPMAP_R_SEQ, docs/SHM.md "Request mapping"): even, nobody writes;
 * odd, a renderer holds it, its pid in bits 1..31 and the epoch it took in bits 32..63. */
#define CLIPMAP_REQUEST_TAKEOVER_MS 100u  /* odd this long, unchanged, before its owner is looked at */
#define CLIPMAP_REQUEST_WAIT_MS 1000u     /* how long to wait for a live owner before CLIPMAP_BUSY */
static inline uint64_t clipmap_request_locked_(uint64_t free_word, uint32_t pid) {
    return (free_word & ~(uint64_t)0xFFFFFFFFu) | (((uint64_t)pid & 0x7FFFFFFFu) << 1) | 1u;
}
static inline uint64_t clipmap_request_released_(uint64_t held) { return ((held >> 32) + 1u) << 32; }
static inline uint32_t clipmap_request_owner_(uint64_t held) { return (uint32_t)((held >> 1) & 0x7FFFFFFFu); }

/* The request protocol at the lock word at byte `at` of the request mapping (CLIPMAP_R_SEQ for the
 * main request, a view request record's for a view; the fields lie at the same distances from it,
 * CLIPMAP_VR_*); with `view`, the incarnation is stored too (CLIPMAP_VR_INCARNATION). */
/* What one request stores under its lock word: a centre and velocity, or (lod_at != 0) a LOD
 * request at byte lod_at of the request mapping. */
struct clipmap_request_fields_ {
    int64_t s, t;
    double vs, vt;
    size_t lod_at;
    double height, pixel_angle;
    uint32_t effective;
    size_t pos_at; /* the request's position record (0: none written) */
    uint64_t kind; /* CLIPMAP_KIND_*: with another kind than texels, s and t are not stored */
    double x, y;
};

static inline int clipmap_request_at_(struct clipmap_request *r, size_t at, int view, uint64_t incarnation,
                                      const struct clipmap_request_fields_ *f) {
    uint64_t *seq = (uint64_t *)(void *)(r->base + at + CLIPMAP_VR_SEQ);
    uint64_t odd = 0, odd_since = 0, start = clipmap_now_ms_();
    uint32_t pid = (uint32_t)getpid();
    for (;;) {
        uint64_t v = __atomic_load_n(seq, __ATOMIC_RELAXED);
        uint64_t expect = v, mine;
        if (v & 1) {
            uint64_t now = clipmap_now_ms_();
            if (v != odd) {
                odd = v;
                odd_since = now;
            } else if (now - odd_since > CLIPMAP_REQUEST_TAKEOVER_MS) {
                if (!clipmap_process_alive_(clipmap_request_owner_(v))) {
                    /* Straight from the dead renderer's odd word to this renderer's own, at the next
                     * epoch: the word is never even over the dead renderer's partial fields, so the
                     * service never takes them. Forward only. */
                    mine = clipmap_request_locked_(clipmap_request_released_(v), pid);
                    if (__atomic_compare_exchange_n(seq, &expect, mine, 0, __ATOMIC_ACQ_REL, __ATOMIC_RELAXED))
                        goto write;
                }
                odd_since = now;
            }
            if (now - start > CLIPMAP_REQUEST_WAIT_MS) return CLIPMAP_BUSY;
            clipmap_pause();
            continue;
        }
        mine = clipmap_request_locked_(v, pid);
        if (!__atomic_compare_exchange_n(seq, &expect, mine, 0, __ATOMIC_ACQ_REL, __ATOMIC_RELAXED)) continue;
    write:
        __atomic_thread_fence(__ATOMIC_RELEASE);
#define CLIPMAP_RSTORE_(off, val) __atomic_store_n((uint64_t *)(void *)(r->base + (off)), (val), __ATOMIC_RELAXED)
        size_t counter;
        if (f->lod_at) {
            uint64_t bits_h, bits_a;
            memcpy(&bits_h, &f->height, 8);
            memcpy(&bits_a, &f->pixel_angle, 8);
            CLIPMAP_RSTORE_(f->lod_at + CLIPMAP_LOD_HEIGHT, bits_h);
            CLIPMAP_RSTORE_(f->lod_at + CLIPMAP_LOD_PIXEL_ANGLE, bits_a);
            CLIPMAP_RSTORE_(f->lod_at + CLIPMAP_LOD_EFFECTIVE, (uint64_t)f->effective);
            counter = f->lod_at + CLIPMAP_LOD_COUNT;
        } else {
            uint64_t bits_s, bits_t;
            memcpy(&bits_s, &f->vs, 8);
            memcpy(&bits_t, &f->vt, 8);
            if (f->kind == CLIPMAP_KIND_TEXELS) {
                CLIPMAP_RSTORE_(at + CLIPMAP_VR_CENTRE_S, (uint64_t)f->s);
                CLIPMAP_RSTORE_(at + CLIPMAP_VR_CENTRE_T, (uint64_t)f->t);
            }
            if (f->pos_at) {
                uint64_t bits_x, bits_y;
                memcpy(&bits_x, &f->x, 8);
                memcpy(&bits_y, &f->y, 8);
                uint64_t next = __atomic_load_n((uint64_t *)(void *)(r->base + at + CLIPMAP_VR_COUNT), __ATOMIC_RELAXED) + 1;
                CLIPMAP_RSTORE_(f->pos_at + CLIPMAP_POS_KIND, f->kind);
                CLIPMAP_RSTORE_(f->pos_at + CLIPMAP_POS_X, bits_x);
                CLIPMAP_RSTORE_(f->pos_at + CLIPMAP_POS_Y, bits_y);
                CLIPMAP_RSTORE_(f->pos_at + CLIPMAP_POS_FOR_COUNT, next);
            }
            CLIPMAP_RSTORE_(at + CLIPMAP_VR_VEL_S, bits_s);
            CLIPMAP_RSTORE_(at + CLIPMAP_VR_VEL_T, bits_t);
            counter = at + CLIPMAP_VR_COUNT;
        }
        CLIPMAP_RSTORE_(at + CLIPMAP_VR_CLIENT_PID, (uint64_t)pid);
        if (view) CLIPMAP_RSTORE_(at + CLIPMAP_VR_INCARNATION, incarnation);
        uint64_t count = __atomic_load_n((uint64_t *)(void *)(r->base + counter), __ATOMIC_RELAXED);
        CLIPMAP_RSTORE_(counter, count + 1);
#undef CLIPMAP_RSTORE_
        expect = mine; /* release: never over a word someone else stored */
        if (__atomic_compare_exchange_n(seq, &expect, clipmap_request_released_(mine), 0, __ATOMIC_ACQ_REL,
                                        __ATOMIC_RELAXED))
            return CLIPMAP_OK;
        return CLIPMAP_BUSY;
    }
}

/* CLIPMAP_NOT_VALID for a request about view *v, which has grids of its own, through the request
 * mapping of the service's mapping. */
static inline int clipmap_request_own_refused_(struct clipmap_request *r, const struct clipmap_view *v) {
    snprintf(r->error, sizeof r->error, "view \"%s\" has grids of its own: its requests go to its own mapping's "
             "request mapping as requests for main (clipmap_view_open_own, clipmap_request_path, "
             "clipmap_request_open, then clipmap_request_centre or clipmap_request_lod with no view)", v->name);
    return CLIPMAP_NOT_VALID;
}

/* Asks for centre (s, t) (level-0 texels) with velocity (vs, vt) (texels per second, 0 when
 * unknown), under the request lock: compare-and-swap from an even word w to
 * clipmap_request_locked_(w, pid), write the fields, compare-and-swap to the next epoch. A word
 * left odd for more than 100 ms whose owner is no live process (a renderer died mid-write) is
 * taken with one compare-and-swap from that odd word straight to this renderer's own odd word at
 * the next epoch (never through an even word, which would expose the dead renderer's partial
 * fields); a live owner is never overruled, however long it stalls.
 * CLIPMAP_OK, or CLIPMAP_BUSY after about a second of a live renderer holding it (or when this
 * renderer's lock was taken from it, which happens only if its pid is not visible to the others:
 * renderers must share a pid namespace). */
static inline int clipmap_request_centre(struct clipmap_request *r, int64_t s, int64_t t, double vs, double vt) {
    const struct clipmap_request_fields_ f = {s, t, vs, vt, 0, 0.0, 0.0, 0, 0, CLIPMAP_KIND_TEXELS, 0.0, 0.0};
    return clipmap_request_at_(r, CLIPMAP_R_SEQ, 0, 0, &f);
}

/* Asks for the centre at a position of coordinate kind `kind` (docs/SHM.md, "Positions in longitude /
 * latitude or map coordinates"): CLIPMAP_KIND_LONLAT (x longitude, y latitude, WGS 84 degrees) or
 * CLIPMAP_KIND_MAP (map x, y of the texture's CRS), with velocity (vs, vt) in level-0 texels per
 * second, as clipmap_request_centre asks. The service converts it through the texture's
 * georeferencing; it refuses a texture without one or a position outside the texture or the
 * projection's domain (STATS position_requests_refused, its log says why) and the centre stays.
 * The texel centre fields keep the previous request's. CLIPMAP_NOT_VALID for another kind. */
static inline int clipmap_request_position(struct clipmap_request *r, uint64_t kind, double x, double y, double vs,
                                           double vt) {
    if (kind != CLIPMAP_KIND_LONLAT && kind != CLIPMAP_KIND_MAP) {
        snprintf(r->error, sizeof r->error, "coordinate kind %llu: expected CLIPMAP_KIND_LONLAT (1) or CLIPMAP_KIND_MAP "
                 "(2); a centre in texels is clipmap_request_centre", (unsigned long long)kind);
        return CLIPMAP_NOT_VALID;
    }
    struct clipmap_request_fields_ f = {0, 0, vs, vt, 0, 0.0, 0.0, 0, CLIPMAP_R_POSITION, kind, x, y};
    return clipmap_request_at_(r, CLIPMAP_R_SEQ, 0, 0, &f);
}

/* The latest request in the main request record as found (no lock taken: a reading for display):
 * its count, texel centre, and the position record's kind, x, y and the count it belongs to
 * (the position is the request's centre when for_count == count and kind != CLIPMAP_KIND_TEXELS). */
struct clipmap_request_seen {
    uint64_t count, for_count, kind;
    int64_t s, t;
    double x, y;
};
static inline void clipmap_request_read(const struct clipmap_request *r, struct clipmap_request_seen *out) {
#define CLIPMAP_RLOAD_(off) __atomic_load_n((const uint64_t *)(const void *)(r->base + (off)), __ATOMIC_ACQUIRE)
    uint64_t bx = CLIPMAP_RLOAD_(CLIPMAP_R_POSITION + CLIPMAP_POS_X), by = CLIPMAP_RLOAD_(CLIPMAP_R_POSITION + CLIPMAP_POS_Y);
    out->count = CLIPMAP_RLOAD_(CLIPMAP_R_SEQ + CLIPMAP_VR_COUNT);
    out->s = (int64_t)CLIPMAP_RLOAD_(CLIPMAP_R_SEQ + CLIPMAP_VR_CENTRE_S);
    out->t = (int64_t)CLIPMAP_RLOAD_(CLIPMAP_R_SEQ + CLIPMAP_VR_CENTRE_T);
    out->kind = CLIPMAP_RLOAD_(CLIPMAP_R_POSITION + CLIPMAP_POS_KIND);
    out->for_count = CLIPMAP_RLOAD_(CLIPMAP_R_POSITION + CLIPMAP_POS_FOR_COUNT);
    memcpy(&out->x, &bx, 8);
    memcpy(&out->y, &by, 8);
#undef CLIPMAP_RLOAD_
}

/* Asks for view *v's centre as clipmap_request_centre does for `main` (which it is for `main`),
 * under the lock word of the view's request record (CLIPMAP_R_VIEWS + CLIPMAP_VIEW_REQUEST_BYTES x
 * record), storing the incarnation clipmap_view_find kept with the fields: the service ignores a
 * request for an incarnation that is no longer the record's (a removed view). CLIPMAP_OK,
 * CLIPMAP_BUSY as clipmap_request_centre's; CLIPMAP_NOT_VALID (r->error says why) when the view's
 * record has no request record (records 24 to 63: ask through the control socket, `VIEW CENTRE`),
 * or the view has grids of its own (v->own: ask the request mapping of its own mapping for `main`,
 * clipmap_request_centre). */
static inline int clipmap_request_view_centre(struct clipmap_request *r, const struct clipmap_view *v, int64_t s,
                                              int64_t t, double vs, double vt) {
    if (v->record == CLIPMAP_VIEW_MAIN) return clipmap_request_centre(r, s, t, vs, vt);
    if (v->own) return clipmap_request_own_refused_(r, v);
    if (v->record >= CLIPMAP_MAX_VIEW_REQUESTS) {
        snprintf(r->error, sizeof r->error, "view \"%s\" is view record %u: the request mapping has request records "
                 "for view records 0 to %u only", v->name, v->record, CLIPMAP_MAX_VIEW_REQUESTS - 1);
        return CLIPMAP_NOT_VALID;
    }
    const struct clipmap_request_fields_ f = {s, t, vs, vt, 0, 0.0, 0.0, 0, 0, CLIPMAP_KIND_TEXELS, 0.0, 0.0};
    return clipmap_request_at_(r, CLIPMAP_R_VIEWS + (size_t)v->record * CLIPMAP_VIEW_REQUEST_BYTES, 1, v->incarnation,
                               &f);
}

/* Asks the service for the levels view *v (`main` too) can use from `height` level-0 texels above
 * the texture, one screen pixel spanning `pixel_angle` radians, addressing `effective` levels at once
 * (0: all): the service moves the view's LOD offset to the finest level sampled there and holds and
 * reads nothing finer for it (docs/VIEWS.md, "Virtual views"). Under the view's lock word, as
 * clipmap_request_view_centre. CLIPMAP_OK, CLIPMAP_BUSY as there; CLIPMAP_NOT_VALID (r->error says
 * why) for a height or angle that is not a finite number above 0 (the angle below pi), a view
 * record without a request record, or a view with grids of its own (ask its own mapping's request
 * mapping for `main`: v NULL). */
static inline int clipmap_request_lod(struct clipmap_request *r, const struct clipmap_view *v, double height,
                                      double pixel_angle, uint32_t effective) {
    if (!(height > 0 && height <= DBL_MAX) || !(pixel_angle > 0 && pixel_angle < 3.141592653589793)) {
        snprintf(r->error, sizeof r->error, "LOD request: height %g and pixel angle %g: expected a finite height above "
                 "0 (level-0 texels) and an angle above 0 and below pi (radians)", height, pixel_angle);
        return CLIPMAP_NOT_VALID;
    }
    int main_view = v == NULL || v->record == CLIPMAP_VIEW_MAIN;
    if (!main_view && v->own) return clipmap_request_own_refused_(r, v);
    if (!main_view && v->record >= CLIPMAP_MAX_VIEW_REQUESTS) {
        snprintf(r->error, sizeof r->error, "view \"%s\" is view record %u: the request mapping has request records "
                 "for view records 0 to %u only", v->name, v->record, CLIPMAP_MAX_VIEW_REQUESTS - 1);
        return CLIPMAP_NOT_VALID;
    }
    const size_t index = main_view ? 0 : 1 + (size_t)v->record;
    const struct clipmap_request_fields_ f = {0, 0, 0.0, 0.0, CLIPMAP_R_LOD + index * CLIPMAP_LOD_RECORD_BYTES,
                                              height, pixel_angle, effective, 0, CLIPMAP_KIND_TEXELS, 0.0, 0.0};
    if (main_view) return clipmap_request_at_(r, CLIPMAP_R_SEQ, 0, 0, &f);
    return clipmap_request_at_(r, CLIPMAP_R_VIEWS + (size_t)v->record * CLIPMAP_VIEW_REQUEST_BYTES, 1, v->incarnation,
                               &f);
}

static inline void clipmap_request_close(struct clipmap_request *r) {
    if (r->base) munmap(r->base, r->len);
    r->base = NULL;
}

#endif /* CLIPMAP_SHM_H */
