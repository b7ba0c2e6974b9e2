/* reader.c: reads random texels inside the published valid regions of a clip texture served by
 * `clipmapd --source hash` and checks every one against the verification texture.
 *
 *   cc -O2 -I include clients/c/reader.c -o reader
 *   ./reader /dev/shm/clipmap-hash.map 1000000 [seed [seconds]]
 *
 * Stops after READS texels or SECONDS seconds (default 120), whichever comes first.
 * Prints "N passed, M failed". Exit status: 0 all passed, 1 a mismatch, 2 could not read. */
#include "clipmap_shm.h"

#include <stdlib.h>

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: %s MAPPING READS [SEED [SECONDS]]\n", argv[0]);
        return 2;
    }
    struct clipmap_map m;
    char err[512];
    if (clipmap_open(argv[1], &m, err, sizeof err) != 0) {
        fprintf(stderr, "clipmap reader: %s\n", err);
        return 2;
    }
    unsigned long long reads = strtoull(argv[2], NULL, 10);
    uint64_t rng = argc > 3 ? strtoull(argv[3], NULL, 10) : 1;
    uint64_t bpt = m.bytes_per_texel;
    unsigned long long passed = 0, failed = 0, busy = 0;
    enum { BLOCK = 8 };
    unsigned char buf[BLOCK * BLOCK * 64];
    time_t give_up = time(NULL) + (argc > 4 ? atol(argv[4]) : 120);
    while (passed + failed < reads && time(NULL) < give_up) {
        rng = clipmap_splitmix64(rng);
        uint32_t level = (uint32_t)(rng % m.level_count);
        struct clipmap_level_state st;
        if (clipmap_level_state(&m, level, &st) != 0) {
            busy++;
            continue;
        }
        if (!st.enabled || st.valid[2] <= st.valid[0] || st.valid[3] <= st.valid[1]) continue;
        uint64_t vw = (uint64_t)(st.valid[2] - st.valid[0]), vh = (uint64_t)(st.valid[3] - st.valid[1]);
        uint64_t w = vw < BLOCK ? vw : BLOCK, h = vh < BLOCK ? vh : BLOCK;
        rng = clipmap_splitmix64(rng);
        int64_t s0 = st.valid[0] + (int64_t)(rng % (vw - w + 1));
        rng = clipmap_splitmix64(rng);
        int64_t t0 = st.valid[1] + (int64_t)(rng % (vh - h + 1));
        if (clipmap_read_region(&m, level, s0, t0, w, h, buf) != 0) continue;
        for (uint64_t i = 0; i < w * h; i++) {
            uint64_t s = (uint64_t)s0 + i % w, t = (uint64_t)t0 + i / w;
            uint64_t v = clipmap_hash_value(level, s, t);
            int ok = 1;
            for (uint64_t k = 0; k < bpt; k++)
                if (buf[i * bpt + k] != (unsigned char)(v >> (8 * (k % 8)))) ok = 0;
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
    printf("%llu passed, %llu failed (%llu busy, heartbeat age %llu ms)\n", passed, failed, busy,
           (unsigned long long)clipmap_heartbeat_age_ms(&m));
    clipmap_close(&m);
    return failed == 0 ? 0 : 1;
}
