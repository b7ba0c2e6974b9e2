//! What window layout would let column strips reach `memcpy` speed?
//!
//! The engine's windows are row-major with a row pitch of `clip x bytes per texel` (the
//! shared-memory contract, layout 1). A flight along +s uncovers a column strip per level, one
//! short run per window row, and runs far below `memcpy` (docs/BENCHMARKS.md). This experiment
//! replays the copies of such a flight — the same strip widths per level, the same wrap and tile
//! splits, from row-major 256-texel tiles — into windows of other layouts, and times each against
//! `memcpy` of the same bytes in the same run:
//!
//! - `rows`: row-major, pitch = clip x B (today's layout);
//! - `rows+64`: row-major with 64 bytes of padding per row (a pitch field in the layout; GPU
//!   uploads keep working with `GL_UNPACK_ROW_LENGTH`);
//! - `bricks16`, `bricks32`: square bricks of 16 or 32 texels, each brick contiguous, bricks in
//!   row-major order (a renderer must de-brick before a plain upload).
//!
//! Every run checks every texel of the last tick's strips at every level against the tiles, so a
//! layout that addressed texels wrongly would fail rather than look fast.
//!
//! ```text
//! cargo run --release --example strip_layout                    # +s and +t, 64 texels a tick
//! cargo run --release --example strip_layout -- --speed 16 --runs 7
//! cargo run --release --example strip_layout -- --granule 16 --huge  # 16-texel centre steps, 2 MiB pages
//! ```

use std::time::Instant;

const B: usize = 4; // RGBA8
const TILE: usize = 256;

#[derive(Clone, Copy, Debug)]
enum Layout {
    Rows { pad: usize },
    Bricks { b: usize },
}

impl Layout {
    fn name(self) -> String {
        match self {
            Layout::Rows { pad: 0 } => "rows".into(),
            Layout::Rows { pad } => format!("rows+{pad}"),
            Layout::Bricks { b } => format!("bricks{b}"),
        }
    }
    fn bytes(self, clip: usize) -> usize {
        match self {
            Layout::Rows { pad } => (clip * B + pad) * clip,
            Layout::Bricks { .. } => clip * clip * B,
        }
    }
    /// Byte offset of window slot (x, y).
    fn offset(self, clip: usize, x: usize, y: usize) -> usize {
        match self {
            Layout::Rows { pad } => y * (clip * B + pad) + x * B,
            Layout::Bricks { b } => {
                let brick = (y / b) * (clip / b) + x / b;
                (brick * b * b + (y % b) * b + x % b) * B
            }
        }
    }
}

/// Resident tiles of one level: a small pool reused pseudo-randomly, large enough not to stay in
/// the first two cache levels.
struct Tiles {
    pool: Vec<Vec<u8>>,
    /// Brick size of the tiles' own layout (1: row-major, as read from files).
    b: usize,
}

impl Tiles {
    fn new(n: usize, b: usize) -> Self {
        let pool = (0..n)
            .map(|i| {
                (0..TILE * TILE * B)
                    .map(|j| (j as u32).wrapping_mul(2_654_435_761).wrapping_add(i as u32) as u8)
                    .collect()
            })
            .collect();
        Tiles { pool, b }
    }
    fn tile(&self, level: usize, ts: u64, tt: u64) -> &[u8] {
        let h = (ts.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ tt.wrapping_mul(0xC2B2_AE3D_27D4_EB4F) ^ level as u64) >> 40;
        &self.pool[h as usize % self.pool.len()]
    }
    /// Level texels (s, t) .. (s + n, t), n not crossing a tile edge (nor a brick edge when the
    /// tiles are bricked).
    fn run(&self, level: usize, s: u64, t: u64, n: usize) -> &[u8] {
        let tile = self.tile(level, s / TILE as u64, t / TILE as u64);
        let (x, y) = ((s % TILE as u64) as usize, (t % TILE as u64) as usize);
        let o = Layout::Bricks { b: self.b }.offset(TILE, x, y);
        &tile[o..o + n * B]
    }
}

/// Level texels [s, s + w) x [t, t + h) of one level.
#[derive(Clone, Copy)]
struct Rect {
    level: usize,
    s: u64,
    t: u64,
    w: u64,
    h: u64,
}

/// Copies level texels [s0, s0 + w) x [t0, t0 + h) into the window (toroidal slots), splitting
/// at tile edges and the window's wrap, in the order that suits the layout. Returns bytes copied.
fn copy_rect(layout: Layout, clip: usize, win: &mut [u8], tiles: &Tiles, r: Rect) -> usize {
    let Rect { level, s: s0, t: t0, w, h } = r;
    let c = clip as u64;
    // Split the columns into runs inside one tile column and one window wrap.
    let mut cols = Vec::new();
    let mut s = s0;
    while s < s0 + w {
        let to_tile = TILE as u64 - s % TILE as u64;
        let to_wrap = c - s % c;
        let n = (s0 + w - s).min(to_tile).min(to_wrap);
        cols.push((s, n));
        s += n;
    }
    match layout {
        Layout::Rows { .. } => {
            for t in t0..t0 + h {
                let y = (t % c) as usize;
                for &(s, n) in &cols {
                    let d = layout.offset(clip, (s % c) as usize, y);
                    win[d..d + n as usize * B].copy_from_slice(tiles.run(level, s, t, n as usize));
                }
            }
        }
        Layout::Bricks { b } => {
            // Brick by brick: each brick's rows are contiguous in the window.
            let b = b as u64;
            let mut t = t0;
            while t < t0 + h {
                let rows = (b - (t % c) % b).min(t0 + h - t);
                for &(s, n) in &cols {
                    let mut ss = s;
                    while ss < s + n {
                        let m = (b - (ss % c) % b).min(s + n - ss);
                        for tt in t..t + rows {
                            let d = layout.offset(clip, (ss % c) as usize, (tt % c) as usize);
                            win[d..d + m as usize * B].copy_from_slice(tiles.run(level, ss, tt, m as usize));
                        }
                        ss += m;
                    }
                }
                t += rows;
            }
        }
    }
    (w * h) as usize * B
}

fn check_rect(layout: Layout, clip: usize, win: &[u8], tiles: &Tiles, r: Rect) {
    let Rect { level, s: s0, t: t0, w, h } = r;
    let c = clip as u64;
    for t in t0..t0 + h {
        for s in s0..s0 + w {
            let d = layout.offset(clip, (s % c) as usize, (t % c) as usize);
            assert_eq!(&win[d..d + B], tiles.run(level, s, t, 1), "{} level {level} texel ({s}, {t})", layout.name());
        }
    }
}

struct Flight {
    dir: (u64, u64),
    speed: u64,
    ticks: usize,
    levels: usize,
    /// Each level's centre moves in steps of this many level texels (1: every texel).
    granule: u64,
}

/// One run of a steady flight: per tick, each level's window moves with the centre (level k's
/// centre is the level-0 centre >> k) and copies the strips that uncovers. Returns (bytes, s).
fn fly(
    layout: Layout,
    clip: usize,
    wins: &mut [Buf],
    tiles: &Tiles,
    f: &Flight,
    start: u64,
    check: bool,
) -> (usize, f64) {
    let c = clip as u64;
    let mut centre = (start, start);
    let mut bytes = 0;
    let mut secs = 0.0;
    for tick in 0..f.ticks {
        let next = (centre.0 + f.dir.0 * f.speed, centre.1 + f.dir.1 * f.speed);
        let last = tick + 1 == f.ticks;
        let t0 = Instant::now();
        let mut rects = Vec::new();
        for k in 0..f.levels {
            let g = f.granule;
            let al = |v: u64| (v >> k) / g * g;
            let (a, b) = ((al(centre.0), al(centre.1)), (al(next.0), al(next.1)));
            let (ds, dt) = (b.0 - a.0, b.1 - a.1);
            let (lo_s, lo_t) = (b.0 - c / 2, b.1 - c / 2);
            if ds > 0 {
                rects.push(Rect { level: k, s: lo_s + c - ds, t: lo_t, w: ds, h: c });
            }
            if dt > 0 {
                rects.push(Rect { level: k, s: lo_s, t: lo_t + c - dt, w: c - ds.min(c), h: dt });
            }
        }
        for &r in &rects {
            bytes += copy_rect(layout, clip, &mut wins[r.level], tiles, r);
        }
        secs += t0.elapsed().as_secs_f64();
        if check && last {
            for &r in &rects {
                check_rect(layout, clip, &wins[r.level], tiles, r);
            }
        }
        centre = next;
    }
    (bytes, secs)
}

/// A window's bytes: a plain allocation, or anonymous memory the kernel is asked to back with
/// transparent huge pages (`--huge`), so that a column strip's 2048 rows touch a few 2 MiB pages
/// instead of 2048 pages of 4 KiB.
enum Buf {
    Plain(Vec<u8>),
    Huge(memmap2::MmapMut),
}

impl Buf {
    fn new(len: usize, huge: bool) -> Buf {
        if !huge {
            return Buf::Plain(vec![1u8; len]);
        }
        let mut m = memmap2::MmapMut::map_anon(len).expect("an anonymous mapping for a window");
        if let Err(e) = m.advise(memmap2::Advice::HugePage) {
            eprintln!("strip_layout: madvise(MADV_HUGEPAGE) refused ({e}); the window stays on small pages");
        }
        m.fill(1);
        Buf::Huge(m)
    }
}

impl std::ops::Deref for Buf {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Buf::Plain(v) => v,
            Buf::Huge(m) => m,
        }
    }
}

impl std::ops::DerefMut for Buf {
    fn deref_mut(&mut self) -> &mut [u8] {
        match self {
            Buf::Plain(v) => v,
            Buf::Huge(m) => m,
        }
    }
}

fn memcpy_rate(bytes: usize, src: &[u8], dst: &mut [u8]) -> f64 {
    let t = Instant::now();
    let (mut done, mut off) = (0, 0);
    while done < bytes {
        let n = (bytes - done).min(1 << 20);
        if off + n > src.len() {
            off = 0;
        }
        dst[off..off + n].copy_from_slice(&src[off..off + n]);
        off += n;
        done += n;
    }
    std::hint::black_box(&dst);
    bytes as f64 / t.elapsed().as_secs_f64()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let mut speed = 64u64;
    let mut runs = 5usize;
    let mut granule = 1u64;
    let mut huge = false;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut num = |what: &str| -> u64 {
            args.next().and_then(|v| v.parse().ok()).unwrap_or_else(|| {
                eprintln!("strip_layout: {what} needs a positive whole number, e.g. `{what} 64`");
                std::process::exit(2)
            })
        };
        match a.as_str() {
            "--speed" => speed = num("--speed").max(1),
            "--runs" => runs = num("--runs").max(1) as usize,
            "--granule" => granule = num("--granule").max(1),
            "--huge" => huge = true,
            _ => {
                eprintln!("strip_layout: unknown argument {a:?}; expected --speed N, --runs N, --granule G or --huge");
                std::process::exit(2)
            }
        }
    }
    let clip = 2048usize;
    let levels = 15; // the stack levels of a 2^26 texture with clip 2048
    let layouts =
        [Layout::Rows { pad: 0 }, Layout::Rows { pad: 64 }, Layout::Bricks { b: 16 }, Layout::Bricks { b: 32 }];
    let src = vec![3u8; 64 << 20];
    let mut dst = vec![5u8; 64 << 20];
    println!(
        "steady flights of {speed} level-0 texels a tick, clip {clip}, RGBA8, {levels} stack levels, 256-texel tiles"
    );
    println!("each level's centre moves in steps of {granule} level texels");
    println!("windows {}", if huge { "on transparent huge pages (--huge)" } else { "in plain allocations" });
    println!("median of {runs} runs of 32 ticks; memcpy of the same bytes in 1 MiB pieces after each run\n");
    println!("{:<8} {:<15} {:>12} {:>12} {:>8} {:>12}", "flight", "layout", "MiB/s", "memcpy", "ratio", "us/tick");
    for (fname, dir) in [("+s", (1, 0)), ("+t", (0, 1))] {
        for (layout, tb) in
            layouts.into_iter().map(|l| (l, 1)).chain([(Layout::Bricks { b: 16 }, 16), (Layout::Bricks { b: 32 }, 32)])
        {
            // 96 tiles: 24 MiB, beyond the first two cache levels. Bricked tiles stand for a
            // tile cache that re-lays tiles out once as they are read.
            let tiles = Tiles::new(96, tb);
            let mut wins: Vec<Buf> = (0..levels).map(|_| Buf::new(layout.bytes(clip), huge)).collect();
            let f = Flight { dir, speed, ticks: 32, levels, granule };
            let (mut rates, mut copies, mut ratios, mut per_tick) = (vec![], vec![], vec![], vec![]);
            for r in 0..runs {
                let start = (1u64 << 25) + (r as u64) * 100_003;
                let (bytes, secs) = fly(layout, clip, &mut wins, &tiles, &f, start, true);
                let rate = bytes as f64 / secs;
                let m = memcpy_rate(bytes, &src, &mut dst);
                rates.push(rate);
                copies.push(m);
                ratios.push(rate / m);
                per_tick.push(secs / f.ticks as f64);
            }
            println!(
                "{:<8} {:<15} {:>12.0} {:>12.0} {:>8.2} {:>12.0}",
                fname,
                if tb > 1 { format!("{}/tiles", layout.name()) } else { layout.name() },
                median(rates) / 1048576.0,
                median(copies) / 1048576.0,
                median(ratios),
                median(per_tick) * 1e6
            );
        }
    }
}
