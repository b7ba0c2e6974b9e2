// The ground plane z = 0 under the reference renderer's pinhole camera, textured from the clipmap
// levels this client keeps on the GPU (docs/GPU.md). One full-screen triangle: every pixel casts
// its ray onto the plane as `clipmap::accuracy::render::Camera::footprint` does (centre, right
// and lower neighbours, LOD from the larger difference), then samples with the clipmap rule of
// `clipmap::sample` (min LOD, the finest level whose whole filter footprint is available, else a
// coarser whole level), filtering by hand from texel loads so the arithmetic is the reference's.
//
// Three variants are made from this one source (`shader_source` in gpu.rs): the lines between the
// marker comments `#if colour` and `#end` are kept for colour textures (unsigned components
// decoded through a table), those between `#if blocks` and `#end` for block-compressed ones (BC
// textures the GPU decodes, then the colour's table), those between `#if heights` and `#end` for
// height textures (`R32Float` metres drawn in false colour, with the sampled height written to a
// fourth target); a marker may name several variants. Everything else is shared.

struct Level {
    // Published valid region s0, t0, s1, t1 (level texels).
    valid: vec4<i32>,
    // Level width, height; flags: bit 0 enabled, bit 1 the texture wraps in longitude (column s
    // is column s mod the width; the region may run past the width); first tag of the level in
    // `tags`.
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
    // Heights: the nodata value as the texture holds it, 1 when there is one (else 0), the
    // false-colour range's low end and 1 / (high - low), metres. Zero for colour textures.
    heights: vec4<f32>,
    levels: array<Level, 32>,
};

@group(0) @binding(0) var<uniform> fr: Frame;
// Per slot of every level: the tile S, T the GPU copy holds, and 1 when its texels are there.
@group(0) @binding(1) var<storage, read> tags: array<vec4<i32>>;
// One layer per level: the level's image cache, slot (i, j) at texels (i TW, j TH).
//#if colour
// The texels' components as published (8 or 16 bits, unsigned).
@group(0) @binding(2) var cache: texture_2d_array<u32>;
//#end
//#if blocks
// A block-compressed mapping's blocks as published (BC1, BC4, BC5, BC7), decoded by the GPU to
// unorm values (8-bit codes c as c / 255).
@group(0) @binding(2) var cache: texture_2d_array<f32>;
//#end
//#if colour blocks
// Component value c to [0, 1] as `TexelFormat::decode` computes it on the CPU (c / 255 or
// c / 65535, rounded once): a table, so that no GPU division rounds differently.
@group(0) @binding(3) var<storage, read> decode: array<f32>;
//#end
//#if heights
// Heights in metres (`l32f` as published; `l16`, `l16i` converted on upload), read with
// `textureLoad` (a 32-bit float texture is not filterable).
@group(0) @binding(2) var cache: texture_2d_array<f32>;
//#end

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
    if (l.size.z & 1) == 0 || t < l.valid.y || t >= l.valid.w {
        return false;
    }
    // s is the level's own column (in [0, width) where the texture wraps): the region holds it,
    // or holds it a width further where the region runs past the width.
    let inside = s >= l.valid.x && s < l.valid.z;
    let lap = wraps(k) && s + l.size.x >= l.valid.x && s + l.size.x < l.valid.z;
    if !(inside || lap) {
        return false;
    }
    let ts = s / l.tile.x;
    let tt = t / l.tile.y;
    let tag = tags[l.size.w + (tt % l.tile.w) * l.tile.z + (ts % l.tile.z)];
    return tag.x == ts && tag.y == tt && tag.z == 1;
}

// Whether the texture wraps in longitude (every level's flag says the same).
fn wraps(k: i32) -> bool {
    return (fr.levels[k].size.z & 2) != 0;
}

// Column s of level k: s mod the width where the texture wraps, else clamped to the edges (as
// `clipmap::sample` addresses).
fn column(k: i32, s: i32) -> i32 {
    let w = fr.levels[k].size.x;
    if wraps(k) {
        return ((s % w) + w) % w;
    }
    return clamp(s, 0, w - 1);
}

// Where texel (s, t) of level k lies in its layer.
fn cache_at(k: i32, s: i32, t: i32) -> vec2<i32> {
    let l = fr.levels[k];
    return vec2<i32>(s % (l.tile.x * l.tile.z), t % (l.tile.y * l.tile.w));
}

//#if colour
fn load(k: i32, s: i32, t: i32) -> vec4<f32> {
    let c = textureLoad(cache, cache_at(k, s, t), k, 0);
    return vec4<f32>(decode[c.x], decode[c.y], decode[c.z], decode[c.w]);
}

fn is_nodata(v: vec4<f32>) -> bool {
    return false;
}
//#end
//#if blocks
// The GPU's decoded value back to its 8-bit code (exact: c / 255 rounds back to c), widened as
// the CPU reads the decoded texels (params.w: 1 BC4's channel as grey L L L 1, 2 BC5's two as grey
// and alpha R R R G), then through the table as a published colour.
fn load(k: i32, s: i32, t: i32) -> vec4<f32> {
    let f = textureLoad(cache, cache_at(k, s, t), k, 0);
    var c = vec4<u32>(round(clamp(f, vec4<f32>(0.0), vec4<f32>(1.0)) * 255.0));
    if fr.params.w == 1.0 {
        c = vec4<u32>(c.x, c.x, c.x, 255u);
    } else if fr.params.w == 2.0 {
        c = vec4<u32>(c.x, c.x, c.x, c.y);
    }
    return vec4<f32>(decode[c.x], decode[c.y], decode[c.z], decode[c.w]);
}

fn is_nodata(v: vec4<f32>) -> bool {
    return false;
}
//#end
//#if heights
// The height in x (the other components stay 0 through the filters).
fn load(k: i32, s: i32, t: i32) -> vec4<f32> {
    return vec4<f32>(textureLoad(cache, cache_at(k, s, t), k, 0).x, 0.0, 0.0, 0.0);
}

fn is_nodata(v: vec4<f32>) -> bool {
    return fr.heights.y != 0.0 && v.x == fr.heights.x;
}
//#end

fn lerp4(a: vec4<f32>, b: vec4<f32>, f: f32) -> vec4<f32> {
    return a + (b - a) * f;
}

// ok: every texel the filter touched was available; nodata: one of them holds no data (heights:
// the pixel shows nodata; a nodata texel does not make a level unavailable).
struct Got {
    ok: bool,
    nodata: bool,
    rgba: vec4<f32>,
};

// The pixel's ground coordinates, exactly: level-0 texel `i` (integer) plus `f` in [0, 1), a
// multiple of 2^-24. The sampler below works from these with integer addressing and one rounded
// f32 operation per filter weight, so the CPU sampler given u = i + f (exact in f64) makes the
// same choices and weights (docs/GPU.md, "What is bit-exact").
struct Coord {
    i: vec2<i32>,
    f: vec2<f32>,
};

fn point(k: i32, c: Coord) -> Got {
    let l = fr.levels[k];
    // floor((i + f) / 2^k) = i >> k, as f < 1.
    let s = column(k, c.i.x >> u32(k));
    let t = clamp(c.i.y >> u32(k), 0, l.size.y - 1);
    if !available(k, s, t) {
        return Got(false, false, vec4<f32>(0.0));
    }
    let v = load(k, s, t);
    return Got(true, is_nodata(v), v);
}

// Level k's bilinear cell along one axis: x = (i + f) / 2^k - 1/2 = x0 + w, x0 an integer, w in
// [0, 1]. With r = i mod 2^k, w 2^k = r - 2^(k-1) + f when r + f >= 2^(k-1), else r + 2^(k-1) + f:
// one f32 addition (correctly rounded), then an exact scaling by 2^-k.
struct Cell {
    x0: i32,
    w: f32,
};

fn cell(i: i32, f: f32, k: i32) -> Cell {
    let r = i & ((1 << u32(k)) - 1);
    let base = i >> u32(k);
    let half = ldexp(1.0, k - 1);
    var up = f >= 0.5;
    if k > 0 {
        up = r >= (1 << u32(k - 1));
    }
    var a = f32(r) + half;
    var x0 = base - 1;
    if up {
        a = f32(r) - half;
        x0 = base;
    }
    return Cell(x0, ldexp(a + f, -k));
}

fn bilinear(k: i32, c: Coord) -> Got {
    let l = fr.levels[k];
    let cx = cell(c.i.x, c.f.x, k);
    let cy = cell(c.i.y, c.f.y, k);
    let s0 = cx.x0;
    let t0 = cy.x0;
    let fx = cx.w;
    let fy = cy.w;
    let sa = column(k, s0);
    let sb = column(k, s0 + 1);
    let ta = clamp(t0, 0, l.size.y - 1);
    let tb = clamp(t0 + 1, 0, l.size.y - 1);
    if !(available(k, sa, ta) && available(k, sb, ta) && available(k, sa, tb) && available(k, sb, tb)) {
        return Got(false, false, vec4<f32>(0.0));
    }
    let a = load(k, sa, ta);
    let b = load(k, sb, ta);
    let cc = load(k, sa, tb);
    let d = load(k, sb, tb);
    let nodata = is_nodata(a) || is_nodata(b) || is_nodata(cc) || is_nodata(d);
    return Got(true, nodata, lerp4(lerp4(a, b, fx), lerp4(cc, d, fx), fy));
}

// floor(lod + 0.5) without the rounding of the sum.
fn nearest_level(lod: f32) -> i32 {
    let k = floor(lod);
    return i32(k) + select(0, 1, lod - k >= 0.5);
}

fn filtered(mode: i32, c: Coord, lod_in: f32) -> Got {
    let last = i32(fr.params.y) - 1;
    let lod = clamp(lod_in, 0.0, f32(last));
    let nearest = min(nearest_level(lod), last);
    if mode == 0 {
        return point(nearest, c);
    }
    if mode == 1 {
        return bilinear(nearest, c);
    }
    let k = i32(floor(lod));
    let f = lod - f32(k);
    let fine = bilinear(k, c);
    if !fine.ok || f == 0.0 || k == last {
        return fine;
    }
    let coarse = bilinear(k + 1, c);
    if !coarse.ok {
        return coarse;
    }
    return Got(true, fine.nodata || coarse.nodata, lerp4(fine.rgba, coarse.rgba, f));
}

fn quantise(v: f32) -> u32 {
    let y = clamp(v, 0.0, 1.0) * 255.0;
    let r = floor(y);
    return u32(r) + select(0u, 1u, y - r >= 0.5);
}

const SKY: vec4<u32> = vec4<u32>(140u, 180u, 230u, 255u);
// Ground where no level holds the footprint (nothing published yet).
const BLACK: vec4<u32> = vec4<u32>(0u, 0u, 0u, 255u);

//#if colour blocks
struct Out {
    // The pixel, RGBA8.
    @location(0) rgba: vec4<u32>,
    // Where it sampled: level-0 texel s, t (as u32 bits) and the fractions f s, f t times 2^24.
    @location(1) at: vec4<u32>,
    // The pixel's LOD (clamped to the levels, before min LOD); -1 for sky.
    @location(2) lod: f32,
};

fn sky() -> Out {
    return Out(SKY, vec4<u32>(0u), -1.0);
}

fn shade(got: Got, at: vec4<u32>, lod: f32) -> Out {
    if !got.ok {
        return Out(BLACK, at, lod);
    }
    let p = got.rgba;
    return Out(vec4<u32>(quantise(p.x), quantise(p.y), quantise(p.z), quantise(p.w)), at, lod);
}
//#end
//#if heights
struct Out {
    // The pixel, RGBA8: the height in false colour, NODATA, or BLACK.
    @location(0) rgba: vec4<u32>,
    // Where it sampled: level-0 texel s, t (as u32 bits) and the fractions f s, f t times 2^24.
    @location(1) at: vec4<u32>,
    // The pixel's LOD (clamped to the levels, before min LOD); -1 for sky.
    @location(2) lod: f32,
    // The sampled height's f32 bits, and what the pixel is: 0 sky, 1 a height, 2 nodata (the
    // filter touched a nodata texel), 3 no level holds the footprint.
    @location(3) height: vec2<u32>,
};

// A pixel without data.
const NODATA: vec4<u32> = vec4<u32>(255u, 0u, 255u, 255u);

fn sky() -> Out {
    return Out(SKY, vec4<u32>(0u), -1.0, vec2<u32>(0u, 0u));
}

// The false-colour ramp's stops, 8-bit values (exact in f32): low to high, every quarter.
fn ramp_stop(i: i32) -> vec3<f32> {
    switch i {
        case 0: { return vec3<f32>(20.0, 40.0, 140.0); }
        case 1: { return vec3<f32>(40.0, 120.0, 220.0); }
        case 2: { return vec3<f32>(60.0, 160.0, 80.0); }
        case 3: { return vec3<f32>(170.0, 130.0, 70.0); }
        default: { return vec3<f32>(250.0, 250.0, 250.0); }
    }
}

fn round_half_up(y: f32) -> u32 {
    let r = floor(y);
    return u32(r) + select(0u, 1u, y - r >= 0.5);
}

// Height h to false colour over the range (clamped): every operation correctly rounded (a
// subtraction, products, exact scalings), as `HeightShading::colour` computes it on the CPU.
fn false_colour(h: f32) -> vec4<u32> {
    let x = clamp((h - fr.heights.z) * fr.heights.w, 0.0, 1.0) * 4.0;
    let i = min(i32(floor(x)), 3);
    let w = x - f32(i);
    let a = ramp_stop(i);
    let b = ramp_stop(i + 1);
    let c = a + (b - a) * w;
    return vec4<u32>(round_half_up(c.x), round_half_up(c.y), round_half_up(c.z), 255u);
}

fn shade(got: Got, at: vec4<u32>, lod: f32) -> Out {
    if !got.ok {
        return Out(BLACK, at, lod, vec2<u32>(0u, 3u));
    }
    if got.nodata {
        return Out(NODATA, at, lod, vec2<u32>(0u, 2u));
    }
    let h = got.rgba.x;
    return Out(false_colour(h), at, lod, vec2<u32>(bitcast<u32>(h), 1u));
}
//#end

// Level-0 coordinate eye_int + rel as an integer and a fraction in [0, 1) rounded down to a
// multiple of 2^-24 (a no-op wherever |rel| >= 1, where rel's own ulp is coarser), as 2^24 times
// the fraction.
struct Split {
    i: i32,
    q: u32,
};

fn split(eye_int: i32, rel: f32) -> Split {
    let fl = floor(rel);
    let q = floor(ldexp(rel - fl, 24));
    return Split(eye_int + i32(fl), u32(q));
}

@fragment
fn fs(@builtin(position) pos: vec4<f32>) -> Out {
    // The pixel's centre: wgpu's fragment position is (i + 0.5, j + 0.5), y down.
    let x = pos.x;
    let y = pos.y;
    let c = ground(x, y);
    if c.z == 0.0 {
        return sky();
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
        return sky();
    }
    let rho = max(max(length(dx.xy - c.xy), length(dy.xy - c.xy)), 1e-12);
    let rel = vec2<f32>(fr.eye.x + c.x, fr.eye.y + c.y);
    let su = split(fr.eye_int.x, rel.x);
    let sv = split(fr.eye_int.y, rel.y);
    let q = vec2<u32>(su.q, sv.q);
    let co = Coord(vec2<i32>(su.i, sv.i), vec2<f32>(ldexp(f32(q.x), -24), ldexp(f32(q.y), -24)));
    let size = fr.levels[0].size;
    // u = i + f with f in [0, 1): u >= 0 exactly when i >= 0, u < size when i < size. A texture
    // that wraps in longitude has no west or east edge: the ground goes on around the world.
    let off_s = !wraps(0) && (co.i.x < 0 || co.i.x >= size.x);
    if off_s || co.i.y < 0 || co.i.y >= size.y {
        return sky();
    }
    let count = i32(fr.params.y);
    let last = f32(count - 1);
    let mode = i32(fr.params.z);
    // The reference clamps the pixel's LOD to the levels, then samples at max(lod, min LOD).
    let pixel_lod = clamp(log2(rho), 0.0, last);
    let lod = clamp(max(pixel_lod, fr.params.x), 0.0, last);
    var got = filtered(mode, co, lod);
    if !got.ok {
        var first = nearest_level(lod) + 1;
        if mode == 2 {
            first = i32(ceil(lod));
        }
        for (var k = first; k < count; k++) {
            got = filtered(mode, co, f32(k));
            if got.ok {
                break;
            }
        }
    }
    let at = vec4<u32>(bitcast<u32>(co.i.x), bitcast<u32>(co.i.y), q.x, q.y);
    return shade(got, at, pixel_lod);
}
