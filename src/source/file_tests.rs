//! Tests of [`FileSource`]: pyramids written by [`crate::prep`] read back equal to the hash
//! texture, every failure maps to its kind, default tiles stand in, and a clipmap over files
//! publishes only correct texels.

use super::*;
use crate::clip::tests::{check_published, settle, tick_and_check};
use crate::clip::{Clipmap, Settings};
use crate::plan::{self, ClipTexturePlan};
use crate::prep::{self, Filter, Job, Layout, Spec};
use crate::source::range::RangeError;
use crate::source::{FaultKind, HashSource};
use std::fs::File;
use std::os::unix::fs::PermissionsExt;
use std::sync::atomic::AtomicBool;

/// Prepares a hash texture under `dir` with the library's preparation API; returns the `.ct`.
fn prepare(
    dir: &Path,
    size: u64,
    clip: u64,
    tile: u64,
    tiles_in_file: (u64, u64),
    header: u64,
    streams: Option<u32>,
) -> PathBuf {
    prepare_spec(dir, Spec { tiles_in_file, header_bytes: header, streams, ..spec(size, clip, tile) })
}

/// A square RGB8 texture, one tile per file, no header, streams, inset or compression.
fn spec(size: u64, clip: u64, tile: u64) -> Spec {
    Spec::plain(size, size, clip, tile)
}

/// Prepares the hash texture of `spec` under `dir`; returns the `.ct`.
fn prepare_spec(dir: &Path, spec: Spec) -> PathBuf {
    let job = Job {
        layout: Layout::new(spec).unwrap(),
        source: prep::Source::Hash,
        filter: Filter::Box,
        linear_light: false,
        name: "hash".into(),
        description: vec![],
        limits: prep::Limits::default(),
    };
    let summary = prep::run(job, dir, &AtomicBool::new(false), dir, &|_| {}).unwrap();
    dir.join(summary.ct)
}

/// A hash texture whose image-cache tiles are compressed as `clipprep --zstd 3` writes them.
fn prepare_zstd(dir: &Path, size: u64, clip: u64, tile: u64) -> PathBuf {
    prepare_spec(dir, Spec { compression: Some(prep::Compression::Zstd(3)), ..spec(size, clip, tile) })
}

fn load(ct: &Path) -> ClipTexturePlan {
    let loaded = plan::load_clip_texture(ct, &plan::Options::default()).unwrap();
    let rendered = loaded.render();
    loaded.plan.unwrap_or_else(|| panic!("{}: {rendered}", ct.display()))
}

fn open(ct: &Path) -> FileSource {
    FileSource::new(load(ct), &Limits::default()).unwrap()
}

/// Every tile of every level of `files` against the hash texture of the same shape.
fn assert_equals_hash(files: &FileSource) -> u64 {
    let hash = HashSource::new(files.desc().clone());
    let mut tiles = 0;
    for k in 0..files.desc().level_count() as u32 {
        let n = files.desc().level(k).tiles();
        let mut got = vec![0u8; files.desc().tile_bytes(k)];
        let mut want = got.clone();
        for t in 0..n[1] {
            for s in 0..n[0] {
                let id = TileId::new(k, s, t);
                files.read_tile(id, &mut got).unwrap_or_else(|e| panic!("{e}"));
                hash.read_tile(id, &mut want).unwrap();
                assert!(got == want, "{id}: file texels differ from the hash texture");
                tiles += 1;
            }
        }
    }
    tiles
}

#[test]
fn a_prepared_hash_pyramid_reads_back_equal_to_the_hash_source_tile_for_tile() {
    let dir = tempfile::tempdir().unwrap();
    let files = open(&prepare(dir.path(), 256, 32, 16, (1, 1), 0, None));
    assert_eq!(files.desc().level_count(), 9);
    assert_eq!(files.desc().level(0).tile, [16, 16]);
    assert_eq!(files.desc().level(3).tile, [32, 32], "pyramid level: one tile the size of the level");
    let tiles = assert_equals_hash(&files);
    assert_eq!(tiles, 256 + 64 + 16 + 6, "levels 256, 128 and 64 are image caches");
    let st = files.stats();
    assert_eq!((st.reads, st.default_tiles), (tiles, 0));
    assert_eq!(st.bytes_read, (256 * 256 + 128 * 128 + 64 * 64) * 3 + (32 * 32 + 16 * 16 + 64 + 16 + 4 + 1) * 3);
}

#[test]
fn multi_tile_files_with_headers_and_streams_read_back_equal_to_the_hash_source() {
    let dir = tempfile::tempdir().unwrap();
    let files = open(&prepare(dir.path(), 256, 32, 16, (4, 2), 100, Some(3)));
    assert_equals_hash(&files);
    assert_eq!(files.stream_servers(), 3);
    assert_eq!(files.stream_names().len(), 3);
    assert!(files.stream_names()[2].ends_with("stream2/"), "{:?}", files.stream_names());
    // The plan's stream choice (tile column mod 3) is the queue; pyramid levels use S mod n.
    for s in 0..16 {
        assert_eq!(files.stream_of(TileId::new(0, s, 5), 3), (s % 3) as usize);
        assert_eq!(files.stream_of(TileId::new(1, s % 8, 0), 2), ((s % 8) % 3 % 2) as usize);
    }
    assert_eq!(files.stream_of(TileId::new(4, 0, 0), 3), 0);
    // 8 tiles per file (spread over the stream directories by column): fewer files opened than
    // tiles read, even with handles evicted.
    let st = files.stats();
    assert!(st.files_opened < st.reads / 2 && st.open_files <= 64, "{st:?}");
}

#[test]
fn the_checked_in_prepared_example_reads_back_equal_to_the_hash_source() {
    let ct = Path::new(env!("CARGO_MANIFEST_DIR")).join("config_examples/prepared/hash256.ct");
    let files = open(&ct);
    assert_eq!((files.desc().clip_size(), files.desc().bytes_per_texel()), (64, 3));
    assert_eq!(assert_equals_hash(&files), 16 + 4 + 7);
}

#[test]
fn compressed_tiles_read_back_equal_to_the_hash_source() {
    let dir = tempfile::tempdir().unwrap();
    let ct = prepare_zstd(dir.path(), 256, 32, 16);
    let l0 = dir.path().join("L00");
    assert!(l0.join("r000.c000.raw.zst").exists() && !l0.join("r000.c000.raw").exists());
    let files = open(&ct);
    // The hash texture does not compress: a compressed tile file is longer than the raw tile, so
    // reading its bytes as texels would go unnoticed by a length check. Every texel is compared.
    assert_eq!(assert_equals_hash(&files), 256 + 64 + 16 + 6);
    assert_eq!(files.stats().default_tiles, 0);
}

#[test]
fn compressed_tiles_that_do_not_decode_to_one_tile_are_corrupt_never_texels() {
    let dir = tempfile::tempdir().unwrap();
    let ct = prepare_zstd(dir.path(), 128, 32, 16);
    let l0 = dir.path().join("L00");
    let path = |s: u64, t: u64| l0.join(format!("r{t:03}.c{s:03}.raw.zst"));
    let good = std::fs::read(path(0, 0)).unwrap();
    // Truncated; garbage; a valid frame of a tile half as long; a file longer than any frame of
    // one tile; and, to show the frame itself is what is checked, the good frame moved elsewhere.
    std::fs::write(path(1, 0), &good[..good.len() / 2]).unwrap();
    std::fs::write(path(2, 0), vec![0xA5u8; good.len()]).unwrap();
    std::fs::write(path(3, 0), zstd::bulk::compress(&vec![7u8; 16 * 16 * 3 / 2], 3).unwrap()).unwrap();
    std::fs::write(path(4, 0), vec![0u8; 16 * 16 * 3 * 2 + 4096]).unwrap();
    std::fs::write(path(5, 0), &good).unwrap();
    let files = open(&ct);
    let mut buf = vec![0u8; files.desc().tile_bytes(0)];
    for (s, want) in
        [(1, "not one zstd frame"), (2, "not one zstd frame"), (3, "decodes to 384 bytes"), (4, "more than one")]
    {
        let e = files.read_tile(TileId::new(0, s, 0), &mut buf).unwrap_err();
        assert_eq!(e.kind(), FaultKind::Corrupt, "tile ({s}, 0): {e}");
        let msg = e.to_string();
        assert!(msg.contains(want) && msg.contains(".raw.zst") && msg.contains("clipprep --zstd"), "{msg}");
    }
    // Tile (5, 0) now holds tile (0, 0)'s texels: readable, and (as with raw files) not ours to
    // detect; tile (0, 0) itself is still right.
    files.read_tile(TileId::new(0, 5, 0), &mut buf).unwrap();
    let mut want = vec![0u8; buf.len()];
    HashSource::new(files.desc().clone()).read_tile(TileId::new(0, 0, 0), &mut want).unwrap();
    assert_eq!(buf, want);
    files.read_tile(TileId::new(0, 0, 0), &mut buf).unwrap();
    assert_eq!(buf, want);
}

/// Whether this process ignores file permissions (root, or CAP_DAC_OVERRIDE): a real probe.
fn permissions_ignored(dir: &Path) -> bool {
    let probe = dir.join("probe");
    std::fs::write(&probe, b"x").unwrap();
    std::fs::set_permissions(&probe, std::fs::Permissions::from_mode(0o000)).unwrap();
    let ignored = File::open(&probe).is_ok();
    std::fs::remove_file(&probe).unwrap();
    ignored
}

#[test]
fn missing_short_and_unreadable_tiles_fail_with_their_kind() {
    let dir = tempfile::tempdir().unwrap();
    let ct = prepare(dir.path(), 128, 32, 16, (1, 1), 0, None);
    let level0 = dir.path().join("L00");
    std::fs::remove_file(level0.join("r000.c001.raw")).unwrap();
    let short = level0.join("r001.c000.raw");
    let f = std::fs::OpenOptions::new().write(true).open(&short).unwrap();
    f.set_len(100).unwrap();
    drop(f);
    let locked = level0.join("r002.c002.raw");
    std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o000)).unwrap();
    let files = open(&ct);
    let mut buf = vec![0u8; files.desc().tile_bytes(0)];
    let err = |s, t, buf: &mut Vec<u8>| files.read_tile(TileId::new(0, s, t), buf).unwrap_err();
    assert_eq!(err(1, 0, &mut buf).kind(), FaultKind::Missing);
    match err(0, 1, &mut buf) {
        SourceError::Short { expected, got, .. } => assert_eq!((expected, got), (768, 100)),
        e => panic!("expected a short read, got {e}"),
    }
    if permissions_ignored(dir.path()) {
        eprintln!("skipping the permission case: this process reads files whatever their mode (root)");
    } else {
        assert_eq!(err(2, 2, &mut buf).kind(), FaultKind::PermissionDenied);
    }
    // A pyramid file that is too short, and a request outside the level.
    let pyramid = dir.path().join("pyramid/L03.raw");
    std::fs::write(&pyramid, [0u8; 10]).unwrap();
    let mut p = vec![0u8; files.desc().tile_bytes(3)];
    assert_eq!(files.read_tile(TileId::new(3, 0, 0), &mut p).unwrap_err().kind(), FaultKind::Short);
    assert_eq!(err(8, 0, &mut buf).kind(), FaultKind::BadRequest);
    files.read_tile(TileId::new(0, 3, 3), &mut buf).unwrap();
    assert_eq!(files.stats().default_tiles, 0);
}

#[test]
fn a_default_tile_stands_in_for_missing_and_short_tiles_and_is_counted() {
    let dir = tempfile::tempdir().unwrap();
    let ct = prepare(dir.path(), 128, 32, 16, (1, 1), 0, None);
    let ic = dir.path().join("L00.ic");
    let mut text = std::fs::read_to_string(&ic).unwrap();
    text.push_str("default_tile sea.raw\n");
    std::fs::write(&ic, text).unwrap();
    let sea: Vec<u8> = (0..16 * 16 * 3).map(|i| (i % 251) as u8).collect();
    std::fs::write(dir.path().join("sea.raw"), &sea).unwrap();
    std::fs::remove_file(dir.path().join("L00/r000.c001.raw")).unwrap();
    std::fs::write(dir.path().join("L00/r001.c000.raw"), [1u8; 7]).unwrap();
    let files = open(&ct);
    assert!(files.has_default_tile(0) && !files.has_default_tile(1));
    let mut buf = vec![0u8; files.desc().tile_bytes(0)];
    files.read_tile(TileId::new(0, 1, 0), &mut buf).unwrap();
    assert_eq!(buf, sea);
    files.read_tile(TileId::new(0, 0, 1), &mut buf).unwrap();
    assert_eq!(buf, sea);
    let hash = HashSource::new(files.desc().clone());
    let mut want = buf.clone();
    files.read_tile(TileId::new(0, 2, 2), &mut buf).unwrap();
    hash.read_tile(TileId::new(0, 2, 2), &mut want).unwrap();
    assert_eq!(buf, want, "present tiles are read from their files");
    assert_eq!(files.stats().default_tiles, 2);

    // A default tile of the wrong size is refused when the source opens.
    std::fs::write(dir.path().join("sea.raw"), &sea[..700]).unwrap();
    let e = FileSource::new(load(&ct), &Limits::default()).err().expect("a short default tile is refused");
    assert!(matches!(e, FileSourceError::DefaultTileSize { level: 0, found: 700, expected: 768, .. }), "{e}");
    assert!(e.to_string().contains("expected 768 (one 16x16 tile)"), "{e}");
    std::fs::remove_file(dir.path().join("sea.raw")).unwrap();
    let e = FileSource::new(load(&ct), &Limits::default()).err().expect("a missing default tile is refused");
    assert!(matches!(e, FileSourceError::DefaultTileRead { level: 0, .. }), "{e}");
}

#[test]
fn open_file_handles_stay_within_their_bound() {
    let dir = tempfile::tempdir().unwrap();
    let ct = prepare(dir.path(), 128, 32, 16, (1, 1), 0, None);
    let limits = Limits { max_open_files: 3, ..Limits::default() };
    let files = FileSource::new(load(&ct), &limits).unwrap();
    let mut buf = vec![0u8; files.desc().tile_bytes(0)];
    for round in 0..2 {
        for s in 0..8 {
            files.read_tile(TileId::new(0, s, 0), &mut buf).unwrap();
            assert!(files.stats().open_files <= 3);
        }
        // The last three stay open: reading them again opens nothing.
        let opened = files.stats().files_opened;
        for s in 5..8 {
            files.read_tile(TileId::new(0, s, 0), &mut buf).unwrap();
        }
        assert_eq!(files.stats().files_opened, opened, "round {round}");
    }
    let none = FileSource::new(load(&ct), &Limits { max_open_files: 0, ..Limits::default() }).unwrap();
    none.read_tile(TileId::new(0, 0, 0), &mut buf).unwrap();
    none.read_tile(TileId::new(0, 0, 0), &mut buf).unwrap();
    assert_eq!((none.stats().files_opened, none.stats().open_files), (2, 0));
}

#[test]
fn a_clipmap_over_files_publishes_only_hash_texels_during_a_random_walk() {
    let dir = tempfile::tempdir().unwrap();
    random_walk_publishes_only_hash_texels(Arc::new(open(&prepare(dir.path(), 1024, 64, 32, (2, 2), 64, Some(2)))));
}

#[test]
fn a_clipmap_over_compressed_tiles_publishes_only_hash_texels_during_a_random_walk() {
    let dir = tempfile::tempdir().unwrap();
    random_walk_publishes_only_hash_texels(Arc::new(open(&prepare_zstd(dir.path(), 1024, 64, 32))));
}

/// Flies a clipmap over `files` (a hash texture) with jumps and partial waits, checking every
/// publication against the hash texture, then settles and checks again.
fn random_walk_publishes_only_hash_texels(files: Arc<FileSource>) {
    let settings =
        Settings { streams: files.stream_servers(), budget_ns: Some(40_000), fade_ticks: 2, ..Settings::default() };
    let mut map = Clipmap::new(files.clone(), settings).unwrap();
    let mut errors = Vec::new();
    let mut c = [500i64, 500];
    let mut x = 0x5EEDu64;
    for step in 0..60 {
        x = crate::source::procedural::splitmix64(x);
        if step % 15 == 14 {
            c = [(x % 1100) as i64 - 30, ((x >> 20) % 1100) as i64 - 30];
        } else {
            c = [c[0] + (x % 41) as i64 - 20, c[1] + ((x >> 8) % 41) as i64 - 20];
        }
        tick_and_check(&mut map, c, &mut errors);
        assert!(errors.is_empty(), "step {step}: {errors:?}");
        if !x.is_multiple_of(3) {
            map.wait_for_reads();
        }
    }
    map.set_budget_ns(None);
    settle(&mut map, c, 60);
    assert!(check_published(&map).unwrap() > 0);
    assert_eq!(map.stats().tick_texel_bytes, 0);
    assert_eq!(map.stats().read_faults.total(), 0);
    assert!(files.stats().reads > 0);
}

/// Objects read by name as a remote store serves them: no size known beforehand, each read
/// counted.
#[derive(Default)]
struct Objects {
    bytes: HashMap<String, Vec<u8>>,
    reads: AtomicU64,
}

struct Object<'a>(&'a Objects, &'a [u8]);

impl RangeRead for Object<'_> {
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<(), RangeError> {
        match self.read_upto(offset, buf)? {
            n if n == buf.len() => Ok(()),
            n => Err(RangeError::Eof { size: offset + n as u64 }),
        }
    }

    fn read_upto(&self, offset: u64, buf: &mut [u8]) -> Result<usize, RangeError> {
        self.0.reads.fetch_add(1, Ordering::Relaxed);
        let start = (offset as usize).min(self.1.len());
        let n = (self.1.len() - start).min(buf.len());
        buf[..n].copy_from_slice(&self.1[start..start + n]);
        Ok(n)
    }
}

impl ByName for Objects {
    fn reader<'a>(&'a self, name: &'a RemoteName) -> Box<dyn RangeRead + 'a> {
        Box::new(Object(self, self.bytes.get(name.as_str()).map_or(&[][..], |b| b.as_slice())))
    }
}

#[test]
fn compressed_tiles_read_by_name_decode_in_one_read_and_are_refused_as_local_ones_are() {
    let tile: Vec<u8> = (0..768u32).map(|i| (i * 7 % 251) as u8).collect();
    let frame = zstd::bulk::compress(&tile, 3).unwrap();
    let mut objects = Objects::default();
    objects.bytes.insert("http://h:1/good.raw.zst".into(), frame.clone());
    objects.bytes.insert("http://h:1/long.raw.zst".into(), vec![0u8; 768 * 2 + 4096]);
    objects.bytes.insert("http://h:1/half.raw.zst".into(), zstd::bulk::compress(&tile[..384], 3).unwrap());
    objects.bytes.insert("http://h:1/raw.raw".into(), tile.clone());
    let read = |name: &str, offset: u64, out: &mut [u8]| {
        let place = Place::parse(name);
        let Place::Remote(remote) = &place else { panic!("{name}") };
        let reader = objects.reader(remote);
        read_stored(&*reader, &place, TileId::new(0, 0, 0), offset, out)
    };
    let mut out = vec![0u8; 768];
    read("http://h:1/good.raw.zst", 0, &mut out).unwrap();
    assert_eq!(out, tile);
    assert_eq!(objects.reads.load(Ordering::Relaxed), 1, "one read of the whole object");
    for (name, offset, want) in [
        ("http://h:1/long.raw.zst", 0, "the object holds more than one 768-byte tile compresses to"),
        ("http://h:1/half.raw.zst", 0, "decodes to 384 bytes"),
        ("http://h:1/good.raw.zst", 100, "placed at byte 100"),
    ] {
        match read(name, offset, &mut out) {
            Err(SourceError::Undecodable { path, problem, .. }) => {
                assert!(problem.contains(want) && path == Path::new(name), "{name}: {problem}")
            }
            other => panic!("{name}: {other:?}"),
        }
    }
    // A raw tile by name: the range read, a short one short.
    let mut half = vec![0u8; 384];
    read("http://h:1/raw.raw", 384, &mut half).unwrap();
    assert_eq!(half, tile[384..]);
    match read("http://h:1/raw.raw", 500, &mut half) {
        Err(SourceError::Short { expected, got, .. }) => assert_eq!((expected, got), (384, 268)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_small_whole_object_is_read_in_one_read_and_a_local_file_of_another_length_is_not_read() {
    let mut objects = Objects::default();
    objects.bytes.insert("http://h:1/sea.raw".into(), vec![3u8; 768]);
    objects.bytes.insert("http://h:1/big.raw".into(), vec![3u8; 5000]);
    let name = |n: &str| RemoteName::parse(n).unwrap();
    let sea = name("http://h:1/sea.raw");
    assert_eq!(read_sized(&*objects.reader(&sea), &[768, 868]).unwrap(), vec![3u8; 768]);
    // Longer than allowed: found to be so from one byte more than the most allowed.
    let big = name("http://h:1/big.raw");
    assert!(matches!(read_sized(&*objects.reader(&big), &[768, 868]), Err(SizedError::Length(869))));
    assert_eq!(objects.reads.load(Ordering::Relaxed), 2);
    // A local file says its length first: refused with it, before a byte is read.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("big.raw");
    std::fs::write(&path, vec![0u8; 5000]).unwrap();
    let local = LocalFile(File::open(&path).unwrap());
    assert!(matches!(read_sized(&local, &[768]), Err(SizedError::Length(5000))));
    std::fs::write(&path, vec![9u8; 768]).unwrap();
    assert_eq!(read_sized(&local, &[768]).unwrap(), vec![9u8; 768]);
}
