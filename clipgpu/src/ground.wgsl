// The ground plane z = 0 under the reference renderer's pinhole camera, textured from the clipmap
// levels this client keeps on the GPU (docs/GPU.md). One full-screen triangle: every pixel casts
// its ray onto the plane as `clipmap::accuracy::render::Camera::footprint` does (centre, right
// and lower neighbours, LOD from the larger difference), then samples with the clipmap rule of
// `clipmap::sample` (min LOD, the finest level whose whole filter footprint is available, else a
// coarser whole level), filtering by hand from texel loads so the arithmetic is the reference's.

struct Level {
    // Published valid region s0, t0, s1, t1 (level texels).
    valid: vec4<i32>,
    // Level width, height; enabled (1) or not (0); first tag of the level in `tags`.
    size: vec4<i32>,
    // Tile width, height; grid width, height (slots).
    tile: vec4<i32>,
};

struct Frame {
    // Eye: fractional part of s, t (level-0 texels), height, tan(fov / 2).
    eye: vec4<f32>,
    // Eye: integer part of s, t; image width, height in pixels.
    eye_int: vec4<i32>,
    forward: vec4<f32>,
    right: vec4<f32>,
    up: vec4<f32>,
    // min LOD, level count, filter (0 point, 1 bilinear, 2 trilinear), unused.
    params: vec4<f32>,
    levels: array<Level, 32>,
};

@group(0) @binding(0) var<uniform> fr: Frame;
// Per slot of every level: the tile S, T the GPU copy holds, and 1 when its texels are there.
@group(0) @binding(1) var<storage, read> tags: array<vec4<i32>>;
// One layer per level: the level's image cache, slot (i, j) at texels (i TW, j TH).
@group(0) @binding(2) var cache: texture_2d_array<f32>;

@vertex
fn vs(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

// Ground hit of the ray through image point (x, y), relative to the eye's foot; w = 0: sky.
fn ground(x: f32, y: f32) -> vec3<f32> {
    let w = f32(fr.eye_int.z);
    let h = f32(fr.eye_int.w);
    let tan_half = fr.eye.w;
    let nx = (2.0 * x / w - 1.0) * tan_half;
    let ny = (1.0 - 2.0 * y / h) * tan_half * h / w;
    let d = fr.forward.xyz + nx * fr.right.xyz + ny * fr.up.xyz;
    if d.z >= -1e-9 {
        return vec3<f32>(0.0, 0.0, 0.0);
    }
    let t = fr.eye.z / -d.z;
    return vec3<f32>(t * d.x, t * d.y, 1.0);
}

// Whether texel (s, t) of level k may be used: the level enabled, the texel inside its published
// valid region, and the GPU slot of its tile holding that very tile.
fn available(k: i32, s: i32, t: i32) -> bool {
    let l = fr.levels[k];
    if l.size.z == 0 || s < l.valid.x || s >= l.valid.z || t < l.valid.y || t >= l.valid.w {
        return false;
    }
    let ts = s / l.tile.x;
    let tt = t / l.tile.y;
    let tag = tags[l.size.w + (tt % l.tile.w) * l.tile.z + (ts % l.tile.z)];
    return tag.x == ts && tag.y == tt && tag.z == 1;
}

fn load(k: i32, s: i32, t: i32) -> vec4<f32> {
    let l = fr.levels[k];
    let p = vec2<i32>(s % (l.tile.x * l.tile.z), t % (l.tile.y * l.tile.w));
    return textureLoad(cache, p, k, 0);
}

fn lerp4(a: vec4<f32>, b: vec4<f32>, f: f32) -> vec4<f32> {
    return a + (b - a) * f;
}

struct Got {
    ok: bool,
    rgba: vec4<f32>,
};

// Level-k coordinate of the pixel's u (or v): integer part `base`, fraction-carrying part `rel`.
fn split(eye_int: i32, rel0: f32, k: i32) -> vec2<f32> {
    let scale = f32(1 << u32(k));
    let rem = eye_int & ((1 << u32(k)) - 1);
    return vec2<f32>(f32(eye_int >> u32(k)), (f32(rem) + rel0) / scale);
}

fn point(k: i32, rel: vec2<f32>) -> Got {
    let l = fr.levels[k];
    let bs = split(fr.eye_int.x, rel.x, k);
    let bt = split(fr.eye_int.y, rel.y, k);
    let s = clamp(i32(bs.x) + i32(floor(bs.y)), 0, l.size.x - 1);
    let t = clamp(i32(bt.x) + i32(floor(bt.y)), 0, l.size.y - 1);
    if !available(k, s, t) {
        return Got(false, vec4<f32>(0.0));
    }
    return Got(true, load(k, s, t));
}

fn bilinear(k: i32, rel: vec2<f32>) -> Got {
    let l = fr.levels[k];
    let bs = split(fr.eye_int.x, rel.x, k);
    let bt = split(fr.eye_int.y, rel.y, k);
    let x = bs.y - 0.5;
    let y = bt.y - 0.5;
    let x0 = floor(x);
    let y0 = floor(y);
    let fx = x - x0;
    let fy = y - y0;
    let s0 = i32(bs.x) + i32(x0);
    let t0 = i32(bt.x) + i32(y0);
    let sa = clamp(s0, 0, l.size.x - 1);
    let sb = clamp(s0 + 1, 0, l.size.x - 1);
    let ta = clamp(t0, 0, l.size.y - 1);
    let tb = clamp(t0 + 1, 0, l.size.y - 1);
    if !(available(k, sa, ta) && available(k, sb, ta) && available(k, sa, tb) && available(k, sb, tb)) {
        return Got(false, vec4<f32>(0.0));
    }
    let a = load(k, sa, ta);
    let b = load(k, sb, ta);
    let c = load(k, sa, tb);
    let d = load(k, sb, tb);
    return Got(true, lerp4(lerp4(a, b, fx), lerp4(c, d, fx), fy));
}

fn filtered(mode: i32, rel: vec2<f32>, lod_in: f32) -> Got {
    let last = i32(fr.params.y) - 1;
    let lod = clamp(lod_in, 0.0, f32(last));
    let nearest = min(i32(floor(lod + 0.5)), last);
    if mode == 0 {
        return point(nearest, rel);
    }
    if mode == 1 {
        return bilinear(nearest, rel);
    }
    let k = i32(floor(lod));
    let f = lod - f32(k);
    let fine = bilinear(k, rel);
    if !fine.ok || f == 0.0 || k == last {
        return fine;
    }
    let coarse = bilinear(k + 1, rel);
    if !coarse.ok {
        return coarse;
    }
    return Got(true, lerp4(fine.rgba, coarse.rgba, f));
}

fn quantise(v: f32) -> u32 {
    let y = clamp(v, 0.0, 1.0) * 255.0;
    let r = floor(y);
    return u32(r) + select(0u, 1u, y - r >= 0.5);
}

const SKY: vec4<u32> = vec4<u32>(140u, 180u, 230u, 255u);

@fragment
fn fs(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<u32> {
    // The pixel's centre: wgpu's fragment position is (i + 0.5, j + 0.5), y down.
    let x = pos.x;
    let y = pos.y;
    let c = ground(x, y);
    if c.z == 0.0 {
        return SKY;
    }
    var dx = ground(x + 1.0, y);
    if dx.z == 0.0 {
        dx = ground(x - 1.0, y);
    }
    var dy = ground(x, y + 1.0);
    if dy.z == 0.0 {
        dy = ground(x, y - 1.0);
    }
    if dx.z == 0.0 || dy.z == 0.0 {
        return SKY;
    }
    let rho = max(max(length(dx.xy - c.xy), length(dy.xy - c.xy)), 1e-12);
    let rel = vec2<f32>(fr.eye.x + c.x, fr.eye.y + c.y);
    let u = f32(fr.eye_int.x) + rel.x;
    let v = f32(fr.eye_int.y) + rel.y;
    let size = fr.levels[0].size;
    if u < 0.0 || v < 0.0 || u >= f32(size.x) || v >= f32(size.y) {
        return SKY;
    }
    let count = i32(fr.params.y);
    let last = f32(count - 1);
    let mode = i32(fr.params.z);
    // The reference clamps the pixel's LOD to the levels, then samples at max(lod, min LOD).
    let lod = clamp(max(clamp(log2(rho), 0.0, last), fr.params.x), 0.0, last);
    var got = filtered(mode, rel, lod);
    if !got.ok {
        var first = i32(floor(lod + 0.5)) + 1;
        if mode == 2 {
            first = i32(ceil(lod));
        }
        for (var k = first; k < count; k++) {
            got = filtered(mode, rel, f32(k));
            if got.ok {
                break;
            }
        }
    }
    if !got.ok {
        return vec4<u32>(0u, 0u, 0u, 255u);
    }
    let q = got.rgba;
    return vec4<u32>(quantise(q.x), quantise(q.y), quantise(q.z), quantise(q.w));
}
