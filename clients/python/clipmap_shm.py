#!/usr/bin/env python3
"""Read a clip texture published by clipmapd in shared memory (layout version 1, docs/SHM.md).

Standard library only (mmap, struct). As a program it reads random texels inside the published
valid regions of a texture served by `clipmapd --source hash` and checks each one:

    python3 clients/python/clipmap_shm.py /dev/shm/clipmap-hash.map 100000 [seed [seconds]]

prints "N passed, M failed"; exit status 0 all passed, 1 a mismatch, 2 could not read.

Consistency: every state is read under its seqlock (sequence read before and after, accepted only
when even and equal). Python has no memory fences; on x86-64 (loads are not reordered with other
loads) that is enough, elsewhere treat this module as a reference, not a production reader.
"""

import mmap
import os
import struct
import sys
import time

MAGIC = b"CLIPMAP1"
VERSION = 1
PAGE = 4096
MAX_LEVELS = 32

# Header offsets.
H_VERSION, H_HEADER_BYTES, H_TOTAL_BYTES = 8, 12, 16
H_TEXEL_FORMAT, H_BYTES_PER_TEXEL, H_CLIP_SIZE, H_LEVEL_COUNT = 24, 28, 32, 36
H_FLAGS, H_HEARTBEAT, H_HEARTBEAT_MS, H_GENERATION = 60, 64, 72, 80
H_GLOBAL_SEQ, H_MIN_LOD, H_TICK = 88, 96, 104
H_LEVEL_DESCS = 192
DESC_BYTES = 64
H_LEVEL_STATES = H_LEVEL_DESCS + MAX_LEVELS * DESC_BYTES
STATE_BYTES = 128
H_END = H_LEVEL_STATES + MAX_LEVELS * STATE_BYTES

# Texel format codes (H_TEXEL_FORMAT): code -> (name, bytes per texel); 0 is any other format.
# 16-bit components are little-endian.
FORMATS = {
    1: ("l8", 1), 3: ("rgb8", 3), 4: ("rgba8", 4), 5: ("rgb565", 2), 6: ("rgba5551", 2),
    7: ("l16", 2), 8: ("la16", 4), 9: ("rgb16", 6), 10: ("rgba16", 8),
}

M64 = (1 << 64) - 1


class ClipmapError(Exception):
    """The mapping cannot be used."""


def splitmix64(x):
    z = (x + 0x9E3779B97F4A7C15) & M64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & M64
    return z ^ (z >> 31)


def hash_texel(level, s, t, bpt):
    """The verification texel at (level, s, t): byte i is byte i % 8 of the little-endian hash."""
    v = splitmix64((level << 58) | (t << 29) | s).to_bytes(8, "little")
    return bytes(v[i % 8] for i in range(bpt))


class Clipmap:
    """One attached mapping."""

    def __init__(self, path):
        self.path = path
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size < H_END:
                raise ClipmapError(f"{path}: truncated: {size} bytes, a mapping has at least {H_END}")
            self.mm = mmap.mmap(f.fileno(), size, access=mmap.ACCESS_READ)
        m = self.mm
        if m[0:8] != MAGIC:
            raise ClipmapError(f'{path}: wrong magic {bytes(m[0:8])!r}: not a clipmap mapping (expected "CLIPMAP1")')
        version = self._u32(H_VERSION)
        if version != VERSION:
            raise ClipmapError(f"{path}: layout version {version}; this reader reads version {VERSION}")
        total = self._u64(H_TOTAL_BYTES)
        if total != size:
            raise ClipmapError(f"{path}: the header says {total} bytes but the file has {size}")
        self.bpt = self._u32(H_BYTES_PER_TEXEL)
        self.clip = self._u32(H_CLIP_SIZE)
        self.count = self._u32(H_LEVEL_COUNT)
        self.format = self._u32(H_TEXEL_FORMAT)
        self.generation = self._u64(H_GENERATION)
        if not (0 < self.bpt <= 64 and self.clip > 0 and 0 < self.count <= MAX_LEVELS):
            raise ClipmapError(
                f"{path}: implausible header: {self.bpt} bytes per texel, clip {self.clip}, {self.count} levels"
            )
        prev_end = self._u32(H_HEADER_BYTES)
        self.levels = []
        for i in range(self.count):
            b = H_LEVEL_DESCS + i * DESC_BYTES
            ss, st, off, nbytes, ws, wt, kind = struct.unpack_from("<7Q", m, b)
            ok = (
                ws == min(ss, self.clip)
                and wt == min(st, self.clip)
                and nbytes == ws * wt * self.bpt
                and off % PAGE == 0
                and off >= prev_end
                and off + nbytes <= total
            )
            if not ok:
                raise ClipmapError(f"{path}: level {i}'s window description is inconsistent")
            prev_end = off + nbytes
            self.levels.append({"size": (ss, st), "offset": off, "window": (ws, wt), "pyramid": kind == 1})

    def _u32(self, off):
        return struct.unpack_from("<I", self.mm, off)[0]

    def _u64(self, off):
        return struct.unpack_from("<Q", self.mm, off)[0]

    def level_state(self, level):
        """A consistent copy of one level's state, or None if the writer kept it busy."""
        b = H_LEVEL_STATES + level * STATE_BYTES
        for _ in range(1000):
            s1 = self._u64(b)
            if s1 & 1:
                continue
            cs, ct, s0, t0, s1v, t1, enabled = struct.unpack_from("<7q", self.mm, b + 8)
            if self._u64(b) == s1:
                return {"seq": s1, "centre": (cs, ct), "valid": (s0, t0, s1v, t1), "enabled": enabled == 1}
        return None

    def read_region(self, level, s0, t0, w, h):
        """Bytes of the w x h texels from (s0, t0) (rows in increasing t), or None when the region is
        not inside the published valid region or the level kept changing."""
        d = self.levels[level]
        ws, off, bpt, clip = d["window"][0], d["offset"], self.bpt, self.clip
        b = H_LEVEL_STATES + level * STATE_BYTES
        for _ in range(64):
            st = self.level_state(level)
            if st is None:
                continue
            v = st["valid"]
            if not (st["enabled"] and v[0] <= s0 and v[1] <= t0 and s0 + w <= v[2] and t0 + h <= v[3]):
                return None
            out = bytearray()
            for row in range(h):
                slot_t = (t0 + row) % clip
                done = 0
                while done < w:
                    slot_s = (s0 + done) % clip
                    run = min(w - done, ws - slot_s)
                    a = off + (slot_t * ws + slot_s) * bpt
                    out += self.mm[a : a + run * bpt]
                    done += run
            if self._u64(b) == st["seq"]:
                return bytes(out)
        return None

    def heartbeat_age_ms(self):
        return max(0, int(time.time() * 1000) - self._u64(H_HEARTBEAT_MS))

    def close(self):
        self.mm.close()


def main(argv):
    if len(argv) < 3:
        print(f"usage: {argv[0]} MAPPING READS [SEED [SECONDS]]", file=sys.stderr)
        return 2
    try:
        c = Clipmap(argv[1])
    except (ClipmapError, OSError) as e:
        print(f"clipmap_shm: {e}", file=sys.stderr)
        return 2
    reads = int(argv[2])
    rng = int(argv[3]) if len(argv) > 3 else 1
    passed = failed = 0
    give_up = time.time() + (float(argv[4]) if len(argv) > 4 else 120.0)
    block = 8
    while passed + failed < reads and time.time() < give_up:
        rng = splitmix64(rng)
        level = rng % c.count
        st = c.level_state(level)
        if st is None or not st["enabled"]:
            continue
        v = st["valid"]
        vw, vh = v[2] - v[0], v[3] - v[1]
        if vw <= 0 or vh <= 0:
            continue
        w, h = min(vw, block), min(vh, block)
        rng = splitmix64(rng)
        s0 = v[0] + rng % (vw - w + 1)
        rng = splitmix64(rng)
        t0 = v[1] + rng % (vh - h + 1)
        got = c.read_region(level, s0, t0, w, h)
        if got is None:
            continue
        for i in range(w * h):
            s, t = s0 + i % w, t0 + i // w
            if got[i * c.bpt : (i + 1) * c.bpt] == hash_texel(level, s, t, c.bpt):
                passed += 1
            else:
                if failed == 0:
                    print(f"clipmap_shm: level {level} texel ({s}, {t}) differs", file=sys.stderr)
                failed += 1
    print(f"{passed} passed, {failed} failed")
    c.close()
    return 0 if failed == 0 else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
