//! Property tests over hostile input: arbitrary bytes, a soup of real token words, and valid files
//! mutated (byte flips, truncation, duplicated and deleted lines, huge numbers, inserted words).
//! Each case goes through both parsers, both plan builders, the tools' reports and tile location
//! (`common/exercise.rs`) and must not panic; findings stay bounded.
//!
//! The case count is fixed (fast in CI); `CLIPMAP_FUZZ_CASES=N` raises it for a longer run, which
//! is how this logic is fuzzed where `cargo fuzz` cannot run (see fuzz/README.md).

use crate::common;
use crate::common::exercise;
use crate::common::mutate::cases;

use common::*;
use proptest::prelude::*;

/// Words that reach deep into the reader.
const WORDS: &[&str] = &[
    "ct_version2.0",
    "ic_version1.0",
    "ext_format",
    "int_format",
    "img_format",
    "virt_size",
    "icache_size",
    "clip_size",
    "effective_levels",
    "allocated_levels",
    "invalid_border",
    "smallest_icache",
    "phase_shift",
    "icache_base",
    "icache_format",
    "icache_params",
    "header_offset",
    "tile_base",
    "tile_format",
    "tile_params",
    "icache_files",
    "tile_files",
    "tile_size",
    "page_size",
    "read_func",
    "lookahead",
    "mem_region_size",
    "cache_size",
    "tex_region_size",
    "valid_region_dst",
    "tiles_in_file",
    "s_streams",
    "t_stream",
    "r_stream",
    "num_streams",
    "default_tile",
    "PFTEX_PACK_8",
    "PFTEX_RGB_8",
    "PFTEX_RGB",
    "PFTEX_RGBA",
    "GL_BITMAP",
    "5121",
    "0",
    "1",
    "-1",
    "2",
    "3",
    "8",
    "256",
    "512",
    "1024",
    "4096",
    "65536",
    "4294967296",
    "9223372036854775807",
    "-9223372036854775808",
    "99999999999999999999",
    "%d",
    "%s%s.%d.r%03d.c%03d",
    "%",
    "%*d",
    "%999d",
    "%q",
    "PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S",
    "PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T",
    "PFIMAGECACHE_TILE_FILENAMEARG_STREAMSERVERNAME",
    "PFIMAGECACHE_TILE_FILENAMEARG_CACHENAME",
    "PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_S",
    "PFCLIPTEX_FNAMEARG_LEVEL",
    "PFCLIPTEX_FNAMEARG_IMAGE_CACHE_BASE",
    "#",
    "#x",
    ";",
    "//",
    "//srv/share",
    "rem",
    "comment",
    "$SET/x",
    "${UNSET:-/d}/y",
    "$(COLON)",
    "$",
    "${EMPTY}",
    "l.2048.ic",
    "l.1024.ic",
    "fuzz.ic",
    "fuzz.ct",
    "/dev/null",
    "..",
    "a/../b",
    "\u{e9}",
];

fn soup() -> impl Strategy<Value = Vec<u8>> {
    let sep = prop::sample::select(vec![" ", "\n", "\t", "  ", "\r\n", ""]);
    prop::collection::vec((prop::sample::select(WORDS), sep), 0..60).prop_map(|v| {
        let mut out = Vec::new();
        for (w, s) in v {
            out.extend_from_slice(w.as_bytes());
            out.extend_from_slice(s.as_bytes());
        }
        out
    })
}

fn bases() -> Vec<String> {
    vec![
        NO_IC_CT.to_string(),
        SMALL_IC.to_string(),
        format!(
            "ct_version2.0\n{RGB8}virt_size 2048 2048 1\nclip_size 512\n\
             icache_files l.2048.ic l.1024.ic\ntile_format p.%d\ntile_params PFCLIPTEX_FNAMEARG_LEVEL\n"
        ),
        format!(
            "{SMALL_IC}tiles_in_file 2 2 1\nheader_offset 64\ns_stream /a/ /b/\nt_stream /c/\n\
             tile_base $SET\ntile_format %s%s.%d.%d\ntile_params \
             PFIMAGECACHE_TILE_FILENAMEARG_STREAMSERVERNAME PFIMAGECACHE_TILE_FILENAMEARG_CACHENAME \
             PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_S PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T\n"
        ),
    ]
}

#[derive(Clone, Debug)]
enum Mutation {
    Flip(usize, u8),
    Truncate(usize),
    DuplicateLine(usize),
    DeleteLine(usize),
    HugeNumber(usize, &'static str),
    Insert(usize, &'static str),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let huge = prop::sample::select(vec![
        "4294967296",
        "1099511627776",
        "9223372036854775807",
        "18446744073709551616",
        "-9223372036854775808",
        "0",
        "-1",
    ]);
    prop_oneof![
        (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Mutation::Flip(i, b)),
        any::<usize>().prop_map(Mutation::Truncate),
        any::<usize>().prop_map(Mutation::DuplicateLine),
        any::<usize>().prop_map(Mutation::DeleteLine),
        (any::<usize>(), huge).prop_map(|(i, n)| Mutation::HugeNumber(i, n)),
        (any::<usize>(), prop::sample::select(WORDS)).prop_map(|(i, w)| Mutation::Insert(i, w)),
    ]
}

fn apply(text: &str, muts: &[Mutation]) -> Vec<u8> {
    let mut b = text.as_bytes().to_vec();
    for m in muts {
        let lines = |b: &[u8]| -> Vec<Vec<u8>> { b.split(|&c| c == b'\n').map(<[u8]>::to_vec).collect() };
        match *m {
            Mutation::Flip(i, x) if !b.is_empty() => {
                let n = b.len();
                b[i % n] ^= x;
            }
            Mutation::Truncate(i) => b.truncate(i % (b.len() + 1)),
            Mutation::DuplicateLine(i) => {
                let mut l = lines(&b);
                let k = i % l.len();
                l.insert(k, l[k].clone());
                b = l.join(&b'\n');
            }
            Mutation::DeleteLine(i) => {
                let mut l = lines(&b);
                l.remove(i % l.len());
                b = l.join(&b'\n');
            }
            Mutation::HugeNumber(i, n) => {
                let s = String::from_utf8_lossy(&b).into_owned();
                let words: Vec<(usize, &str)> = s
                    .split_ascii_whitespace()
                    .map(|w| (w.as_ptr() as usize - s.as_ptr() as usize, w))
                    .filter(|(_, w)| w.parse::<i64>().is_ok())
                    .collect();
                if !words.is_empty() {
                    let (at, w) = words[i % words.len()];
                    let mut t = s.clone();
                    t.replace_range(at..at + w.len(), n);
                    b = t.into_bytes();
                }
            }
            Mutation::Insert(i, w) => {
                let at = i % (b.len() + 1);
                let mut ins = format!(" {w} ").into_bytes();
                let tail = b.split_off(at);
                b.append(&mut ins);
                b.extend(tail);
            }
            Mutation::Flip(..) => {}
        }
    }
    b
}

fn run(bytes: &[u8]) {
    let fx = Fixture::new();
    fx.write_level_ics("l", 2048, 1024, 256);
    exercise::exercise(bytes, fx.dir.path());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(300), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        run(&bytes);
    }

    #[test]
    fn token_soup_never_panics(bytes in soup()) {
        run(&bytes);
    }

    #[test]
    fn mutated_valid_files_never_panic(
        base in prop::sample::select(bases()),
        muts in prop::collection::vec(mutation(), 1..5),
    ) {
        run(&apply(&base, &muts));
    }
}
