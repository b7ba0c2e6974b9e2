//! 16-bit texel formats end to end: a 16-bit height map through the real `clipprep`, a dump
//! (`cliptex dump`, a 16-bit PNG) and the real `clipmapd` (texels read through the Rust client),
//! bit for bit; 16-bit RGB(A), grey+alpha and streamed TIFF inputs; an input deeper than its
//! format refused unless the reduction is asked for; 8-bit inputs widened exactly; the
//! procedural sources in every 16-bit format; the mapping's format codes as the C header and the
//! Python reader mirror them.

use crate::common;

use clipmap::source::procedural::splitmix64;
use common::exec;
use image::{DynamicImage, ImageBuffer, Luma, LumaA, Rgb, Rgba};
use serde_json::Value;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const CLIPPREP: &str = env!("CARGO_BIN_EXE_clipprep");
const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");
const CLIPMAPD: &str = env!("CARGO_BIN_EXE_clipmapd");
const ICACHE: &str = env!("CARGO_BIN_EXE_icache");
const ROOT: &str = env!("CLIPMAP_ROOT");

/// Runs `prog args` in `cwd`; it must succeed; returns stdout.
fn ok(cwd: &Path, prog: &str, args: &[&str]) -> String {
    let (out, d) = exec(cwd, prog, args);
    assert!(out.status.success(), "expected success\n{d}");
    String::from_utf8(out.stdout).unwrap()
}

/// A pseudo-random value in `lo..=hi` for pixel (x, y) and channel `c` (not a gradient: every
/// bit of every sample varies).
fn noise(x: u32, y: u32, c: u32, lo: u16, hi: u16) -> u16 {
    let h = splitmix64(((c as u64) << 48) ^ ((y as u64) << 24) ^ x as u64);
    lo + (h % (hi as u64 - lo as u64 + 1)) as u16
}

/// A height map of 201 m to 1497 m (one metre per step): smooth hills plus noise.
fn height_map(w: u32, h: u32) -> ImageBuffer<Luma<u16>, Vec<u16>> {
    ImageBuffer::from_fn(w, h, |x, y| {
        let hills = 850.0 + 320.0 * ((x as f64 / 37.0).sin() + (y as f64 / 23.0).cos());
        let v = hills + noise(x, y, 0, 0, 96) as f64 - 48.0;
        Luma([(v.round() as i64).clamp(201, 1497) as u16])
    })
}

/// Prepares `input` with `args` into `dir/out`; returns the `.ct` path and the JSON summary.
fn prep(dir: &Path, input: &Path, args: &[&str]) -> (PathBuf, Value) {
    let out = dir.join("out");
    let mut all = vec!["--input", input.to_str().unwrap(), "--out", out.to_str().unwrap(), "--json"];
    all.extend_from_slice(args);
    let summary: Value = serde_json::from_str(&ok(dir, CLIPPREP, &all)).expect("--json prints JSON");
    (dir.join(summary["ct"].as_str().unwrap()), summary)
}

/// `cliptex validate --strict` passes and `cliptex info` reads the format back as `format`.
fn validates_as(dir: &Path, ct: &Path, format: &str) {
    let ct = ct.to_str().unwrap();
    ok(dir, CLIPTEX, &["validate", ct, "--strict"]);
    let info: Value = serde_json::from_str(&ok(dir, CLIPTEX, &["info", ct, "--json"])).unwrap();
    assert_eq!(info["texel_format"], format, "{info}");
}

/// Dumps `level` of `ct` to a PNG; returns the picture and the report.
fn dump(dir: &Path, ct: &Path, level: u32) -> (DynamicImage, Value) {
    let png = dir.join(format!("dump-{level}.png"));
    let l = level.to_string();
    let report =
        ok(dir, CLIPTEX, &["dump", ct.to_str().unwrap(), "--level", &l, "--out", png.to_str().unwrap(), "--json"]);
    let report: Value = serde_json::from_str(&report).unwrap();
    (image::open(&png).expect("the dump is a PNG"), report)
}

/// A running `clipmapd`, killed on drop.
struct Service {
    child: Child,
    socket: PathBuf,
    err: PathBuf,
}

impl Service {
    fn start(dir: &Path, name: &str, ct: &Path) -> Service {
        let socket = dir.join(format!("{name}.sock"));
        let err = dir.join(format!("{name}.err"));
        let child = Command::new(CLIPMAPD)
            .arg(ct)
            .args(["--tick-hz", "120", "--name", name, "--shm-dir", dir.to_str().unwrap(), "--socket"])
            .arg(&socket)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&err).unwrap())
            .spawn()
            .unwrap();
        let s = Service { child, socket, err };
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(30) {
            if let Ok(mut c) = UnixStream::connect(&s.socket) {
                let mut line = String::new();
                if writeln!(c, "PING").is_ok()
                    && BufReader::new(c).read_line(&mut line).is_ok()
                    && line.starts_with("OK")
                {
                    return s;
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!("the service did not come up: {}", s.log());
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.err).unwrap_or_default()
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Waits until level `k` is published enabled around `centre` (any centre when `None`) with
/// a non-empty valid region; returns the region `[s0, t0, s1, t1]`.
fn valid_region(c: &clipmap::shm::Client, k: usize, centre: Option<[i64; 2]>, svc: &Service) -> [i64; 4] {
    let t = Instant::now();
    loop {
        if let Some(st) = c.level_state(k) {
            let [s0, t0, s1, t1] = st.valid;
            if st.enabled && s1 > s0 && t1 > t0 && centre.is_none_or(|want| st.centre == want) {
                return st.valid;
            }
        }
        assert!(t.elapsed() < Duration::from_secs(30), "level {k} never became valid\n{}", svc.log());
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Reads the valid region of level `k` through the client and checks every texel against
/// `want(s, t)`; returns the number of texels checked.
fn check_served(c: &clipmap::shm::Client, k: usize, v: [i64; 4], want: &dyn Fn(i64, i64) -> u16) -> usize {
    let [s0, t0, s1, t1] = v;
    let (w, h) = ((s1 - s0) as u64, (t1 - t0) as u64);
    let mut buf = vec![0u8; (w * h * 2) as usize];
    c.read_region(k, s0, t0, w, h, &mut buf).expect("the valid region reads");
    for (i, texel) in buf.chunks_exact(2).enumerate() {
        let (s, t) = (s0 + (i as u64 % w) as i64, t0 + (i as u64 / w) as i64);
        let got = u16::from_le_bytes([texel[0], texel[1]]);
        assert_eq!(got, want(s, t), "level {k} texel ({s}, {t}) as served");
    }
    buf.len() / 2
}

#[test]
fn a_sixteen_bit_height_map_round_trips_bit_exactly_through_clipprep_the_service_and_a_dump() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (w, h) = (512u32, 256u32);
    let heights = height_map(w, h);
    let (lo, hi) = heights.pixels().fold((u16::MAX, 0), |(lo, hi), p| (lo.min(p[0]), hi.max(p[0])));
    assert!(lo <= 210 && hi >= 1400, "the map spans its range: {lo}..{hi}");
    let input = d.join("heights.png");
    heights.save(&input).unwrap();
    assert!(matches!(image::open(&input).unwrap(), DynamicImage::ImageLuma16(_)), "the input is a 16-bit PNG");

    let (ct, summary) = prep(d, &input, &["--tile", "64", "--clip", "128", "--format", "l16"]);
    assert_eq!(summary["format"], "l16", "{summary}");
    validates_as(d, &ct, "l16");
    let ct_text = std::fs::read_to_string(&ct).unwrap();
    assert!(ct_text.contains("ext_format PFTEX_UNSIGNED_SHORT"), "{ct_text}");
    assert!(ct_text.contains("int_format GL_LUMINANCE16_EXT"), "{ct_text}");

    // (a) The dump of level 0 is a 16-bit grey PNG equal to the input.
    let (l0, report) = dump(d, &ct, 0);
    assert_eq!((report["colour"].as_str(), report["format"].as_str()), (Some("l16"), Some("l16")), "{report}");
    let l0 = l0.as_luma16().expect("a 16-bit format dumps to a 16-bit grey PNG").clone();
    assert_eq!(l0.dimensions(), (w, h));
    assert!(l0 == heights, "level 0 as dumped differs from the input");

    // Level 1 is the 2x2 box of level 0, floor((a + b + c + d + 2) / 4), exactly (image rows and
    // t run opposite ways, but 2x2 blocks line up).
    let (l1, _) = dump(d, &ct, 1);
    let l1 = l1.as_luma16().expect("16-bit").clone();
    assert_eq!(l1.dimensions(), (w / 2, h / 2));
    let box2 = |x: u32, y: u32| -> u16 {
        let p = |dx: u32, dy: u32| heights.get_pixel(2 * x + dx, 2 * y + dy)[0] as u32;
        ((p(0, 0) + p(1, 0) + p(0, 1) + p(1, 1) + 2) / 4) as u16
    };
    for (x, y, p) in l1.enumerate_pixels() {
        assert_eq!(p[0], box2(x, y), "level 1 pixel ({x}, {y})");
    }

    // (b) The service serves the same texels: level-0 texel (s, t) is image pixel (s, H-1-t).
    let svc = Service::start(d, "heights", &ct);
    let c = clipmap::shm::Client::attach(d, "heights").expect("the mapping is there");
    assert_eq!((c.format_code, c.bytes_per_texel), (7, 2), "L16 in the mapping's header");
    let want0 = |s: i64, t: i64| heights.get_pixel(s as u32, h - 1 - t as u32)[0];
    let want1 = |s: i64, t: i64| l1.get_pixel(s as u32, h / 2 - 1 - t as u32)[0];
    let mut checked = 0;
    let v = valid_region(&c, 0, None, &svc);
    checked += check_served(&c, 0, v, &want0);
    // Elsewhere too: near a corner, then the other.
    for centre in [[100i64, 60i64], [430, 200]] {
        c.request_centre(centre, [0.0, 0.0]);
        let v = valid_region(&c, 0, Some(centre), &svc);
        checked += check_served(&c, 0, v, &want0);
        let v1 = valid_region(&c, 1, None, &svc);
        checked += check_served(&c, 1, v1, &want1);
    }
    assert!(checked > 3 * 100 * 100, "{checked} texels checked");
}

#[test]
fn sixteen_bit_colour_and_grey_alpha_pngs_round_trip_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (w, h) = (128u32, 128u32);
    let n = |x, y, c| noise(x, y, c, 0, u16::MAX);
    let cases: Vec<(&str, DynamicImage)> = vec![
        (
            "rgba16",
            DynamicImage::ImageRgba16(ImageBuffer::from_fn(w, h, |x, y| Rgba([0, 1, 2, 3].map(|c| n(x, y, c))))),
        ),
        ("rgb16", DynamicImage::ImageRgb16(ImageBuffer::from_fn(w, h, |x, y| Rgb([0, 1, 2].map(|c| n(x, y, c)))))),
        ("la16", DynamicImage::ImageLumaA16(ImageBuffer::from_fn(w, h, |x, y| LumaA([n(x, y, 0), n(x, y, 1)])))),
    ];
    for (format, img) in cases {
        let sub = d.join(format);
        std::fs::create_dir(&sub).unwrap();
        let input = sub.join("in.png");
        img.save(&input).unwrap();
        let (ct, _) = prep(&sub, &input, &["--tile", "32", "--clip", "64", "--format", format]);
        validates_as(&sub, &ct, format);
        let (got, report) = dump(&sub, &ct, 0);
        assert_eq!(report["colour"], format, "{report}");
        assert_eq!(got, img, "{format}: level 0 as dumped differs from the input");
        // `icache dump` of level 0's image cache alone gives the same picture.
        let ic = ct.parent().unwrap().join("L00.ic");
        let png = sub.join("ic.png");
        let report = ok(&sub, ICACHE, &["dump", ic.to_str().unwrap(), "--out", png.to_str().unwrap(), "--json"]);
        assert!(report.contains(&format!("\"colour\": \"{format}\"")), "{report}");
        assert_eq!(image::open(&png).unwrap(), img, "{format}: icache dump");
    }
}

#[test]
fn a_streamed_sixteen_bit_tiff_keeps_every_bit() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (w, h) = (256u32, 128u32);
    let rgb =
        DynamicImage::ImageRgb16(ImageBuffer::from_fn(w, h, |x, y| Rgb([0, 1, 2].map(|c| noise(x, y, c, 0, 65535)))));
    let input = d.join("in.tif");
    rgb.save(&input).unwrap();
    let (ct, _) = prep(d, &input, &["--tile", "32", "--clip", "64", "--format", "rgb16"]);
    validates_as(d, &ct, "rgb16");
    let (got, _) = dump(d, &ct, 0);
    assert_eq!(got, rgb, "the streamed TIFF's level 0 differs from the input");
    // Grey through the same path, as a height map.
    let grey = DynamicImage::ImageLuma16(height_map(w, h));
    let sub = d.join("grey");
    std::fs::create_dir(&sub).unwrap();
    let input = sub.join("in.tif");
    grey.save(&input).unwrap();
    let (ct, _) = prep(&sub, &input, &["--tile", "32", "--clip", "64", "--format", "l16"]);
    let (got, _) = dump(&sub, &ct, 0);
    assert_eq!(got, grey, "the streamed grey TIFF's level 0 differs from the input");
}

#[test]
fn an_input_deeper_than_its_format_is_refused_unless_the_reduction_is_asked_for() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (w, h) = (128u32, 128u32);
    let grey = ImageBuffer::<Luma<u16>, Vec<u16>>::from_fn(w, h, |x, y| Luma([noise(x, y, 0, 0, 65535)]));
    let png = d.join("grey16.png");
    grey.save(&png).unwrap();
    let rgb = ImageBuffer::<Rgb<u16>, Vec<u16>>::from_fn(w, h, |x, y| Rgb([0, 1, 2].map(|c| noise(x, y, c, 0, 65535))));
    let rgb_png = d.join("rgb16.png");
    rgb.save(&rgb_png).unwrap();
    let tif = d.join("grey16.tif");
    grey.save(&tif).unwrap();
    let out = d.join("out");
    for (input, format, layout, wider) in [
        (&png, "l8", "16-bit grey", "--format l16"),
        (&rgb_png, "rgb8", "16-bit RGB", "--format rgb16"),
        (&rgb_png, "rgba8", "16-bit RGB", "--format rgba16"),
        (&rgb_png, "rgb565", "16-bit RGB", "--format rgb16"),
        (&tif, "l8", "16-bit grey", "--format l16"),
    ] {
        let args = ["--input", input.to_str().unwrap(), "--tile", "32", "--clip", "64", "--format", format, "--out"];
        let mut args = args.to_vec();
        args.push(out.to_str().unwrap());
        let (o, desc) = exec(d, CLIPPREP, &args);
        assert_eq!(o.status.code(), Some(1), "bad input\n{desc}");
        let err = String::from_utf8_lossy(&o.stderr);
        for word in [layout, "deeper than the texel format", format, "at most 8 bits", wider, "--reduce-depth"] {
            assert!(err.contains(word), "`{word}` in the message\n{desc}");
        }
        assert!(!out.exists(), "nothing written\n{desc}");
    }
    // With --reduce-depth: rounded to nearest, v / 257 (never a tie).
    let (ct, _) = prep(d, &png, &["--tile", "32", "--clip", "64", "--format", "l8", "--reduce-depth"]);
    let (got, report) = dump(d, &ct, 0);
    assert_eq!(report["colour"], "rgb", "8-bit formats dump as before: {report}");
    let got = got.as_rgb8().expect("an 8-bit picture").clone();
    let mut rounded_up = 0;
    for (x, y, p) in got.enumerate_pixels() {
        let v = grey.get_pixel(x, y)[0] as u32;
        let want = ((v * 255 + 32767) / 65535) as u8;
        assert_eq!(p.0, [want; 3], "pixel ({x}, {y}) of {v}");
        rounded_up += usize::from(want as u32 * 257 > v);
    }
    assert!(rounded_up > 1000, "rounded, not truncated: {rounded_up} rounded up");
    let sub = d.join("rgb");
    std::fs::create_dir(&sub).unwrap();
    let (ct, _) = prep(&sub, &rgb_png, &["--tile", "32", "--clip", "64", "--format", "rgb8", "--reduce-depth"]);
    let (got, _) = dump(&sub, &ct, 0);
    let want = ImageBuffer::<Rgb<u8>, Vec<u8>>::from_fn(w, h, |x, y| {
        Rgb(rgb.get_pixel(x, y).0.map(|v| ((v as u32 * 255 + 32767) / 65535) as u8))
    });
    assert!(got.as_rgb8() == Some(&want), "16-bit RGB reduced to rgb8 with rounding");
}

#[test]
fn eight_bit_inputs_into_sixteen_bit_formats_are_scaled_by_257() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (w, h) = (64u32, 64u32);
    let grey = ImageBuffer::<Luma<u8>, Vec<u8>>::from_fn(w, h, |x, y| Luma([(noise(x, y, 0, 0, 255)) as u8]));
    let input = d.join("grey8.png");
    grey.save(&input).unwrap();
    let (ct, _) = prep(d, &input, &["--tile", "16", "--clip", "32", "--format", "l16"]);
    let (got, _) = dump(d, &ct, 0);
    let got = got.as_luma16().expect("16-bit").clone();
    for (x, y, p) in got.enumerate_pixels() {
        assert_eq!(p[0], grey.get_pixel(x, y)[0] as u16 * 257, "pixel ({x}, {y})");
    }
    let rgba = ImageBuffer::<Rgba<u8>, Vec<u8>>::from_fn(w, h, |x, y| {
        Rgba([0, 1, 2, 3].map(|c| noise(x, y, c, 0, 255) as u8))
    });
    let sub = d.join("rgba");
    std::fs::create_dir(&sub).unwrap();
    let input = sub.join("rgba8.png");
    rgba.save(&input).unwrap();
    let (ct, _) = prep(&sub, &input, &["--tile", "16", "--clip", "32", "--format", "rgba16"]);
    let (got, _) = dump(&sub, &ct, 0);
    let want =
        ImageBuffer::<Rgba<u16>, Vec<u16>>::from_fn(w, h, |x, y| Rgba(rgba.get_pixel(x, y).0.map(|v| v as u16 * 257)));
    assert!(got.as_rgba16() == Some(&want), "8-bit RGBA widened exactly");
}

#[test]
fn the_procedural_sources_write_every_sixteen_bit_format() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for source in ["hash", "terrain"] {
        for format in ["l16", "la16", "rgb16", "rgba16"] {
            let out = d.join(format!("{source}-{format}"));
            let args = ["--source", source, "--size", "256x128", "--tile", "32", "--clip", "64", "--format", format];
            let mut args = args.to_vec();
            args.extend_from_slice(&["--out", out.to_str().unwrap(), "--json"]);
            let summary: Value = serde_json::from_str(&ok(d, CLIPPREP, &args)).unwrap();
            let ct = d.join(summary["ct"].as_str().unwrap());
            validates_as(d, &ct, format);
            let (img, report) = dump(d, &ct, 0);
            assert_eq!(report["colour"], format, "{report}");
            assert_eq!((img.width(), img.height()), (256, 128));
            let px = img.to_rgba16();
            let distinct: std::collections::BTreeSet<[u16; 4]> = px.pixels().map(|p| p.0).collect();
            assert!(distinct.len() > 1000, "{source} {format}: {} distinct texels", distinct.len());
        }
    }
    // The terrain's 16-bit luminance is its height map: smooth, so neighbours differ little
    // compared to the full 16-bit range.
    let (img, _) = dump(d, &d.join("terrain-l16/terrain-l16.ct"), 0);
    let img = img.as_luma16().unwrap().clone();
    let steps: Vec<u32> = (1..256)
        .map(|x| (img.get_pixel(x, 64)[0] as i32 - img.get_pixel(x - 1, 64)[0] as i32).unsigned_abs())
        .collect();
    assert!(steps.iter().all(|&s| s < 8000), "{steps:?}");
}

#[test]
fn the_mapping_format_codes_are_mirrored_by_the_c_header_and_the_python_reader() {
    use clipmap::shm::layout::{format_code, format_from_code};
    use clipmap::texel::TexelFormat as F;
    let header = std::fs::read_to_string(Path::new(ROOT).join("include/clipmap_shm.h")).unwrap();
    let python = std::fs::read_to_string(Path::new(ROOT).join("clients/python/clipmap_shm.py")).unwrap();
    let docs = std::fs::read_to_string(Path::new(ROOT).join("docs/SHM.md")).unwrap();
    for f in [F::L8, F::RGB8, F::RGBA8, F::RGB565, F::RGBA5551, F::L16, F::LA16, F::RGB16, F::RGBA16, F::L32F, F::L16I]
    {
        let code = format_code(f);
        assert_ne!(code, 0, "{f} has a code");
        assert_eq!(format_from_code(code), Some(f));
        let name = f.short_name();
        let define = format!("#define CLIPMAP_FORMAT_{} {code}u", name.to_uppercase());
        assert!(header.lines().any(|l| l.trim() == define), "`{define}` in the C header");
        let entry = format!("{code}: (\"{name}\", {})", f.bytes_per_texel());
        assert!(python.contains(&entry), "`{entry}` in the Python reader");
        let row = format!("| {code} | {} | {} |", name.to_uppercase(), f.bytes_per_texel());
        assert!(docs.contains(&row), "`{row}` in docs/SHM.md");
    }
}

#[test]
fn a_sixteen_bit_image_counts_two_bytes_a_sample_against_the_memory_limit() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let input = d.join("big.png");
    ImageBuffer::<Luma<u16>, Vec<u16>>::from_fn(512, 512, |x, y| Luma([noise(x, y, 0, 0, 65535)]))
        .save(&input)
        .unwrap();
    let out = d.join("out");
    let args = ["--input", input.to_str().unwrap(), "--tile", "64", "--clip", "128", "--format", "l16"];
    let mut args = args.to_vec();
    args.extend_from_slice(&["--max-memory", "1", "--out", out.to_str().unwrap()]);
    let (o, desc) = exec(d, CLIPPREP, &args);
    assert_eq!(o.status.code(), Some(1), "{desc}");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("512x512 (2 MiB decoded), over the in-memory limit of 1 MiB"), "{desc}");
}
