//! The peers of `clipbench tiles` (`tiles.rs`): GDAL cutting the image into an XYZ tree
//! (`gdal2tiles.py`), the reference PMTiles writer, an MBTiles written from the same tiles, GDAL
//! reading the kinds it has drivers for, curl fetching what our passes fetched, and GDAL's decode of
//! the level-0 tiles that every read is checked against ([`Reference`], used by `tiles.rs` and
//! `tiles_flight.rs`).

use super::cog_shared::Spent;
use super::perf::MachineCpu;
use super::serve::AccessLog;
use clipmap::source::TileId;
use std::fmt::Write as _;
use std::path::Path;
use std::process::Command;
use std::time::Instant;

/// Loopback is not to go through a proxy the environment may name.
const NO_PROXY: [(&str, &str); 2] = [("NO_PROXY", "127.0.0.1,localhost"), ("no_proxy", "127.0.0.1,localhost")];

/// Run in the scratch directory with the finest zoom: georeferences `terrain.png` over the whole
/// Web Mercator square (`src.tif`), cuts it into `xyz/` with `gdal2tiles.py --xyz`, writes every
/// tile of the tree into `tiles.pmtiles` (the reference writer) and `tiles.mbtiles` (TMS rows,
/// the spec's tables and metadata), and GDAL's decode of every tile of the finest zoom into
/// `reference.raw` (XYZ order, RGBA rows from the north). Prints GDAL's version.
const MAKE: &str = r#"
import os, sqlite3, subprocess, sys
from osgeo import gdal
from pmtiles.tile import zxy_to_tileid, TileType, Compression
from pmtiles.writer import Writer
gdal.UseExceptions()
zmax = int(sys.argv[1])
h = 20037508.342789244
gdal.Translate("src.tif", "terrain.png", outputSRS="EPSG:3857", outputBounds=[-h, h, h, -h])
r = subprocess.run(["gdal2tiles.py", "--xyz", "-q", "-w", "none", "--processes=2", "-z", f"0-{zmax}", "src.tif", "xyz"],
                   capture_output=True, text=True)
if r.returncode != 0:
    sys.exit(f"gdal2tiles.py failed: {r.stderr}")
os.remove("src.tif")
tiles = sorted((zxy_to_tileid(z, x, y), z, x, y) for z in range(zmax + 1) for x in range(2 ** z) for y in range(2 ** z))
def data(z, x, y):
    with open(f"xyz/{z}/{x}/{y}.png", "rb") as f:
        return f.read()
with open("tiles.pmtiles", "wb") as f:
    w = Writer(f)
    for tid, z, x, y in tiles:
        w.write_tile(tid, data(z, x, y))
    w.finalize({"tile_type": TileType.PNG, "tile_compression": Compression.NONE, "min_zoom": 0, "max_zoom": zmax,
                "min_lon_e7": int(-180e7), "min_lat_e7": int(-85.0511287e7), "max_lon_e7": int(180e7),
                "max_lat_e7": int(85.0511287e7), "center_zoom": 0, "center_lon_e7": 0, "center_lat_e7": 0},
               {"name": "clipbench"})
db = sqlite3.connect("tiles.mbtiles")
db.execute("CREATE TABLE metadata (name text, value text)")
db.execute("CREATE TABLE tiles (zoom_level integer, tile_column integer, tile_row integer, tile_data blob)")
db.execute("CREATE UNIQUE INDEX tile_index ON tiles (zoom_level, tile_column, tile_row)")
for k, v in [("name", "clipbench"), ("type", "baselayer"), ("version", "1"), ("format", "png"),
             ("bounds", "-180,-85.0511287798066,180,85.0511287798066"), ("minzoom", "0"), ("maxzoom", str(zmax))]:
    db.execute("INSERT INTO metadata VALUES (?, ?)", (k, v))
db.executemany("INSERT INTO tiles VALUES (?, ?, ?, ?)",
               ((z, x, 2 ** z - 1 - y, data(z, x, y)) for _, z, x, y in tiles))
db.commit()
db.close()
n = 2 ** zmax
with open("reference.raw", "wb") as out:
    for y in range(n):
        for x in range(n):
            ds = gdal.Open(f"xyz/{zmax}/{x}/{y}.png")
            if ds.RasterCount != 4 or ds.RasterXSize != 256 or ds.RasterYSize != 256:
                sys.exit(f"xyz/{zmax}/{x}/{y}.png: {ds.RasterCount} bands of {ds.RasterXSize}x{ds.RasterYSize}, expected RGBA 256x256")
            out.write(ds.ReadRaster(buf_pixel_space=4, buf_line_space=4 * 256, buf_band_space=1))
print(gdal.__version__)
"#;

/// What [`make_pyramid`] made.
pub struct Made {
    pub version: String,
}

fn python_in(python: &Path, dir: &Path, script: &str, args: &[String], env: &[(&str, &str)]) -> anyhow::Result<String> {
    let file = dir.join("clipbench_tiles.py");
    std::fs::write(&file, script)?;
    let out = Command::new(python).arg(&file).args(args).envs(env.iter().copied()).current_dir(dir).output()?;
    anyhow::ensure!(
        out.status.success(),
        "{} failed: {}",
        args.first().map_or("python", |a| a.as_str()),
        String::from_utf8_lossy(&out.stderr).trim()
    );
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Makes the tree, the archives and the reference decode in `dir` ([`MAKE`]).
pub fn make_pyramid(python: &Path, dir: &Path, max_zoom: u8) -> anyhow::Result<Made> {
    let ok = Command::new(python).args(["-c", "import pmtiles.writer"]).output().is_ok_and(|o| o.status.success());
    anyhow::ensure!(ok, "the reference PMTiles writer is needed: pip install pmtiles");
    let out = python_in(python, dir, MAKE, &[max_zoom.to_string()], &[])
        .map_err(|e| anyhow::anyhow!("making the tile pyramid with gdal2tiles.py and the archives: {e}"))?;
    Ok(Made { version: out.trim().to_string() })
}

/// GDAL's WMS driver description of the XYZ tree: its TMS mini-driver, rows from the top,
/// `max_zoom` the finest level, 4 bands, no cache.
pub fn wms_xml(base: &str, max_zoom: u8, tile: u64) -> String {
    let h = 20037508.342789244f64;
    format!(
        "<GDAL_WMS><Service name=\"TMS\"><ServerUrl>{base}/xyz/${{z}}/${{x}}/${{y}}.png</ServerUrl></Service>\
         <DataWindow><UpperLeftX>{}</UpperLeftX><UpperLeftY>{h}</UpperLeftY><LowerRightX>{h}</LowerRightX>\
         <LowerRightY>{}</LowerRightY><TileLevel>{max_zoom}</TileLevel><TileCountX>1</TileCountX>\
         <TileCountY>1</TileCountY><YOrigin>top</YOrigin></DataWindow><Projection>EPSG:3857</Projection>\
         <BlockSizeX>{tile}</BlockSizeX><BlockSizeY>{tile}</BlockSizeY><BandsCount>4</BandsCount></GDAL_WMS>",
        -h, -h
    )
}

/// GDAL reading every tile of its dataset's full resolution: `dump` writes one untimed pass in
/// the reference's layout; `time` runs `passes` passes on DEPTH processes (each opens before the
/// clock starts; tiles dealt out in turn), then as many in one process.
const READS: &str = r#"
import json, sys, time, multiprocessing as mp
from osgeo import gdal
gdal.UseExceptions()
mode, name, tile, depth, passes, out = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]), sys.argv[6]
def read(ds, i, nx):
    by, bx = divmod(i, nx)
    b = ds.RasterCount
    buf = ds.ReadRaster(bx * tile, by * tile, tile, tile, buf_pixel_space=b, buf_line_space=b * tile, buf_band_space=1)
    if len(buf) != b * tile * tile:
        raise SystemExit(f"tile {i}: {len(buf)} bytes")
    return buf
if mode == "dump":
    ds = gdal.Open(name)
    nx, ny = ds.RasterXSize // tile, ds.RasterYSize // tile
    if ds.RasterCount != 4:
        sys.exit(f"{ds.RasterCount} bands, expected RGBA")
    with open(out, "wb") as f:
        for i in range(nx * ny):
            f.write(read(ds, i, nx))
    print(json.dumps({"version": gdal.__version__, "tiles": nx * ny}))
    sys.exit(0)
def run(depth):
    start, done = mp.Barrier(depth + 1), mp.Barrier(depth + 1)
    counts = mp.Array("q", depth)
    def worker(w):
        try:
            for _ in range(passes):
                ds = gdal.Open(name)
                nx, ny = ds.RasterXSize // tile, ds.RasterYSize // tile
                start.wait(300)
                n = 0
                for i in range(w, nx * ny, depth):
                    read(ds, i, nx)
                    n += 1
                ds = None
                counts[w] = n
                done.wait(300)
        except BaseException as e:
            start.abort(); done.abort()
            print(f"worker {w}: {e}", file=sys.stderr)
            sys.exit(1)
    procs = [mp.Process(target=worker, args=(w,)) for w in range(depth)]
    for p in procs:
        p.start()
    times, tiles = [], 0
    for _ in range(passes):
        start.wait(300)
        t0 = time.perf_counter()
        done.wait(300)
        times.append(time.perf_counter() - t0)
        tiles = sum(counts)
    for p in procs:
        p.join()
    return times, tiles
times, tiles = run(depth)
one, _ = run(1)
print(json.dumps({"version": gdal.__version__, "tiles": tiles, "seconds": times, "one_process_seconds": one}))
"#;

/// What GDAL measured on one kind.
pub struct Gdal {
    pub version: String,
    /// Tiles a pass.
    pub tiles: u64,
    /// Seconds a pass, `depth` processes.
    pub seconds: Vec<f64>,
    /// Seconds a pass, one process.
    pub one_process_seconds: Vec<f64>,
    /// Requests a pass of the `depth` processes, open included (nginx's log; HTTP kinds).
    pub requests: Option<u64>,
    /// The dump pass: every tile as GDAL read it, in the reference's layout.
    pub dump: Vec<u8>,
}

/// GDAL reading `name` (a path or a WMS description), first the dump pass, then the timed ones;
/// requests counted in `log` for an HTTP kind.
pub fn gdal_reads(
    python: &Path,
    dir: &Path,
    name: &str,
    tile: u64,
    depth: u64,
    passes: u64,
    log: Option<&AccessLog>,
) -> anyhow::Result<Gdal> {
    let dump = dir.join("gdal_dump.raw");
    let args = |mode: &str| -> Vec<String> {
        vec![
            mode.into(),
            name.into(),
            tile.to_string(),
            depth.to_string(),
            passes.to_string(),
            dump.to_string_lossy().into_owned(),
        ]
    };
    python_in(python, dir, READS, &args("dump"), &NO_PROXY).map_err(|e| anyhow::anyhow!("GDAL reading: {e}"))?;
    let bytes = std::fs::read(&dump)?;
    let _ = std::fs::remove_file(&dump);
    let before = log.map_or(Ok(0), |l| l.settled().map(|h| h.len()))?;
    let out =
        python_in(python, dir, READS, &args("time"), &NO_PROXY).map_err(|e| anyhow::anyhow!("GDAL reading: {e}"))?;
    // The timed run's requests: `passes` passes on `depth` processes, then as many on one; a
    // pass of the first is half of them (both read every tile).
    let requests = match log {
        Some(l) => Some(((l.settled()?.len() - before) as f64 / (2 * passes) as f64).round() as u64),
        None => None,
    };
    #[derive(serde::Deserialize)]
    struct Out {
        version: String,
        tiles: u64,
        seconds: Vec<f64>,
        one_process_seconds: Vec<f64>,
    }
    let o: Out = serde_json::from_str(out.trim())?;
    Ok(Gdal {
        version: o.version,
        tiles: o.tiles,
        seconds: o.seconds,
        one_process_seconds: o.one_process_seconds,
        requests,
        dump: bytes,
    })
}

/// One transfer curl makes: a URL, and a byte range of it (both ends included).
pub struct Transfer {
    pub url: String,
    pub range: Option<(u64, u64)>,
}

/// curl making `transfers`, `depth` at once over kept connections, once a pass; seconds a pass
/// and the machine's CPU over them. Checks every transfer's status (200, or 206 for a range).
pub fn curl_passes(
    curl: &Path,
    dir: &Path,
    transfers: &[Transfer],
    depth: u64,
    passes: u64,
    tiles: u64,
) -> anyhow::Result<(Vec<f64>, Spent)> {
    let mut config = String::new();
    for (i, t) in transfers.iter().enumerate() {
        // `next` between transfers (one after the last would be a transfer with no URL).
        if i > 0 {
            config.push_str("next\n");
        }
        let _ = writeln!(config, "url = \"{}\"", t.url);
        if let Some((a, b)) = t.range {
            let _ = writeln!(config, "range = \"{a}-{b}\"");
        }
        config.push_str("output = \"/dev/null\"\nfail\nwrite-out = \"%{http_code} %{size_download}\\n\"\n");
    }
    let file = dir.join("curl_transfers.txt");
    std::fs::write(&file, config)?;
    let mut times = Vec::new();
    let cpu = MachineCpu::now();
    for _ in 0..passes {
        let t = Instant::now();
        let out = Command::new(curl)
            .args(["--silent", "--show-error", "--noproxy", "*", "--parallel", "--parallel-immediate"])
            .arg("--parallel-max")
            .arg(depth.to_string())
            .arg("--config")
            .arg(&file)
            .output()?;
        times.push(t.elapsed().as_secs_f64());
        let text = String::from_utf8_lossy(&out.stdout);
        let mut n = 0;
        for line in text.lines() {
            let code = line.split(' ').next().unwrap_or("");
            anyhow::ensure!(code == "200" || code == "206", "curl: status {code} (`{line}`), expected 200 or 206");
            n += 1;
        }
        anyhow::ensure!(
            out.status.success() && n == transfers.len(),
            "curl made {n} of {} transfers, {}: {}",
            transfers.len(),
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    let spent = Spent::since(cpu, &times, tiles * passes);
    Ok((times, spent))
}

/// GDAL's decode of every level-0 tile file, what every tile read is checked against: tile by
/// tile in XYZ order (rows from the north, columns within), each tile's RGBA rows from the north.
pub struct Reference {
    pub gdal: Vec<u8>,
    /// Tiles a side of level 0.
    pub tiles: u64,
    /// Tile size, texels.
    pub tile: u64,
}

/// Bytes a texel: RGBA (PNG tiles).
pub const BPT: usize = 4;

impl Reference {
    pub fn tile_bytes(&self) -> usize {
        BPT * (self.tile * self.tile) as usize
    }

    /// GDAL's decode of level-0 texture tile `id`, rows from the north.
    fn of(&self, id: TileId) -> &[u8] {
        let y = self.tiles - 1 - id.t;
        &self.gdal[(y * self.tiles + id.s) as usize * self.tile_bytes()..][..self.tile_bytes()]
    }

    /// Texels of our level-0 tile `id` (rows from the south) that differ from GDAL's decode.
    pub fn wrong(&self, id: TileId, ours: &[u8]) -> u64 {
        let theirs = self.of(id);
        let (tile, row) = (self.tile as usize, BPT * self.tile as usize);
        let mut wrong = 0;
        for r in 0..tile {
            let a = &ours[r * row..(r + 1) * row];
            let b = &theirs[(tile - 1 - r) * row..][..row];
            if a != b {
                wrong += a.chunks(BPT).zip(b.chunks(BPT)).filter(|(x, y)| x != y).count() as u64;
            }
        }
        wrong
    }

    /// GDAL's texel at level-0 texel (s, t) (t from the south).
    pub fn texel(&self, s: u64, t: u64) -> &[u8] {
        let id = TileId { level: 0, s: s / self.tile, t: t / self.tile };
        let row = self.tile - 1 - t % self.tile;
        &self.of(id)[((row * self.tile + s % self.tile) as usize) * BPT..][..BPT]
    }

    /// Texels of a dump in the reference's own layout (GDAL reading a kind) that differ from it.
    pub fn wrong_dump(&self, dump: &[u8]) -> u64 {
        if dump.len() != self.gdal.len() {
            return (self.gdal.len() / BPT) as u64;
        }
        dump.chunks(BPT).zip(self.gdal.chunks(BPT)).filter(|(a, b)| a != b).count() as u64
    }
}
