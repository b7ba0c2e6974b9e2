//! Micro-benchmarks of the paging engine: one update tick during a steady flight (its strip
//! copies, plus waiting for the tiles it asked for), and the residency geometry (every level's
//! regions for a centre) of a 2^26 texture.
//! `cargo bench --bench engine`; `clipbench engine` measures the goals in one run.

use clipmap::clip::{Clipmap, CostTable, Settings};
use clipmap::geom::LevelShape;
use clipmap::source::{HashSource, TextureDesc};
use clipmap::texel::TexelFormat;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use std::sync::Arc;

fn strip_copy(c: &mut Criterion) {
    let desc =
        TextureDesc::new([1 << 20; 2], 512, TexelFormat::RGBA8, [128; 2]).unwrap().with_invalid_border(8).unwrap();
    let settings = Settings { budget_ns: None, cost: Some(CostTable::fixed(200.0, 10.0, 0.1)), ..Settings::default() };
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
                let sign = if (tick / 200) % 2 == 0 { 1 } else { -1 };
                tick += 1;
                let v = [sign * v[0], sign * v[1]];
                centre = [centre[0] + v[0], centre[1] + v[1]];
                let r = map.tick(centre, Some(v));
                map.wait_for_reads();
                black_box(r.bytes_copied)
            })
        });
    }
    group.finish();
}

fn residency(c: &mut Criterion) {
    let desc = TextureDesc::new([1 << 26; 2], 2048, TexelFormat::RGBA8, [256; 2]).unwrap();
    let shapes: Vec<LevelShape> =
        desc.levels().iter().map(|l| LevelShape { size: l.size, tile: l.tile, clip: 2048, lookahead: 1 }).collect();
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

criterion_group!(benches, strip_copy, residency);
criterion_main!(benches);
