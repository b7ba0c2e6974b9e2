//! Input images given to `clipprep`: cut short, or too large to decode in memory.

use super::service::{fails, CLIPPREP};
use std::path::Path;

fn image_rgb(w: u32, h: u32) -> image::RgbImage {
    image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 7) as u8, (y * 5) as u8, (x ^ y) as u8]))
}

fn prep_args<'a>(input: &'a str, out: &'a str) -> Vec<&'a str> {
    vec!["--input", input, "--tile", "32", "--clip", "32", "--format", "rgb8", "--out", out]
}

/// Writes `img` as `name` in `dir`, keeps only `keep` of its bytes (a fraction), returns the path.
fn cut(dir: &Path, name: &str, img: &image::RgbImage, keep: f64) -> std::path::PathBuf {
    let p = dir.join(name);
    img.save(&p).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..(bytes.len() as f64 * keep) as usize]).unwrap();
    p
}

#[test]
fn truncated_jpeg_png_and_tiff_are_refused_alike_and_leave_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let img = image_rgb(128, 96);
    for name in ["cut.jpg", "cut.png", "cut.tif"] {
        let p = cut(d, name, &img, 0.6);
        let out = d.join(format!("out-{name}"));
        let err = fails(d, CLIPPREP, &prep_args(p.to_str().unwrap(), out.to_str().unwrap()), 1, &[name]);
        assert!(
            err.contains("cannot decode the input image")
                && err.contains("truncated, corrupt or not a PNG, JPEG or TIFF"),
            "{name}: {err}"
        );
        assert!(!out.exists(), "{name}: no output");
    }
    let left: Vec<_> = std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 3, "only the inputs remain: {left:?}");
}

#[test]
fn a_jpeg_cut_just_before_its_end_marker_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let p = d.join("short.jpg");
    image_rgb(128, 96).save(&p).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() - 2]).unwrap();
    let out = d.join("out");
    fails(d, CLIPPREP, &prep_args(p.to_str().unwrap(), out.to_str().unwrap()), 1, &["ends early", "no EOI marker"]);
    assert!(!out.exists());
}

#[test]
fn the_out_of_memory_advice_names_something_that_works() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let p = d.join("big.png");
    image_rgb(1024, 1024).save(&p).unwrap();
    let out = d.join("out");
    let mut args = prep_args(p.to_str().unwrap(), out.to_str().unwrap());
    args.extend(["--max-memory", "1"]);
    let err = fails(d, CLIPPREP, &args, 1, &["over the in-memory limit of 1 MiB", "raise --max-memory to at least 4"]);
    // Following the advice works.
    let i = args.iter().position(|a| *a == "--max-memory").unwrap();
    args[i + 1] = "64";
    let (o, desc) = super::service::run(d, CLIPPREP, &args);
    assert_eq!(o.status.code(), Some(0), "advice `{err}` followed:\n{desc}");
}
