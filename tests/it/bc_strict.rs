//! Block-compressed pyramids are this crate's extension (docs/CONFIG.md §20): each `.ct` and `.ic`
//! whose `ext_format` names a `CLIPMAP_BC*` format is a portability finding, a warning that
//! `cliptex validate --strict` makes an error, as the other extensions are ("Performer would not
//! read it"); a plain pyramid of the same texels has none.

use crate::common::{expect, ic_ok, SMALL_IC};
use clipmap::config::Severity;
use std::process::Command;

/// `SMALL_IC` (an RGB8 cache) with BC1's format lines.
fn bc1_ic() -> String {
    SMALL_IC.replace("PFTEX_PACK_8", "CLIPMAP_BC1").replace("PFTEX_RGB_8", "GL_COMPRESSED_RGB_S3TC_DXT1_EXT")
}

#[test]
fn a_block_format_is_a_portability_finding_with_its_line() {
    let (plan, d) = ic_ok(&bc1_ic());
    assert_eq!(plan.texel.short_name(), "bc1");
    let x = expect(&d, "block-format-extension", Severity::Warning, Some((2, 1)), &["CLIPMAP_BC1", "BC1", "Performer"]);
    assert!(x.portability, "{x:?}");
    assert_eq!(d.items.iter().filter(|d| d.code == "block-format-extension").count(), 1);
    // The same cache in RGB8 has none.
    let (_, d) = ic_ok(SMALL_IC);
    assert!(d.items.iter().all(|d| d.code != "block-format-extension"));
}

/// `cliptex ARGS`: exit code, standard output and error.
fn cliptex(args: &[&str]) -> (i32, String) {
    let run = Command::new(env!("CARGO_BIN_EXE_cliptex")).args(args).output().unwrap();
    (
        run.status.code().unwrap(),
        format!("{}{}", String::from_utf8_lossy(&run.stdout), String::from_utf8_lossy(&run.stderr)),
    )
}

#[test]
fn validate_strict_refuses_a_prepared_bc_pyramid_and_plain_validate_accepts_it() {
    let dir = tempfile::tempdir().unwrap();
    for (format, extension) in [("bc1", Some("CLIPMAP_BC1")), ("bc7", Some("CLIPMAP_BC7")), ("rgb8", None)] {
        let out = dir.path().join(format);
        let run = Command::new(env!("CARGO_BIN_EXE_clipprep"))
            .args(["--source", "hash", "--size", "64", "--tile", "16", "--clip", "32", "--json", "-q"])
            .args(["--format", format])
            .args(if extension.is_some() { &["--bc-quality", "fast"][..] } else { &[][..] })
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(run.status.success(), "clipprep {format}: {}", String::from_utf8_lossy(&run.stderr));
        let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
        let ct = std::path::PathBuf::from(v["ct"].as_str().unwrap());
        let ct = if ct.is_absolute() { ct } else { out.join(ct) };
        let ct = ct.to_str().unwrap();
        let (code, text) = cliptex(&["validate", ct]);
        assert_eq!(code, 0, "{format}: {text}");
        let (code, text) = cliptex(&["validate", "--strict", ct]);
        match extension {
            Some(ext) => {
                assert_ne!(code, 0, "{format}: --strict accepted a block format: {text}");
                let finding = format!("`ext_format {ext}` names {} blocks", format.to_uppercase());
                assert!(
                    text.contains(&finding) && text.contains("Performer 3.0 would not read it"),
                    "{format}: {text}"
                );
            }
            None => {
                assert_eq!(code, 0, "{format}: {text}");
                assert!(!text.contains("would not read it"), "{format}: {text}");
            }
        }
    }
}
