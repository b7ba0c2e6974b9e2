//! Micro-benchmarks of the paging engine: one update tick during a steady flight (its strip
//! copies, plus waiting for the tiles it asked for); the strip copies alone, a column strip
//! against a row strip of the same texels, with every tile resident; the residency geometry
//! (every level's regions for a centre) of a 2^26 texture; and the priority refresh of a read
//! queue (priorities of every mem-region tile, and a queue re-sorting 1024 pending reads).
//! `cargo bench --bench engine`; `clipbench engine` measures the goals in one run.

// `criterion_group!` generates a `pub fn` that cannot carry a doc comment; a bench is no API.
#![allow(missing_docs)]

use clipmap::clip::{Clipmap, Settings};
use clipmap::geom::{default_centre, tile_texels, LevelShape};
use clipmap::limits::Limits;
use clipmap::queue::{priority, ReadQueues, ReadRequest};
use clipmap::source::{HashSource, TextureDesc, TileId};
use clipmap::texel::TexelFormat;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use std::sync::Arc;

fn strip_copy(c: &mut Criterion) {
    let desc =
        TextureDesc::new([1 << 20; 2], 512, TexelFormat::RGBA8, [128; 2]).unwrap().with_invalid_border(8).unwrap();
    let settings = Settings { budget_ns: None, ..Settings::default() };
    let mut map = Clipmap::new(Arc::new(HashSource::new(desc)), settings).unwrap();
    let mut centre = [1i64 << 19; 2];
    for _ in 0..20 {
        if map.tick(centre, Some([0, 0])).min_lod == 0.0 {
            break;
        }
        map.wait_for_reads();
    }
    let d = 32i64;
    let mut group = c.benchmark_group("update_tick");
    // Level 0 uncovers d x 512 texels, level 1 d/2 x 512, ...: about 2·d·clip texels.
    group.throughput(Throughput::Bytes((2 * d as u64 * 512 - 512) * 4));
    for (name, v) in [("move_s_32", [d, 0]), ("move_t_32", [0, d])] {
        // Back and forth every 200 ticks, so that the centre stays well inside the texture
        // however many iterations criterion runs.
        let mut tick = 0u64;
        group.bench_function(name, |b| {
            b.iter(|| {
                let sign = if (tick / 200).is_multiple_of(2) { 1 } else { -1 };
                tick += 1;
                let v = [sign * v[0], sign * v[1]];
                centre = [centre[0] + v[0], centre[1] + v[1]];
                let r = map.tick(centre, Some(v));
                map.wait_for_reads();
                black_box(r.tiles_read)
            })
        });
    }
    group.finish();
}

fn residency(c: &mut Criterion) {
    let desc = TextureDesc::new([1 << 26; 2], 2048, TexelFormat::RGBA8, [256; 2]).unwrap();
    let shapes: Vec<LevelShape> = desc.levels().iter().map(|l| LevelShape::new(l.size, l.tile, 2048, 1)).collect();
    let mut centre = [1i64 << 25; 2];
    c.bench_function("residency_all_levels_2^26", |b| {
        b.iter(|| {
            centre[0] += 17;
            for (k, shape) in shapes.iter().enumerate() {
                black_box(shape.frame([centre[0] >> k, centre[1] >> k], 8, [17, 0]));
            }
        })
    });
}

/// A column strip against a row strip: the centre steps `d` texels and back, inside tiles that
/// stay resident, so each tick is only the copy of the strips (d columns, or d rows, of a
/// 512-texel window at level 0, half as many at level 1, ...).
fn strip_copy_resident(c: &mut Criterion) {
    let desc =
        TextureDesc::new([1 << 20; 2], 512, TexelFormat::RGBA8, [128; 2]).unwrap().with_invalid_border(8).unwrap();
    let settings = Settings { budget_ns: None, ..Settings::default() };
    let mut map = Clipmap::new(Arc::new(HashSource::new(desc)), settings).unwrap();
    // The windows' edges lie mid-tile, so a step of 32 texels needs no other tile.
    let home = [(1i64 << 19) + 64; 2];
    let d = 32i64;
    for i in 0..40 {
        let off = if i % 2 == 0 { 0 } else { d };
        map.tick([home[0] + off, home[1] + off], Some([0, 0]));
        map.wait_for_reads();
    }
    assert_eq!(map.tick(home, Some([0, 0])).min_lod, 0.0, "every level filled before timing");
    let mut group = c.benchmark_group("strip_copy");
    group.throughput(Throughput::Bytes((2 * d as u64 * 512 - 512) * 4));
    for (name, v) in [("column_32", [d, 0]), ("row_32", [0, d])] {
        let mut there = false;
        group.bench_function(name, |b| {
            b.iter(|| {
                there = !there;
                let c = if there { [home[0] + v[0], home[1] + v[1]] } else { home };
                let r = map.tick(c, Some([0, 0]));
                // Every level stays complete: the strips were copied from resident tiles.
                assert_eq!(r.min_lod, 0.0);
                black_box(r.tiles_read)
            })
        });
    }
    group.finish();
}

/// The priority refresh every tick does: (a) the priority of every tile in every level's mem
/// region of a 2^26 texture (clip 2048), (b) a read queue taking 1024 requests with fresh
/// priorities and re-sorting them (update, then a flush that waits for the runner; reads are held
/// back by a ready-read bound of 1, so no tile is read while timing).
fn priority_refresh(c: &mut Criterion) {
    let desc = TextureDesc::new([1 << 26; 2], 2048, TexelFormat::RGBA8, [256; 2]).unwrap();
    let shapes: Vec<LevelShape> = desc.levels().iter().map(|l| LevelShape::new(l.size, l.tile, 2048, 1)).collect();
    let levels = shapes.len();
    let mut group = c.benchmark_group("priority_refresh");
    let mut centre = [1i64 << 25; 2];
    group.bench_function("all_mem_tiles_2^26", |b| {
        b.iter(|| {
            centre[0] += 17;
            let v = [17, 5];
            let mut n = 0u32;
            for (k, shape) in shapes.iter().enumerate() {
                let f = shape.frame(default_centre(centre, k as u32), 8, v);
                for t in f.mem.t0..f.mem.t1 {
                    for s in f.mem.s0..f.mem.s1 {
                        let texels = tile_texels(shape.size, shape.tile, [s as u64, t as u64]);
                        n = n.wrapping_add(priority(k as u32, levels, texels, f.valid, 2048, v).rank);
                    }
                }
            }
            black_box(n)
        })
    });

    let small = TextureDesc::new([1 << 20; 2], 512, TexelFormat::RGBA8, [128; 2]).unwrap();
    let limits = Limits { max_pending_reads: 4096, max_ready_reads: 1, ..Limits::default() };
    let grids = Clipmap::grids(&small, &Settings::default());
    let memory =
        clipmap::shm::ImageMemory::anonymous(clipmap::clip::memory_shape(&small, &grids), small.format()).unwrap();
    let mut queues = ReadQueues::new(Arc::new(HashSource::new(small)), Arc::new(memory), 1, limits).unwrap();
    let tiles: Vec<TileId> =
        (0..32u64).flat_map(|t| (0..32u64).map(move |s| TileId::new(0, 4000 + s, 4000 + t))).collect();
    let mut step = 0i64;
    group.throughput(Throughput::Elements(tiles.len() as u64));
    group.bench_function("queue_update_1024", |b| {
        b.iter(|| {
            step += 1;
            // A valid region that moves, so every refresh reorders the queue.
            let base = 4016 * 128 + (step % 64) * 64;
            let valid = clipmap::geom::Rect::new(base, base, base + 496, base + 496);
            let wanted: Vec<ReadRequest> = tiles
                .iter()
                .map(|&tile| {
                    let texels = tile_texels([1 << 20; 2], [128; 2], [tile.s, tile.t]);
                    ReadRequest { tile, priority: priority(0, 13, texels, valid, 512, [32, -16]) }
                })
                .collect();
            queues.update(&wanted);
            queues.flush();
        })
    });
    group.finish();
}

criterion_group!(benches, strip_copy, strip_copy_resident, residency, priority_refresh);
criterion_main!(benches);
