//! Putting a prepared pyramid where it is served: the configuration of a pyramid written by
//! [`crate::prep::run`] rewritten to read its tiles from a remote location
//! ([`point_config_at`]), and (with the `remote` feature) every file of the pyramid uploaded
//! there ([`upload`]).
//!
//! The rewrite keeps the `.ct` and `.ic` files local (configuration files are read from local
//! disk only) and names the tiles remotely: the `.ct` gets a `tile_base` for its pyramid files,
//! each `.ic` a `tile_format` (or stream servers) and `default_tile` under the base URL.

use std::path::{Path, PathBuf};

/// `text` (a `.ct` when `is_ct`, else an `.ic`, as [`crate::prep::run`] writes them) with
/// every tile named under `base` (a URL of the pyramid's directory, no trailing `/`); stream
/// server i is put under `stream_bases[i % len]` when that is not empty.
pub fn point_config_at(text: &str, is_ct: bool, base: &str, stream_bases: &[String]) -> String {
    let base = base.trim_end_matches('/');
    let has_streams = text.lines().any(|l| l.starts_with("s_stream"));
    let mut out = String::new();
    let mut based = false;
    for line in text.lines() {
        // In the manual's order: `tile_base` before the file lists.
        if is_ct && !based && (line == "icache_files" || line == "tile_files") {
            out.push_str(&format!("tile_base {base}/\n"));
            based = true;
        }
        if let Some(f) = line.strip_prefix("tile_format ").filter(|_| !is_ct && !has_streams) {
            out.push_str(&format!("tile_format {base}/{f}\n"));
        } else if let Some(list) = line.strip_prefix("s_stream ").filter(|_| !is_ct) {
            let names: Vec<String> = list
                .split_whitespace()
                .enumerate()
                .map(|(i, s)| {
                    let b = if stream_bases.is_empty() {
                        base
                    } else {
                        stream_bases[i % stream_bases.len()].trim_end_matches('/')
                    };
                    format!("{b}/{s}")
                })
                .collect();
            out.push_str(&format!("s_stream {}\n", names.join(" ")));
        } else if let Some(d) = line.strip_prefix("default_tile ").filter(|_| !is_ct) {
            out.push_str(&format!("default_tile {base}/{d}\n"));
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

/// Writes the configuration files of the pyramid in `root` into `dst`, pointed at `base`
/// ([`point_config_at`]); returns the `.ct` written.
pub fn write_pointed_config(root: &Path, dst: &Path, base: &str, stream_bases: &[String]) -> std::io::Result<PathBuf> {
    std::fs::create_dir_all(dst)?;
    let mut ct = None;
    let mut entries: Vec<PathBuf> = std::fs::read_dir(root)?.map(|e| e.map(|e| e.path())).collect::<Result<_, _>>()?;
    entries.sort();
    for p in entries {
        let is_ct = match p.extension().and_then(|x| x.to_str()) {
            Some("ct") => true,
            Some("ic") => false,
            _ => continue,
        };
        let text = std::fs::read_to_string(&p)?;
        let target = dst.join(p.file_name().unwrap_or_default());
        let pointed = point_config_at(&text, is_ct, base, stream_bases);
        crate::save::atomically(&target, |w| std::io::Write::write_all(w, pointed.as_bytes()))?;
        if is_ct {
            ct = Some(target);
        }
    }
    ct.ok_or_else(|| std::io::Error::new(std::io::ErrorKind::NotFound, format!("no .ct in {}", root.display())))
}

/// Every regular file under `root`, relative to it, sorted.
pub fn files_under(root: &Path) -> std::io::Result<Vec<PathBuf>> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) -> std::io::Result<()> {
        for e in std::fs::read_dir(dir)? {
            let e = e?;
            let t = e.file_type()?;
            if t.is_dir() {
                walk(root, &e.path(), out)?;
            } else if t.is_file() {
                out.push(e.path().strip_prefix(root).unwrap_or(&e.path()).to_path_buf());
            }
        }
        Ok(())
    }
    let mut out = Vec::new();
    walk(root, root, &mut out)?;
    out.sort();
    Ok(out)
}

/// Uploads every file under `root` to `base` + `/` + its relative path (S3 PutObject, or an
/// HTTP PUT), each with the retries of `remote`; returns the files and bytes uploaded.
#[cfg(feature = "remote")]
pub fn upload(
    root: &Path,
    base: &str,
    remote: &crate::source::remote::Remote,
    progress: &dyn Fn(u64),
) -> Result<(u64, u64), String> {
    let base = base.trim_end_matches('/');
    let files = files_under(root).map_err(|e| format!("{}: {e}", root.display()))?;
    let (mut n, mut bytes) = (0u64, 0u64);
    for rel in files {
        let data = std::fs::read(root.join(&rel)).map_err(|e| format!("{}: {e}", root.join(&rel).display()))?;
        let name = format!("{base}/{}", rel.to_string_lossy());
        bytes += data.len() as u64;
        remote.put(&name, bytes::Bytes::from(data)).map_err(|e| format!("uploading {}: {e}", rel.display()))?;
        n += 1;
        progress(1);
    }
    Ok((n, bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_move_under_the_base_and_configuration_names_stay() {
        let ic = "ic_version2.0\ntile_format L00/r%03d.c%03d.raw\ntile_params A B\ndefault_tile L00/default.raw\n";
        let p = point_config_at(ic, false, "s3://b/pyr/", &[]);
        assert!(p.contains("tile_format s3://b/pyr/L00/r%03d.c%03d.raw\n"), "{p}");
        assert!(p.contains("default_tile s3://b/pyr/L00/default.raw\n"), "{p}");
        let streams = "ic_version2.0\ntile_format %sL00/r%03d.c%03d.raw\ns_stream stream0/ stream1/\n";
        let p = point_config_at(streams, false, "http://h:1/pyr", &["http://a:1/pyr".into(), "http://b:2/pyr".into()]);
        assert!(p.contains("tile_format %sL00/r%03d.c%03d.raw\n"), "the stream prefix carries the base: {p}");
        assert!(p.contains("s_stream http://a:1/pyr/stream0/ http://b:2/pyr/stream1/\n"), "{p}");
        let ct = "ct_version2.0\nicache_files\n\tL00.ic\ntile_files\n\tpyramid/L05.raw\n";
        let p = point_config_at(ct, true, "http://h:1/pyr", &[]);
        assert!(p.contains("tile_base http://h:1/pyr/\nicache_files\n\tL00.ic\ntile_files\n"), "{p}");
    }
}
