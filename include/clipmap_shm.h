/* clipmap_shm.h: read a clip texture published by clipmapd in shared memory.
 *
 * Layout version 1, documented in docs/SHM.md; this header follows that page alone. Header-only,
 * C11 plus the GCC/Clang __atomic builtins, POSIX mmap. Little-endian hosts only.
 *
 * Use:
 *   struct clipmap_map m; char err[256];
 *   if (clipmap_open(path, &m, err, sizeof err) != 0) { fprintf(stderr, "%s\n", err); ... }
 *   struct clipmap_level_state st;
 *   if (clipmap_level_state(&m, level, &st) == 0 && st.enabled) { ...inside st.valid... }
 *   clipmap_read_region(&m, level, s0, t0, w, h, buf);   // 0: consistent copy
 *   clipmap_close(&m);
 */
#ifndef CLIPMAP_SHM_H
#define CLIPMAP_SHM_H

#include <errno.h>
#include <fcntl.h>
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

#define CLIPMAP_MAGIC "CLIPMAP1"
#define CLIPMAP_VERSION 1u
#define CLIPMAP_PAGE 4096u
#define CLIPMAP_MAX_LEVELS 32u

/* Header (byte offsets from the start of the mapping). */
#define CLIPMAP_H_MAGIC 0           /* u8[8] "CLIPMAP1" */
#define CLIPMAP_H_VERSION 8         /* u32 */
#define CLIPMAP_H_HEADER_BYTES 12   /* u32: bytes before the first window */
#define CLIPMAP_H_TOTAL_BYTES 16    /* u64: size of the mapping */
#define CLIPMAP_H_TEXEL_FORMAT 24   /* u32 */
#define CLIPMAP_H_BYTES_PER_TEXEL 28 /* u32 */
#define CLIPMAP_H_CLIP_SIZE 32      /* u32 */
#define CLIPMAP_H_LEVEL_COUNT 36    /* u32 */
#define CLIPMAP_H_LEVEL0_S 40       /* u64 */
#define CLIPMAP_H_LEVEL0_T 48       /* u64 */
#define CLIPMAP_H_WRITER_PID 56     /* u32 */
#define CLIPMAP_H_FLAGS 60          /* u32: bit 0 clean shutdown */
#define CLIPMAP_H_HEARTBEAT 64      /* u64 atomic: ticks */
#define CLIPMAP_H_HEARTBEAT_MS 72   /* u64 atomic: ms since the Unix epoch */
#define CLIPMAP_H_GENERATION 80     /* u64 */
#define CLIPMAP_H_GLOBAL_SEQ 88     /* u64 atomic seqlock of MIN_LOD and TICK */
#define CLIPMAP_H_MIN_LOD 96        /* f64 bits */
#define CLIPMAP_H_TICK 104          /* u64 */
#define CLIPMAP_H_REQUEST 128       /* request block */
#define CLIPMAP_H_LEVEL_DESCS 192   /* 32 descriptors of 64 bytes */
#define CLIPMAP_H_LEVEL_STATES (CLIPMAP_H_LEVEL_DESCS + 32 * 64) /* 32 states of 128 bytes */
#define CLIPMAP_H_END (CLIPMAP_H_LEVEL_STATES + 32 * 128)

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

#define CLIPMAP_DESC_BYTES 64
#define CLIPMAP_D_SIZE_S 0
#define CLIPMAP_D_SIZE_T 8
#define CLIPMAP_D_WINDOW_OFFSET 16
#define CLIPMAP_D_WINDOW_BYTES 24
#define CLIPMAP_D_WINDOW_S 32
#define CLIPMAP_D_WINDOW_T 40
#define CLIPMAP_D_KIND 48 /* 0 stack, 1 pyramid */

#define CLIPMAP_STATE_BYTES 128
#define CLIPMAP_S_SEQ 0
#define CLIPMAP_S_CENTRE_S 8
#define CLIPMAP_S_CENTRE_T 16
#define CLIPMAP_S_VALID_S0 24
#define CLIPMAP_S_VALID_T0 32
#define CLIPMAP_S_VALID_S1 40
#define CLIPMAP_S_VALID_T1 48
#define CLIPMAP_S_ENABLED 56
#define CLIPMAP_S_INVALID_BORDER 64
#define CLIPMAP_S_UPDATED_TICK 72
#define CLIPMAP_S_ORIGIN_S 80
#define CLIPMAP_S_ORIGIN_T 88

#define CLIPMAP_R_SEQ 0
#define CLIPMAP_R_CENTRE_S 8
#define CLIPMAP_R_CENTRE_T 16
#define CLIPMAP_R_VEL_S 24
#define CLIPMAP_R_VEL_T 32
#define CLIPMAP_R_CLIENT_PID 40
#define CLIPMAP_R_COUNT 48

struct clipmap_level_desc {
    uint64_t size[2];   /* level size in texels */
    uint64_t offset;    /* window byte offset in the mapping */
    uint64_t bytes;     /* window bytes */
    uint64_t window[2]; /* window size in texels: min(clip, size) */
    int pyramid;        /* 1: resident whole */
};

struct clipmap_level_state {
    uint64_t seq;
    int64_t centre[2];
    int64_t valid[4]; /* s0, t0, s1, t1: s0 <= s < s1, t0 <= t < t1 */
    int enabled;
    uint64_t invalid_border;
    uint64_t updated_tick;
};

struct clipmap_map {
    unsigned char *base;
    size_t len;
    uint32_t bytes_per_texel;
    uint32_t clip_size;
    uint32_t level_count;
    uint32_t texel_format;
    uint64_t generation;
    struct clipmap_level_desc levels[CLIPMAP_MAX_LEVELS];
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

/* Atomic 8-byte load of a field the writer changes. */
static inline uint64_t clipmap_load(const struct clipmap_map *m, size_t off, int order) {
    return __atomic_load_n((const uint64_t *)(const void *)(m->base + off), order);
}

/* Maps `path` and checks magic, version and every size. 0 on success; else -1 with `err` set. */
static inline int clipmap_open(const char *path, struct clipmap_map *m, char *err, size_t errlen) {
    memset(m, 0, sizeof *m);
    int fd = open(path, O_RDWR);
    if (fd < 0) fd = open(path, O_RDONLY);
    if (fd < 0) {
        snprintf(err, errlen, "%s: %s", path, strerror(errno));
        return -1;
    }
    struct stat st;
    if (fstat(fd, &st) != 0) {
        snprintf(err, errlen, "%s: %s", path, strerror(errno));
        close(fd);
        return -1;
    }
    if ((uint64_t)st.st_size < CLIPMAP_H_END) {
        snprintf(err, errlen, "%s: truncated: %lld bytes, a mapping has at least %d", path, (long long)st.st_size,
                 CLIPMAP_H_END);
        close(fd);
        return -1;
    }
    int prot = PROT_READ | ((fcntl(fd, F_GETFL) & O_ACCMODE) == O_RDWR ? PROT_WRITE : 0);
    void *p = mmap(NULL, (size_t)st.st_size, prot, MAP_SHARED, fd, 0);
    close(fd);
    if (p == MAP_FAILED) {
        snprintf(err, errlen, "%s: mmap: %s", path, strerror(errno));
        return -1;
    }
    m->base = (unsigned char *)p;
    m->len = (size_t)st.st_size;
#define CLIPMAP_FAIL(...)                   \
    do {                                    \
        snprintf(err, errlen, __VA_ARGS__); \
        munmap(m->base, m->len);            \
        m->base = NULL;                     \
        return -1;                          \
    } while (0)
    if (memcmp(m->base + CLIPMAP_H_MAGIC, CLIPMAP_MAGIC, 8) != 0)
        CLIPMAP_FAIL("%s: wrong magic: not a clipmap mapping (expected \"CLIPMAP1\")", path);
    __atomic_thread_fence(__ATOMIC_ACQUIRE);
    uint32_t version = clipmap_u32(m, CLIPMAP_H_VERSION);
    if (version != CLIPMAP_VERSION)
        CLIPMAP_FAIL("%s: layout version %u; this reader reads version %u", path, version, CLIPMAP_VERSION);
    uint64_t total = clipmap_u64(m, CLIPMAP_H_TOTAL_BYTES);
    if (total != (uint64_t)m->len)
        CLIPMAP_FAIL("%s: the header says %llu bytes but the file has %llu", path, (unsigned long long)total,
                     (unsigned long long)m->len);
    m->bytes_per_texel = clipmap_u32(m, CLIPMAP_H_BYTES_PER_TEXEL);
    m->clip_size = clipmap_u32(m, CLIPMAP_H_CLIP_SIZE);
    m->level_count = clipmap_u32(m, CLIPMAP_H_LEVEL_COUNT);
    m->texel_format = clipmap_u32(m, CLIPMAP_H_TEXEL_FORMAT);
    m->generation = clipmap_u64(m, CLIPMAP_H_GENERATION);
    if (m->bytes_per_texel == 0 || m->bytes_per_texel > 64 || m->clip_size == 0 || m->level_count == 0 ||
        m->level_count > CLIPMAP_MAX_LEVELS)
        CLIPMAP_FAIL("%s: implausible header: %u bytes per texel, clip %u, %u levels", path, m->bytes_per_texel,
                     m->clip_size, m->level_count);
    uint64_t header_bytes = clipmap_u32(m, CLIPMAP_H_HEADER_BYTES);
    uint64_t prev_end = header_bytes;
    for (uint32_t i = 0; i < m->level_count; i++) {
        size_t b = CLIPMAP_H_LEVEL_DESCS + (size_t)i * CLIPMAP_DESC_BYTES;
        struct clipmap_level_desc *d = &m->levels[i];
        d->size[0] = clipmap_u64(m, b + CLIPMAP_D_SIZE_S);
        d->size[1] = clipmap_u64(m, b + CLIPMAP_D_SIZE_T);
        d->offset = clipmap_u64(m, b + CLIPMAP_D_WINDOW_OFFSET);
        d->bytes = clipmap_u64(m, b + CLIPMAP_D_WINDOW_BYTES);
        d->window[0] = clipmap_u64(m, b + CLIPMAP_D_WINDOW_S);
        d->window[1] = clipmap_u64(m, b + CLIPMAP_D_WINDOW_T);
        d->pyramid = clipmap_u64(m, b + CLIPMAP_D_KIND) == 1;
        uint64_t ws = d->size[0] < m->clip_size ? d->size[0] : m->clip_size;
        uint64_t wt = d->size[1] < m->clip_size ? d->size[1] : m->clip_size;
        int ok = d->window[0] == ws && d->window[1] == wt && ws <= (1u << 16) && wt <= (1u << 16) &&
                 d->bytes == ws * wt * m->bytes_per_texel && d->offset % CLIPMAP_PAGE == 0 && d->offset >= prev_end &&
                 d->offset <= total && d->bytes <= total - d->offset;
        if (!ok) CLIPMAP_FAIL("%s: level %u's window description is inconsistent", path, i);
        prev_end = d->offset + d->bytes;
    }
#undef CLIPMAP_FAIL
    return 0;
}

static inline void clipmap_close(struct clipmap_map *m) {
    if (m->base) munmap(m->base, m->len);
    m->base = NULL;
}

/* A consistent copy of one level's state (seqlock). 0 on success, -1 if the writer kept it busy
 * (or died in the middle of a publication). */
static inline int clipmap_level_state(const struct clipmap_map *m, uint32_t level, struct clipmap_level_state *out) {
    if (level >= m->level_count) return -1;
    size_t b = CLIPMAP_H_LEVEL_STATES + (size_t)level * CLIPMAP_STATE_BYTES;
    for (int tries = 0; tries < 1000; tries++) {
        uint64_t s1 = clipmap_load(m, b + CLIPMAP_S_SEQ, __ATOMIC_ACQUIRE);
        if (s1 & 1) continue;
        out->seq = s1;
        out->centre[0] = (int64_t)clipmap_load(m, b + CLIPMAP_S_CENTRE_S, __ATOMIC_RELAXED);
        out->centre[1] = (int64_t)clipmap_load(m, b + CLIPMAP_S_CENTRE_T, __ATOMIC_RELAXED);
        for (int i = 0; i < 4; i++)
            out->valid[i] = (int64_t)clipmap_load(m, b + CLIPMAP_S_VALID_S0 + 8 * (size_t)i, __ATOMIC_RELAXED);
        out->enabled = clipmap_load(m, b + CLIPMAP_S_ENABLED, __ATOMIC_RELAXED) == 1;
        out->invalid_border = clipmap_load(m, b + CLIPMAP_S_INVALID_BORDER, __ATOMIC_RELAXED);
        out->updated_tick = clipmap_load(m, b + CLIPMAP_S_UPDATED_TICK, __ATOMIC_RELAXED);
        __atomic_thread_fence(__ATOMIC_ACQUIRE);
        if (clipmap_load(m, b + CLIPMAP_S_SEQ, __ATOMIC_RELAXED) == s1) return 0;
    }
    return -1;
}

static inline int64_t clipmap_mod(int64_t a, int64_t n) {
    int64_t r = a % n;
    return r < 0 ? r + n : r;
}

/* Copies the w x h texels of `level` starting at (s0, t0) into `out` (rows in increasing t, s
 * fastest). 0: a consistent copy of texels inside the published valid region; 1: the region is
 * not (now) inside the valid region; -1: the level kept changing. */
static inline int clipmap_read_region(const struct clipmap_map *m, uint32_t level, int64_t s0, int64_t t0, uint64_t w,
                                      uint64_t h, unsigned char *out) {
    if (level >= m->level_count) return 1;
    const struct clipmap_level_desc *d = &m->levels[level];
    size_t b = CLIPMAP_H_LEVEL_STATES + (size_t)level * CLIPMAP_STATE_BYTES;
    uint64_t bpt = m->bytes_per_texel;
    int64_t clip = (int64_t)m->clip_size;
    for (int tries = 0; tries < 64; tries++) {
        struct clipmap_level_state st;
        if (clipmap_level_state(m, level, &st) != 0) continue;
        if (!st.enabled || s0 < st.valid[0] || t0 < st.valid[1] || s0 + (int64_t)w > st.valid[2] ||
            t0 + (int64_t)h > st.valid[3])
            return 1;
        for (uint64_t row = 0; row < h; row++) {
            uint64_t slot_t = (uint64_t)clipmap_mod(t0 + (int64_t)row, clip);
            uint64_t done = 0;
            while (done < w) {
                uint64_t slot_s = (uint64_t)clipmap_mod(s0 + (int64_t)done, clip);
                uint64_t run = w - done;
                if (run > d->window[0] - slot_s) run = d->window[0] - slot_s;
                memcpy(out + (row * w + done) * bpt, m->base + d->offset + (slot_t * d->window[0] + slot_s) * bpt,
                       run * bpt);
                done += run;
            }
        }
        __atomic_thread_fence(__ATOMIC_ACQUIRE);
        if (clipmap_load(m, b + CLIPMAP_S_SEQ, __ATOMIC_RELAXED) == st.seq) return 0;
    }
    return -1;
}

/* Milliseconds since the writer's last heartbeat. */
static inline uint64_t clipmap_heartbeat_age_ms(const struct clipmap_map *m) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    uint64_t now = (uint64_t)ts.tv_sec * 1000u + (uint64_t)ts.tv_nsec / 1000000u;
    uint64_t beat = clipmap_load(m, CLIPMAP_H_HEARTBEAT_MS, __ATOMIC_ACQUIRE);
    return now > beat ? now - beat : 0;
}

#endif /* CLIPMAP_SHM_H */
