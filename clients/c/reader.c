/* reader.c: reads random texel blocks inside the published valid regions of a clip texture served
 * by `clipmapd --source hash` and checks every texel against the verification texture.
 *
 *   cc -O2 -I include clients/c/reader.c -o reader
 *   ./reader /dev/shm/clipmap-hash.map 1000000 [seed [seconds]]
 *
 * Stops after READS texels or SECONDS seconds (default 120), whichever comes first. Blocks are
 * small (up to 8x8), large (up to 128x128) or placed across a tile corner, so reads cross tile
 * edges and the grid's toroidal wrap. Blocks over a missing tile, or that find the writer busy or
 * the snapshot stale, are skipped (and the snapshot taken again), not failures.
 * Prints "N passed, M failed (...)". Exit status: 0 no mismatch, 1 a mismatch, 2 the mapping was
 * refused (at open, or published state out of bounds), with the reason on stderr.
 *
 *   ./reader MAPPING --dump LEVEL S0,T0,S1,T1 OUT [SECONDS]
 *
 * writes the texels of [S0, S1) x [T0, T1) of LEVEL (any texture, not only the hash texture) to the
 * file OUT as they are stored: rows in increasing t, s fastest, bytes per texel as the header says,
 * no header (what `clipmap-read --dump-level ... --out FILE.raw` and the Python reader's --dump
 * write). The region must lie inside the level's published valid region; the reader tries again
 * for up to SECONDS (default 5) while it is not (the service still loading it) and then exits 2.
 *
 *   ./reader MAPPING --tile LEVEL S T OUT [SECONDS]
 *   ./reader MAPPING --decode LEVEL S T OUT [SECONDS]
 *
 * write tile (S, T) of LEVEL to the file OUT: --tile its slot's bytes as they are (clipmap_read_tile;
 * for a block-compressed format its blocks, docs/SHM.md "Block-compressed formats"), --decode a BC1,
 * BC4, BC5 or BC7 tile's texels decoded (clipmap_decode_blocks: TW x TH texels of 4, 1, 2 or 4 bytes,
 * rows in increasing t). Each prints "level L tile S T bytes N" and tries again for up to SECONDS
 * (default 5) while the slot does not hold the tile ready or default; a tile missing, never ready or
 * not decoded here (a texel format) exits 2 saying why. The random reads and --dump refuse a block format
 * (exit 2): its texels have no address of their own.
 *
 *   ./reader MAPPING --heights
 *
 * prints what the header's heights block says, one line: "not heights", or "heights STORAGE
 * scale S offset O nodata N|none levels RULE" (numbers as %.17g; the Python reader's --heights
 * prints the same line).
 *
 *   ./reader MAPPING --georef
 *
 * prints what the georef block says (docs/SHM.md, "Georef block"): "not georeferenced", or a line
 * "georef epsg CODE|none wraps 0|1 origin X Y", a line "level K A B D E" per level (its GDAL
 * geotransform terms [1], [2], [4], [5]) and a last line "definition TEXT" (numbers as %.17g; the
 * Python reader's --georef prints the same lines).
 *
 *   ./reader MAPPING --map-of-texel LEVEL S T
 *
 * prints the map coordinates of the continuous texel position (S, T) of LEVEL (clipmap_map_of_texel),
 * one line "X Y" (%.17g; the Python reader's --map-of-texel prints the same), or "not georeferenced".
 *
 *   ./reader MAPPING --ranges
 *
 * prints the published range of every tile a slot holds ready or default (clipmap_tile_range), one
 * line each: "LEVEL S T MIN MAX" (metres as %.17g; "nan nan" when every texel is nodata), and
 *
 *   ./reader MAPPING --heights-region
 *
 * every enabled level's published region in metres: per level a line "level L region S0 T0 S1 T1",
 * then one line per row (increasing t) of each texel's metres as %.17g or "nodata". Both exit 2
 * for a mapping whose texels are not heights; the Python reader's options print the same.
 *
 * Views (docs/SHM.md, "Views"): `--view NAME`, anywhere after MAPPING, reads that view's snapshot
 * instead of the primary view's (`main`, the default) and checks the texels under its regions the
 * same way; the summary line ends with "view NAME". A name no view carries is refused (exit 2)
 * with the names of the views that exist; a view removed while it is read ends the run with the
 * summary, "view NAME was removed: ..." on stderr and exit status 3. A view with grids of its own
 * (views block version 2, record state 2) is read in its own mapping, DIR/clipmap-NAME@VIEW.map
 * beside MAPPING (which must then be named DIR/clipmap-NAME.map): that mapping is opened with every
 * check MAPPING gets (and must be owned by MAPPING's owner, not a symbolic link), and its `main` is
 * the view; a missing or refused own mapping exits 2 naming its path.
 *
 *   ./reader MAPPING --views
 *
 * lists the views that exist, one line each: "view main primary", then "view NAME record R
 * incarnation I weight W" for each live view record in record order (with " own" at the end for a
 * view with grids of its own), and
 *
 *   ./reader MAPPING --snapshot [--view NAME]
 *
 * prints the view's snapshot: its line as --views prints it, "tick T min_lod X centre S T border B",
 * then one line per level: "level K centre S T region S0 T0 S1 T1 enabled E tick U" (floats as
 * %.17g; exit 3 when the view was removed; for a view with grids of its own, its own mapping's
 * `main` snapshot). The Python reader's options print the same.
 *
 * `--lod HEIGHT,ANGLE[,EFFECTIVE]`, anywhere after MAPPING, first asks the service for the view's
 * levels (clipmap_request_lod: HEIGHT level-0 texels above the texture, a pixel of ANGLE radians,
 * EFFECTIVE levels addressed at once, 0 or omitted: all) through MAPPING's request mapping (its
 * name with .map changed to .req; for a view with grids of its own, its own mapping's request
 * mapping, as a request for its `main`), then reads as without it; a request that cannot be made
 * exits 2 with why. */
#include "clipmap_shm.h"

#include <stdlib.h>

enum { SMALL = 8, LARGE = 128 };

static uint64_t next(uint64_t *rng) {
    *rng = clipmap_splitmix64(*rng);
    return *rng;
}

/* A random extent [lo, lo + n) inside [v0, v1) along one axis, tile size `tile`: mode 0 small,
 * 1 large, 2 across a tile edge where the region has one. */
static void pick(uint64_t *rng, int mode, int64_t v0, int64_t v1, uint64_t tile, int64_t *lo, uint64_t *n) {
    uint64_t span = (uint64_t)(v1 - v0);
    if (mode == 2) {
        /* The first tile edge at or after a random texel; a block a few texels either side. */
        int64_t at = v0 + (int64_t)(next(rng) % span);
        uint64_t e = ((uint64_t)at / tile + 1) * tile;
        if (e > (uint64_t)v0 && e < (uint64_t)v1) {
            uint64_t before = 1 + next(rng) % SMALL, after = 1 + next(rng) % SMALL;
            int64_t a = (int64_t)e - (int64_t)before;
            if (a < v0) a = v0;
            uint64_t b = e + after;
            if (b > (uint64_t)v1) b = (uint64_t)v1;
            *lo = a;
            *n = b - (uint64_t)a;
            return;
        }
        mode = 0;
    }
    uint64_t most = mode == 0 ? SMALL : LARGE;
    uint64_t w = 1 + next(rng) % (span < most ? span : most);
    *lo = v0 + (int64_t)(next(rng) % (span - w + 1));
    *n = w;
}

/* A view's line of --views and --snapshot. */
static void print_view(const char *name, uint32_t record, uint64_t incarnation, double weight, int own) {
    if (record == CLIPMAP_VIEW_MAIN)
        printf("view %s primary\n", name);
    else
        printf("view %s record %u incarnation %llu weight %.17g%s\n", name, record, (unsigned long long)incarnation,
               weight, own ? " own" : "");
}

/* The view's snapshot: in the service's mapping m, or for a view with grids of its own `main`'s of
 * its own mapping (and whether the view is still the one bound). */
static int view_snapshot(const struct clipmap_map *m, const struct clipmap_view *v, const struct clipmap_map *own,
                         struct clipmap_snapshot *snap) {
    return v->own ? clipmap_view_own_snapshot(m, v, own, snap) : clipmap_view_snapshot(m, v, snap);
}

/* --tile / --decode LEVEL S T OUT [SECONDS]: the tile's bytes, or its texels decoded, into OUT. */
static int tile(int argc, char **argv, const struct clipmap_map *tm) {
    unsigned level;
    long long S, T;
    char extra;
    int decode = strcmp(argv[2], "--decode") == 0;
    double seconds = argc > 7 ? strtod(argv[7], NULL) : 5.0;
    if (argc < 7 || argc > 8 || sscanf(argv[3], "%u%c", &level, &extra) != 1 ||
        sscanf(argv[4], "%lld%c", &S, &extra) != 1 || sscanf(argv[5], "%lld%c", &T, &extra) != 1 || !(seconds >= 0)) {
        fprintf(stderr, "usage: %s MAPPING %s LEVEL S T OUT [SECONDS]\n", argv[0], argv[2]);
        return 2;
    }
    if (level >= tm->level_count) {
        fprintf(stderr, "clipmap reader: %s: %s level %u: the texture has levels 0 to %u\n", argv[1], argv[2], level,
                tm->level_count - 1);
        return 2;
    }
    const struct clipmap_level_desc *d = &tm->levels[level];
    uint32_t px = clipmap_decoded_bytes(tm->texel_format);
    if (decode && px == 0) {
        fprintf(stderr, "clipmap reader: %s: --decode: texel format %u is not decoded here: this reader decodes bc1, "
                "bc4, bc5 and bc7 (20, 21, 22, 23); read the tile's bytes with --tile\n", argv[1], tm->texel_format);
        return 2;
    }
    size_t n = (size_t)d->slot_bytes, texels = (size_t)(d->tile[0] * d->tile[1] * px);
    unsigned char *buf = malloc(n), *dec = decode ? malloc(texels) : NULL;
    if (buf == NULL || (decode && dec == NULL)) {
        fprintf(stderr, "clipmap reader: %s: cannot allocate %zu bytes\n", argv[2], n + texels);
        free(buf);
        free(dec);
        return 2;
    }
    struct timespec start, now;
    clock_gettime(CLOCK_MONOTONIC, &start);
    int rc;
    for (;;) {
        rc = clipmap_read_tile(tm, level, S, T, buf);
        clock_gettime(CLOCK_MONOTONIC, &now);
        double spent = (double)(now.tv_sec - start.tv_sec) + (double)(now.tv_nsec - start.tv_nsec) * 1e-9;
        if (rc == CLIPMAP_OK || (rc != CLIPMAP_STALE && rc != CLIPMAP_BUSY) || spent >= seconds) break;
        struct timespec pause = {0, 10 * 1000 * 1000};
        nanosleep(&pause, NULL);
    }
    if (rc != CLIPMAP_OK) {
        const char *why = rc == CLIPMAP_NOT_VALID ? "the level has no such tile"
                          : rc == CLIPMAP_MISSING ? "the tile is missing (the service could not read it)"
                          : rc == CLIPMAP_STALE   ? "its slot never held it ready"
                                                  : "the writer kept its tag busy";
        fprintf(stderr, "clipmap reader: %s: %s level %u tile (%lld, %lld): %s\n", argv[1], argv[2], level, S, T, why);
        free(buf);
        free(dec);
        return 2;
    }
    if (decode && clipmap_decode_blocks(tm->texel_format, buf, n, d->tile[0], d->tile[1], dec) != CLIPMAP_OK) {
        fprintf(stderr, "clipmap reader: %s: --decode level %u: %zu bytes are not the tile's blocks\n", argv[1], level, n);
        free(buf);
        free(dec);
        return 2;
    }
    FILE *f = fopen(argv[6], "wb");
    int ok = f != NULL && fwrite(decode ? dec : buf, 1, decode ? texels : n, f) == (decode ? texels : n);
    if (f != NULL && fclose(f) != 0) ok = 0;
    free(buf);
    free(dec);
    if (!ok) {
        fprintf(stderr, "clipmap reader: cannot write %s: %s\n", argv[6], strerror(errno));
        remove(argv[6]);
        return 2;
    }
    printf("level %u tile %lld %lld bytes %zu\n", level, S, T, decode ? texels : n);
    return 0;
}

/* --dump LEVEL S0,T0,S1,T1 OUT [SECONDS]: the region's stored bytes into OUT (see the top). */
static int dump(int argc, char **argv, const struct clipmap_map *m, const struct clipmap_view *v,
                const struct clipmap_map *own, const struct clipmap_map *tm) {
    unsigned level = 0;
    long long s0, t0, s1, t1;
    char extra;
    double seconds = argc > 6 ? strtod(argv[6], NULL) : 5.0;
    if (argc < 6 || argc > 7 || sscanf(argv[3], "%u%c", &level, &extra) != 1 ||
        sscanf(argv[4], "%lld,%lld,%lld,%lld%c", &s0, &t0, &s1, &t1, &extra) != 4 || !(seconds >= 0)) {
        fprintf(stderr, "usage: %s MAPPING --dump LEVEL S0,T0,S1,T1 OUT [SECONDS]\n", argv[0]);
        return 2;
    }
    if (level >= tm->level_count) {
        fprintf(stderr, "clipmap reader: %s: --dump level %u: the texture has levels 0 to %u\n", argv[1], level,
                tm->level_count - 1);
        return 2;
    }
    const struct clipmap_level_desc *d = &tm->levels[level];
    if (s0 < 0 || t0 < 0 || s0 >= s1 || t0 >= t1 || (uint64_t)s1 > d->size[0] || (uint64_t)t1 > d->size[1] ||
        (uint64_t)(s1 - s0) * (uint64_t)(t1 - t0) > 4096u * 4096u) {
        fprintf(stderr, "clipmap reader: %s: --dump region %lld,%lld,%lld,%lld: expected 0 <= S0 < S1 <= %llu and "
                "0 <= T0 < T1 <= %llu, at most 4096x4096 texels\n", argv[1], s0, t0, s1, t1,
                (unsigned long long)d->size[0], (unsigned long long)d->size[1]);
        return 2;
    }
    uint64_t w = (uint64_t)(s1 - s0), h = (uint64_t)(t1 - t0), n = w * h * tm->bytes_per_texel;
    unsigned char *buf = malloc(n);
    if (buf == NULL) {
        fprintf(stderr, "clipmap reader: --dump: cannot allocate %llu bytes\n", (unsigned long long)n);
        return 2;
    }
    struct timespec start, now;
    clock_gettime(CLOCK_MONOTONIC, &start);
    struct clipmap_snapshot snap;
    memset(&snap, 0, sizeof snap);
    int rc;
    for (;;) {
        rc = view_snapshot(m, v, own, &snap);
        if (rc == CLIPMAP_OK) rc = clipmap_read_region(tm, &snap, level, s0, t0, w, h, buf);
        clock_gettime(CLOCK_MONOTONIC, &now);
        double spent = (double)(now.tv_sec - start.tv_sec) + (double)(now.tv_nsec - start.tv_nsec) * 1e-9;
        int again = rc == CLIPMAP_NOT_VALID || rc == CLIPMAP_STALE || rc == CLIPMAP_BUSY;
        if (rc == CLIPMAP_OK || !again || spent >= seconds) break;
        struct timespec pause = {0, 10 * 1000 * 1000};
        nanosleep(&pause, NULL);
    }
    if (rc != CLIPMAP_OK) {
        static const char *const why[] = {"ok", "not inside the level's published valid region", "a tile of it is "
                                          "missing (the service could not read it)", "the writer kept it busy",
                                          "the slots moved on", "published state out of bounds", "the view was removed",
                                          "no such view"};
        const struct clipmap_level_state *st = &snap.levels[level];
        fprintf(stderr, "clipmap reader: %s: --dump level %u region [%lld, %lld) x [%lld, %lld): %s; the level "
                "publishes [%lld, %lld) x [%lld, %lld)%s\n", argv[1], level, s0, s1, t0, t1,
                rc >= 0 && rc <= CLIPMAP_NO_VIEW ? why[rc] : "?", (long long)st->valid[0], (long long)st->valid[2],
                (long long)st->valid[1], (long long)st->valid[3], st->enabled ? "" : " (disabled)");
        free(buf);
        return rc == CLIPMAP_REMOVED ? 3 : 2;
    }
    FILE *f = fopen(argv[5], "wb");
    int ok = f != NULL && fwrite(buf, 1, n, f) == n;
    if (f != NULL && fclose(f) != 0) ok = 0;
    free(buf);
    if (!ok) {
        fprintf(stderr, "clipmap reader: cannot write %s: %s\n", argv[5], strerror(errno));
        return 2;
    }
    printf("level %u region %lld %lld %lld %lld bytes %llu tick %llu\n", level, s0, t0, s1, t1,
           (unsigned long long)n, (unsigned long long)snap.tick);
    return 0;
}

int main(int argc, char **argv) {
    /* --view NAME, anywhere after MAPPING: taken out of argv, which then reads as before. */
    const char *view_name = "main";
    const char *lod = NULL;
    int kept = 0;
    for (int i = 0; i < argc; i++) {
        if (i > 0 && strcmp(argv[i], "--lod") == 0) {
            if (i + 1 >= argc) {
                fprintf(stderr, "usage: %s MAPPING ... --lod HEIGHT,ANGLE[,EFFECTIVE]: --lod needs its numbers\n", argv[0]);
                return 2;
            }
            lod = argv[++i];
            continue;
        }
        if (i > 0 && strcmp(argv[i], "--view") == 0) {
            if (i + 1 >= argc) {
                fprintf(stderr, "usage: %s MAPPING READS [SEED [SECONDS]] [--view NAME]: --view needs a name\n", argv[0]);
                return 2;
            }
            view_name = argv[++i];
            continue;
        }
        argv[kept++] = argv[i];
    }
    argc = kept;
    argv[argc] = NULL;
    if (argc < 3) {
        fprintf(stderr, "usage: %s MAPPING READS [SEED [SECONDS]] [--view NAME]\n", argv[0]);
        return 2;
    }
    struct clipmap_map m;
    if (clipmap_open(argv[1], &m) != 0) {
        fprintf(stderr, "clipmap reader: %s\n", m.error);
        return 2;
    }
    if (strcmp(argv[2], "--views") == 0) {
        static struct clipmap_view_list list;
        int rc = clipmap_views(&m, &list);
        if (rc != CLIPMAP_OK) {
            fprintf(stderr, "clipmap reader: %s: %s\n", argv[1], list.error);
        } else {
            for (uint32_t i = 0; i < list.count; i++)
                print_view(list.views[i].name, list.views[i].record, list.views[i].incarnation, list.views[i].weight,
                           list.views[i].own);
        }
        clipmap_close(&m);
        return rc == CLIPMAP_OK ? 0 : 2;
    }
    static struct clipmap_view view;
    if (clipmap_view_find(&m, view_name, &view) != CLIPMAP_OK) {
        fprintf(stderr, "clipmap reader: %s: %s\n", argv[1], view.error);
        clipmap_close(&m);
        return 2;
    }
    /* tm: the mapping whose texels the view reads (a view with grids of its own: its own mapping). */
    static struct clipmap_map own;
    const struct clipmap_map *tm = &m;
    if (view.own) {
        if (clipmap_view_open_own(&m, &view, &own) != 0) {
            fprintf(stderr, "clipmap reader: %s: %s\n", argv[1], own.error);
            clipmap_close(&m);
            return 2;
        }
        tm = &own;
    }
    if (lod != NULL) {
        double height = 0, angle = 0;
        unsigned effective = 0;
        int got = sscanf(lod, "%lf,%lf,%u", &height, &angle, &effective);
        char req_path[4096];
        if (got < 2 || clipmap_request_path(tm, req_path, sizeof req_path) != 0) {
            fprintf(stderr, "clipmap reader: --lod %s: expected HEIGHT,ANGLE[,EFFECTIVE] (such as 12000,0.001) and a "
                    "MAPPING named *.map%s%s\n", lod, got < 2 ? "" : ": ", got < 2 ? "" : req_path);
            clipmap_close(&own);
            clipmap_close(&m);
            return 2;
        }
        struct clipmap_request req;
        int rc = clipmap_request_open(req_path, tm, &req);
        /* A view with grids of its own asks its own mapping's request mapping for `main`. */
        if (rc == 0)
            rc = clipmap_request_lod(&req, view.own ? NULL : &view, height, angle, effective) == CLIPMAP_OK ? 0 : -1;
        if (rc != 0) {
            fprintf(stderr, "clipmap reader: %s: LOD request: %s\n", req_path, req.error);
            clipmap_request_close(&req);
            clipmap_close(&own);
            clipmap_close(&m);
            return 2;
        }
        clipmap_request_close(&req);
    }
    if (strcmp(argv[2], "--snapshot") == 0) {
        struct clipmap_snapshot snap;
        int rc = view_snapshot(&m, &view, &own, &snap);
        if (rc != CLIPMAP_OK) {
            fprintf(stderr, "clipmap reader: %s: %s\n", argv[1], snap.error);
            clipmap_close(&own);
            clipmap_close(&m);
            return rc == CLIPMAP_REMOVED ? 3 : 2;
        }
        print_view(view.name, view.record, view.incarnation, view.weight, view.own);
        printf("tick %llu min_lod %.17g centre %lld %lld border %llu\n", (unsigned long long)snap.tick, snap.min_lod,
               (long long)snap.centre[0], (long long)snap.centre[1], (unsigned long long)snap.invalid_border);
        for (uint32_t k = 0; k < snap.level_count; k++) {
            const struct clipmap_level_state *st = &snap.levels[k];
            printf("level %u centre %lld %lld region %lld %lld %lld %lld enabled %d tick %llu\n", k,
                   (long long)st->centre[0], (long long)st->centre[1], (long long)st->valid[0], (long long)st->valid[1],
                   (long long)st->valid[2], (long long)st->valid[3], st->enabled, (unsigned long long)st->updated_tick);
        }
        clipmap_close(&own);
        clipmap_close(&m);
        return 0;
    }
    if (strcmp(argv[2], "--ranges") == 0 || strcmp(argv[2], "--heights-region") == 0) {
        if (!tm->heights) {
            fprintf(stderr, "clipmap reader: %s: the texels are not heights (heights block all zero)\n", argv[1]);
            clipmap_close(&own);
            clipmap_close(&m);
            return 2;
        }
        int rc = 0;
        if (strcmp(argv[2], "--ranges") == 0) {
            for (uint32_t k = 0; k < tm->level_count; k++) {
                const struct clipmap_level_desc *d = &tm->levels[k];
                for (uint64_t slot = 0; slot < d->slot_count; slot++) {
                    size_t tag = (size_t)(d->tags_offset + slot * CLIPMAP_TAG_BYTES);
                    int64_t S = (int64_t)clipmap_load(tm, tag + CLIPMAP_T_TILE_S, __ATOMIC_RELAXED);
                    int64_t T = (int64_t)clipmap_load(tm, tag + CLIPMAP_T_TILE_T, __ATOMIC_RELAXED);
                    double lo, hi;
                    if (clipmap_tile_range(tm, k, S, T, &lo, &hi) == CLIPMAP_OK)
                        printf("%u %lld %lld %.17g %.17g\n", k, (long long)S, (long long)T, lo, hi);
                }
            }
        } else {
            struct clipmap_snapshot snap;
            int src = view_snapshot(&m, &view, &own, &snap);
            if (src != CLIPMAP_OK) {
                fprintf(stderr, "clipmap reader: %s: %s\n", argv[1], snap.error);
                rc = src == CLIPMAP_REMOVED ? 3 : 2;
            }
            for (uint32_t k = 0; rc == 0 && k < snap.level_count; k++) {
                const struct clipmap_level_state *st = &snap.levels[k];
                if (!st->enabled) continue;
                uint64_t w = (uint64_t)(st->valid[2] - st->valid[0]), h = (uint64_t)(st->valid[3] - st->valid[1]);
                unsigned char *buf = malloc((size_t)(w * h * tm->bytes_per_texel));
                int r = buf ? clipmap_read_region(tm, &snap, k, st->valid[0], st->valid[1], w, h, buf) : -1;
                if (r != CLIPMAP_OK) {
                    fprintf(stderr, "clipmap reader: level %u region: read failed (%d)\n", k, r);
                    free(buf);
                    rc = 1;
                    break;
                }
                printf("level %u region %lld %lld %lld %lld\n", k, (long long)st->valid[0], (long long)st->valid[1],
                       (long long)st->valid[2], (long long)st->valid[3]);
                for (uint64_t i = 0; i < w * h; i++) {
                    const unsigned char *p = buf + i * tm->bytes_per_texel;
                    double v;
                    if (tm->texel_format == CLIPMAP_FORMAT_L32F) {
                        float f;
                        memcpy(&f, p, 4);
                        v = f;
                    } else if (tm->texel_format == CLIPMAP_FORMAT_L16) {
                        uint16_t u;
                        memcpy(&u, p, 2);
                        v = u;
                    } else {
                        int16_t x;
                        memcpy(&x, p, 2);
                        v = x;
                    }
                    if (tm->height_has_nodata && v == tm->height_nodata)
                        printf("nodata");
                    else
                        printf("%.17g", v * tm->height_scale + tm->height_offset);
                    putchar(i % w == w - 1 ? '\n' : ' ');
                }
                free(buf);
            }
        }
        clipmap_close(&own);
        clipmap_close(&m);
        return rc;
    }
    if (strcmp(argv[2], "--tile") == 0 || strcmp(argv[2], "--decode") == 0) {
        int rc = tile(argc, argv, tm);
        clipmap_close(&own);
        clipmap_close(&m);
        return rc;
    }
    if (tm->block != 1 && (strcmp(argv[2], "--dump") == 0 || argv[2][0] != '-')) {
        fprintf(stderr, "clipmap reader: %s: texel format %u is block-compressed (4 x 4 blocks of %u bytes): its texels "
                "have no address of their own; read whole tiles with --tile or --decode\n", argv[1], tm->texel_format,
                tm->bytes_per_texel);
        clipmap_close(&own);
        clipmap_close(&m);
        return 2;
    }
    if (strcmp(argv[2], "--dump") == 0) {
        int rc = dump(argc, argv, &m, &view, &own, tm);
        clipmap_close(&own);
        clipmap_close(&m);
        return rc;
    }
    if (strcmp(argv[2], "--map-of-texel") == 0) {
        unsigned level;
        char extra;
        double st[2], xy[2];
        int rc = 0;
        if (argc != 6 || sscanf(argv[3], "%u%c", &level, &extra) != 1 || sscanf(argv[4], "%lf%c", &st[0], &extra) != 1 ||
            sscanf(argv[5], "%lf%c", &st[1], &extra) != 1) {
            fprintf(stderr, "usage: %s MAPPING --map-of-texel LEVEL S T\n", argv[0]);
            rc = 2;
        } else if (level >= tm->level_count) {
            fprintf(stderr, "clipmap reader: %s: no level %u (the mapping has %u)\n", argv[1], level, tm->level_count);
            rc = 2;
        } else if (clipmap_map_of_texel(tm, level, st[0], st[1], xy) != 0) {
            printf("not georeferenced\n");
        } else {
            printf("%.17g %.17g\n", xy[0], xy[1]);
        }
        clipmap_close(&own);
        clipmap_close(&m);
        return rc;
    }
    if (strcmp(argv[2], "--request") == 0) {
        /* MAPPING --request: the main request as found in the request mapping, its coordinate kind
         * and position (docs/SHM.md, "Positions in longitude / latitude or map coordinates"). */
        static const char *const kinds[] = {"texels", "lonlat", "map"};
        char path[4096];
        struct clipmap_request r;
        int rc = 0;
        if (clipmap_request_path(&m, path, sizeof path) != 0 || clipmap_request_open(path, &m, &r) != 0) {
            fprintf(stderr, "clipmap reader: %s: no request mapping to read\n", argv[1]);
            rc = 1;
        } else {
            struct clipmap_request_seen q;
            clipmap_request_read(&r, &q);
            const int positioned = q.count != 0 && q.for_count == q.count && q.kind != CLIPMAP_KIND_TEXELS;
            printf("request count %llu centre %lld %lld kind %s", (unsigned long long)q.count, (long long)q.s,
                   (long long)q.t, !positioned ? "texels" : q.kind <= CLIPMAP_KIND_MAP ? kinds[q.kind] : "unknown");
            if (positioned) printf(" position %.17g %.17g", q.x, q.y);
            printf("\n");
            clipmap_request_close(&r);
        }
        clipmap_close(&own);
        clipmap_close(&m);
        return rc;
    }
    if (strcmp(argv[2], "--georef") == 0) {
        if (!tm->georef) {
            printf("not georeferenced\n");
        } else {
            char epsg[16] = "none";
            if (tm->georef_epsg != 0) snprintf(epsg, sizeof epsg, "%u", tm->georef_epsg);
            printf("georef epsg %s wraps %d origin %.17g %.17g\n", epsg, tm->georef_wraps, tm->georef_origin[0],
                   tm->georef_origin[1]);
            for (uint32_t k = 0; k < tm->level_count; k++)
                printf("level %u %.17g %.17g %.17g %.17g\n", k, tm->georef_terms[k][0], tm->georef_terms[k][1],
                       tm->georef_terms[k][2], tm->georef_terms[k][3]);
            printf("definition %s\n", tm->georef_definition);
        }
        clipmap_close(&own);
        clipmap_close(&m);
        return 0;
    }
    if (strcmp(argv[2], "--heights") == 0) {
        static const char *const rules[] = {"mean", "point", "min", "max"};
        if (!tm->heights) {
            printf("not heights\n");
        } else {
            const char *storage = tm->texel_format == CLIPMAP_FORMAT_L32F ? "l32f"
                                  : tm->texel_format == CLIPMAP_FORMAT_L16 ? "l16" : "l16i";
            char nodata[40] = "none";
            if (tm->height_has_nodata) snprintf(nodata, sizeof nodata, "%.17g", tm->height_nodata);
            printf("heights %s scale %.17g offset %.17g nodata %s levels %s\n", storage, tm->height_scale,
                   tm->height_offset, nodata, rules[tm->height_rule]);
        }
        clipmap_close(&own);
        clipmap_close(&m);
        return 0;
    }
    char *end;
    unsigned long long reads = strtoull(argv[2], &end, 10);
    int bad = *argv[2] == 0 || *end != 0;
    uint64_t rng = 1;
    if (argc > 3) {
        rng = strtoull(argv[3], &end, 10);
        bad |= *argv[3] == 0 || *end != 0;
    }
    double seconds = 120.0;
    if (argc > 4) {
        seconds = strtod(argv[4], &end);
        bad |= *argv[4] == 0 || *end != 0;
    }
    if (bad) {
        fprintf(stderr, "usage: %s MAPPING READS [SEED [SECONDS]] [--view NAME]: READS and SEED are integers, SECONDS "
                "a number\n", argv[0]);
        clipmap_close(&own);
        clipmap_close(&m);
        return 2;
    }
    uint64_t bpt = tm->bytes_per_texel;
    unsigned long long passed = 0, failed = 0, busy = 0, stale = 0, missing = 0, moved = 0, idle = 0;
    unsigned long long blocks = 0, crossing = 0;
    unsigned char *buf = malloc((size_t)LARGE * LARGE * 64);
    if (!buf) {
        fprintf(stderr, "clipmap reader: out of memory\n");
        return 2;
    }
    struct clipmap_snapshot snap;
    memset(&snap, 0, sizeof snap);
    int have = 0, removed = 0;
    struct timespec t0, now;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (unsigned long long iter = 0; passed + failed < reads; iter++) {
        /* The clock every 64 reads, and before every snapshot taken again: a snapshot the writer
         * holds costs up to CLIPMAP_MAX_RETRIES yields, which a loaded machine makes long. */
        if ((iter & 63) == 0 || !have) {
            clock_gettime(CLOCK_MONOTONIC, &now);
            if ((double)(now.tv_sec - t0.tv_sec) + 1e-9 * (double)(now.tv_nsec - t0.tv_nsec) >= seconds) break;
        }
        if (!have || (iter & 255) == 0) {
            int rc = view_snapshot(&m, &view, &own, &snap);
            if (rc == CLIPMAP_REMOVED) {
                fprintf(stderr, "clipmap reader: %s: %s\n", argv[1], snap.error);
                removed = 1;
                break;
            }
            if (rc == CLIPMAP_CORRUPT) {
                fprintf(stderr, "clipmap reader: %s: %s\n", argv[1], snap.error);
                free(buf);
                clipmap_close(&own);
                clipmap_close(&m);
                return 2;
            }
            if (rc == CLIPMAP_BUSY) {
                busy++;
                if (!have) continue;
            } else {
                have = 1;
            }
        }
        uint32_t level = (uint32_t)(next(&rng) % tm->level_count);
        const struct clipmap_level_state *st = &snap.levels[level];
        if (!st->enabled) {
            idle++;
            continue;
        }
        const struct clipmap_level_desc *d = &tm->levels[level];
        int mode = (int)(next(&rng) % 3);
        int64_t s0, t0b;
        uint64_t w, h;
        pick(&rng, mode, st->valid[0], st->valid[2], d->tile[0], &s0, &w);
        pick(&rng, mode, st->valid[1], st->valid[3], d->tile[1], &t0b, &h);
        int rc = clipmap_read_region(tm, &snap, level, s0, t0b, w, h, buf);
        if (rc != CLIPMAP_OK) {
            switch (rc) {
            case CLIPMAP_MISSING: missing++; break;
            case CLIPMAP_BUSY: busy++; break;
            case CLIPMAP_STALE: stale++; break;
            case CLIPMAP_NOT_VALID: moved++; break;
            default:
                fprintf(stderr, "clipmap reader: level %u: read_region refused the snapshot (%d)\n", level, rc);
                free(buf);
                clipmap_close(&own);
                clipmap_close(&m);
                return 2;
            }
            have = 0; /* take a new snapshot */
            continue;
        }
        blocks++;
        if ((uint64_t)s0 / d->tile[0] != ((uint64_t)s0 + w - 1) / d->tile[0] ||
            (uint64_t)t0b / d->tile[1] != ((uint64_t)t0b + h - 1) / d->tile[1])
            crossing++;
        for (uint64_t j = 0; j < h; j++) {
            for (uint64_t i = 0; i < w; i++) {
                uint64_t s = (uint64_t)s0 + i, t = (uint64_t)t0b + j;
                /* A wrapping texture's region may run past the width: texel s is texel s mod width. */
                if (tm->georef_wraps) s %= d->size[0];
                uint64_t v = clipmap_hash_value(level, s, t);
                const unsigned char *got = buf + (j * w + i) * bpt;
                int ok = 1;
                for (uint64_t k = 0; k < bpt; k++)
                    if (got[k] != (unsigned char)(v >> (8 * (k % 8)))) ok = 0;
                if (ok) {
                    passed++;
                } else {
                    if (failed == 0)
                        fprintf(stderr, "clipmap reader: level %u texel (%llu, %llu) differs\n", level,
                                (unsigned long long)s, (unsigned long long)t);
                    failed++;
                }
            }
        }
    }
    printf("%llu passed, %llu failed (%llu blocks, %llu across tiles; skipped: %llu busy, %llu stale, %llu missing, "
           "%llu moved, %llu disabled; heartbeat age %llu ms; view %s)\n",
           passed, failed, blocks, crossing, busy, stale, missing, moved, idle,
           (unsigned long long)clipmap_heartbeat_age_ms(tm), view.name);
    free(buf);
    clipmap_close(&own);
    clipmap_close(&m);
    return failed != 0 ? 1 : removed ? 3 : 0;
}
