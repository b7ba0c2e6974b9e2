/* growth.c: prints a growing texture's growth block (extent, data levels, patches, ...) as one
 * JSON object, or `null` when the texture does not grow; with SECONDS, once more every time it
 * changes until SECONDS have passed (a reader follows growth without reattaching).
 *
 *   cc -O2 -I include clients/c/growth.c -o growth
 *   ./growth /dev/shm/clipmap-survey.map [SECONDS]
 *
 * Exit status: 0 ok, 2 the mapping was refused (at open, or its growth block is impossible). */
#include "clipmap_shm.h"

#include <stddef.h>
#include <stdlib.h>
#include <time.h>

static void print(const struct clipmap_growth *g) {
    if (!g->growing) {
        printf("null\n");
    } else {
        printf("{\"data_levels\": %llu, \"extent\": [%lld, %lld, %lld, %lld], \"outside_frame\": %llu, "
               "\"patches\": %llu, \"texels_per_unit\": %.17g, \"tiles_pending\": %llu, \"tiles_rebuilt\": %llu, "
               "\"tiles_replaced\": %llu, \"world_origin\": [%.17g, %.17g]}\n",
               (unsigned long long)g->data_levels, (long long)g->extent[0], (long long)g->extent[1],
               (long long)g->extent[2], (long long)g->extent[3], (unsigned long long)g->outside_frame,
               (unsigned long long)g->patches, g->texels_per_unit, (unsigned long long)g->tiles_pending,
               (unsigned long long)g->tiles_rebuilt, (unsigned long long)g->tiles_replaced, g->world_origin[0],
               g->world_origin[1]);
    }
    fflush(stdout);
}

int main(int argc, char **argv) {
    if (argc < 2 || argc > 3) {
        fprintf(stderr, "usage: %s MAPPING [SECONDS]\n", argv[0]);
        return 2;
    }
    double seconds = argc == 3 ? strtod(argv[2], NULL) : 0.0;
    struct clipmap_map m;
    if (clipmap_open(argv[1], &m) != 0) {
        fprintf(stderr, "clipmap growth: %s\n", m.error);
        return 2;
    }
    struct clipmap_growth g, last;
    memset(&last, 0, sizeof last);
    time_t until = time(NULL) + (time_t)seconds;
    int first = 1;
    do {
        int rc = clipmap_growth(&m, &g);
        if (rc == CLIPMAP_CORRUPT) {
            fprintf(stderr, "clipmap growth: %s: %s\n", argv[1], g.error);
            clipmap_close(&m);
            return 2;
        }
        if (rc == CLIPMAP_OK && (first || memcmp(&g, &last, offsetof(struct clipmap_growth, error)) != 0)) {
            print(&g);
            last = g;
            first = 0;
        }
        if (seconds > 0) {
            struct timespec ts = {0, 20 * 1000 * 1000};
            nanosleep(&ts, NULL);
        }
    } while (seconds > 0 && time(NULL) < until);
    clipmap_close(&m);
    return 0;
}
