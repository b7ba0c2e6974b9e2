//! The data `clipbench perf` measures on: a hash pyramid written with the preparation library
//! (Performer layout, one raw tile per file), and for GDAL a tiled GeoTIFF with overviews made
//! from the same level-0 image (`gdal_translate -co TILED=YES` + `gdaladdo`).

use super::Size;
use anyhow::Context;
use clipmap::prep::{self, Filter, Job, Layout, Spec};
use clipmap::source::procedural::hash_region;
use clipmap::texel::TexelFormat;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;

/// Where GDAL's tools are.
#[derive(Clone, Debug)]
pub struct Gdal {
    /// A Python with `osgeo.gdal`.
    pub python: PathBuf,
    pub translate: PathBuf,
    pub addo: PathBuf,
}

fn python_with_gdal() -> Option<PathBuf> {
    for p in ["/usr/bin/python3", "python3"] {
        let out = Command::new(p).args(["-c", "from osgeo import gdal; print(gdal.__version__)"]).output();
        if let Ok(out) = out {
            if out.status.success() {
                return Some(PathBuf::from(p));
            }
        }
    }
    None
}

fn tool(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path).chain([PathBuf::from("/usr/bin")]).map(|d| d.join(name)).find(|p| p.is_file())
}

fn lookup() -> Result<Gdal, String> {
    let translate = tool("gdal_translate").ok_or("gdal_translate not found")?;
    let addo = tool("gdaladdo").ok_or("gdaladdo not found")?;
    let python = python_with_gdal().ok_or("no python3 with osgeo.gdal")?;
    Ok(Gdal { python, translate, addo })
}

/// GDAL's tools, installed first with `apt-get` if `install` and missing (its output on standard
/// error); `Err` says why not.
pub fn find_gdal(install: bool) -> Result<Gdal, String> {
    match lookup() {
        Ok(g) => Ok(g),
        Err(why) if install => {
            // Its output goes to standard error, so that `--json` output stays parseable.
            super::install::run("apt-get".as_ref(), &["install", "-y", "gdal-bin", "python3-gdal"])
                .map_err(|e| format!("{why}; {e}"))?;
            lookup()
        }
        Err(why) => Err(format!("{why} (pass --install-peers)")),
    }
}

/// The prepared texture.
pub struct Prepared {
    pub root: PathBuf,
    pub ct: PathBuf,
    pub layout: Layout,
    pub size: u64,
    /// The GeoTIFF with overviews, when GDAL is there.
    pub tif: Option<PathBuf>,
}

/// Texture size, clip size and tile size per run size.
pub fn shape(size: Size) -> (u64, u64, u64) {
    match size {
        Size::Full => (8192, 1024, 256),
        Size::Quick => (4096, 512, 256),
        Size::Smoke => (512, 128, 64),
    }
}

/// Writes the pyramid (and the GeoTIFF) under `dir`.
pub fn prepare(dir: &Path, size: Size, gdal: Option<&Gdal>) -> anyhow::Result<Prepared> {
    let (n, clip, tile) = shape(size);
    let layout = Layout::new(Spec {
        width: n,
        height: n,
        clip,
        tile,
        format: TexelFormat::RGBA8,
        tiles_in_file: (1, 1),
        header_bytes: 0,
        streams: None,
        inset: None,
        compression: None,
    })?;
    let root = dir.join("pyramid");
    let job = Job {
        layout: layout.clone(),
        source: prep::Source::Hash,
        filter: Filter::Box,
        linear_light: false,
        name: "hash".into(),
        description: vec!["clipbench perf".into()],
        limits: prep::Limits::default(),
    };
    let summary = prep::run(job, &root, &AtomicBool::new(false), dir, &|_| {}).context("preparing the pyramid")?;
    let ct = root.join(&summary.ct);
    let tif = match gdal {
        Some(g) => Some(geotiff(dir, g, n, tile)?),
        None => None,
    };
    Ok(Prepared { root, ct, layout, size: n, tif })
}

/// Reads every regular file at or below `path` once, so that what a timed run reads next is in
/// the page cache: some virtual machines page out file pages untouched for a few seconds (DAMON
/// proactive reclaim), which turned a part of the "warm" flight's reads into disk reads.
pub fn warm(path: &Path) -> anyhow::Result<()> {
    let what = || format!("warming {}", path.display());
    let files = if path.is_dir() {
        prep::publish::files_under(path).with_context(what)?.into_iter().map(|f| path.join(f)).collect()
    } else {
        vec![path.to_path_buf()]
    };
    for f in files {
        std::io::copy(&mut std::fs::File::open(&f).with_context(what)?, &mut std::io::sink()).with_context(what)?;
    }
    Ok(())
}

fn run(cmd: &mut Command) -> anyhow::Result<()> {
    let out = cmd.output().with_context(|| format!("running {cmd:?}"))?;
    anyhow::ensure!(out.status.success(), "{cmd:?} failed ({}): {}", out.status, String::from_utf8_lossy(&out.stderr));
    Ok(())
}

/// Level 0 of the hash texture as a raw RGBA8 image, then a tiled GeoTIFF with overviews down
/// to 1x1 in tiles of the pyramid's size.
fn geotiff(dir: &Path, gdal: &Gdal, n: u64, tile: u64) -> anyhow::Result<PathBuf> {
    let raw = dir.join("level0.raw");
    {
        let mut f = std::io::BufWriter::new(std::fs::File::create(&raw)?);
        let rows = 64usize.min(n as usize);
        let mut band = vec![0u8; n as usize * rows * 4];
        for t0 in (0..n).step_by(rows) {
            hash_region(0, 0, t0, n as usize, rows, 4, &mut band);
            f.write_all(&band)?;
        }
        f.flush()?;
    }
    let mut vrt = format!("<VRTDataset rasterXSize=\"{n}\" rasterYSize=\"{n}\">\n");
    for b in 0..4 {
        vrt.push_str(&format!(
            "  <VRTRasterBand dataType=\"Byte\" band=\"{}\" subClass=\"VRTRawRasterBand\">\n    \
             <SourceFilename relativetoVRT=\"1\">level0.raw</SourceFilename>\n    \
             <ImageOffset>{b}</ImageOffset><PixelOffset>4</PixelOffset><LineOffset>{}</LineOffset>\n  \
             </VRTRasterBand>\n",
            b + 1,
            n * 4
        ));
    }
    vrt.push_str("</VRTDataset>\n");
    let vrt_path = dir.join("level0.vrt");
    std::fs::write(&vrt_path, vrt)?;
    let tif = dir.join("hash.tif");
    let block = tile.to_string();
    run(Command::new(&gdal.translate)
        .args(["-q", "-of", "GTiff", "-co", "TILED=YES", "-co", "INTERLEAVE=PIXEL"])
        .args(["-co", &format!("BLOCKXSIZE={block}"), "-co", &format!("BLOCKYSIZE={block}")])
        .arg(&vrt_path)
        .arg(&tif))?;
    let factors: Vec<String> = (1..=n.trailing_zeros()).map(|k| (1u64 << k).to_string()).collect();
    run(Command::new(&gdal.addo)
        .args(["-q", "-r", "nearest", "--config", "GDAL_TIFF_OVR_BLOCKSIZE", &block])
        .arg(&tif)
        .args(&factors))?;
    std::fs::remove_file(&raw)?;
    Ok(tif)
}
