//! `clipprep --config-only`: a configuration that serves a COG (local or remote) as it is.

use super::*;

/// `--config-only`: the `.ct` and `.ic` files that serve the COG --input as it is, written into
/// --out through the same temporary directory as a pyramid (nothing at --out on an error).
pub(crate) fn config_only(cli: &Cli) -> Result<(), PrepError> {
    if cli.input.as_deref().and_then(Path::to_str).is_some_and(clipmap::plan::source_line::names_pyramid) {
        return pyramid_config(cli);
    }
    use clipmap::place::Place;
    use clipmap::plan::cog::rounded_size;
    use clipmap::source::configured::level_tile;
    use clipmap::source::TileSource;
    let started = Instant::now();
    let input = cli.input.clone().expect("clap requires --input with --config-only");
    if let Some((flag, why)) = conversion_option(cli) {
        return Err(PrepError::Geometry(format!(
            "{flag} asks for a conversion, and --config-only writes only the configuration that serves {} as it is: {why}; drop {flag}, or drop --config-only to prepare a pyramid from the image",
            shown(&input)
        )));
    }
    if let Some(url) = Place::from_path(cli.out.clone()).remote() {
        return Err(PrepError::Geometry(format!(
            "--out {url} is a remote location, and --config-only writes the configuration into a local directory (configuration files are read from local disk only); give a local --out"
        )));
    }
    let place = Place::from_path(input.clone());
    if !clipmap::source::cog::is_tiff_place(&place) {
        let what = match &place {
            Place::Local(_) => "a local file that starts like a TIFF",
            Place::Remote(_) => "an http(s):// or s3:// name ending in .tif or .tiff",
        };
        return Err(PrepError::Geometry(format!(
            "--config-only serves a tiled GeoTIFF or COG as it is, and {} is not one: expected {what}; drop --config-only to prepare a pyramid from it",
            shown(&input)
        )));
    }
    check_pow2("the clip size".into(), cli.clip, "; pass --clip with a power of two")?;
    let src = clipmap::source::CogSource::open_place(&place, cli.clip)
        .map_err(|e| PrepError::Geometry(format!("--input {}: {e}", shown(&input))))?;
    let desc = src.desc();
    let format = desc.format();
    if let Some(f) = cli.format {
        if f.texel() != format {
            return Err(PrepError::Geometry(format!(
                "--format {}: {} is served as {format} texels, and --config-only serves it as it is; give --format {format}, or leave --format out",
                f.texel().short_name(),
                shown(&input),
            )));
        }
    }
    let tile = level_tile(&src, 0, [u64::MAX, u64::MAX]).unwrap_or([0, 0]);
    if tile[0] != tile[1] || !tile[0].is_power_of_two() {
        return Err(PrepError::Geometry(format!(
            "{} is tiled in {} x {} TIFF tiles, and a Performer configuration needs square tiles of a power of two; write it again in such tiles (gdal_translate -of COG -co BLOCKSIZE=256), or prepare a pyramid from it without --config-only",
            shown(&input),
            tile[0],
            tile[1]
        )));
    }
    if let Some(t) = cli.tile {
        if t != tile[0] {
            return Err(PrepError::Geometry(format!(
                "--tile {t}: {} is tiled in {} x {} TIFF tiles, which --config-only serves as they are; give --tile {}, or leave --tile out",
                shown(&input),
                tile[0],
                tile[1],
                tile[0]
            )));
        }
    }
    let size = desc.size();
    let virt = rounded_size(size);
    let mut layout = Layout::new(Spec {
        width: virt[0],
        height: virt[1],
        clip: cli.clip,
        tile: tile[0],
        format,
        tiles_in_file: (1, 1),
        header_bytes: 0,
        streams: None,
        inset: None,
        compression: None,
    })?;
    // Each image cache in its level's own TIFF tiles: overviews may be tiled unlike level 0
    // (`gdaladdo --config GDAL_TIFF_OVR_BLOCKSIZE 128`), and the `.ic` describes its level.
    for level in layout.levels.iter_mut().filter(|l| l.kind == clipmap::prep::layout::LevelKind::ImageCache) {
        let Some([w, h]) = level_tile(&src, level.index, [u64::MAX, u64::MAX]) else { continue };
        if w != h || !w.is_power_of_two() {
            return Err(PrepError::Geometry(format!(
                "{}: level {} is tiled in {w} x {h} TIFF tiles, and a Performer configuration needs square tiles of a power of two; write its overviews again in such tiles (gdaladdo --config GDAL_TIFF_OVR_BLOCKSIZE 256), or prepare a pyramid from it without --config-only",
                input.display(),
                level.index
            )));
        }
        (level.tile_w, level.tile_h) = (w.min(level.width), h.min(level.height));
    }
    // The name the configuration reads: a URL as given, a local file by its absolute path (the
    // configuration's directory is not where the COG lies).
    let name_of_cog = match &place {
        Place::Remote(r) => r.as_str().to_string(),
        Place::Local(p) => clipmap::plan::absolute(p).to_string_lossy().into_owned(),
    };
    let file = input.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let mut description = vec![format!(
        "Prepared by clipprep {} from the COG {file} ({} x {} texels, {format}) with --config-only: the texture is the COG served as it is.",
        env!("CARGO_PKG_VERSION"),
        size[0],
        size[1]
    )];
    if virt != size {
        description.push(format!(
            "virt_size is its size rounded up to powers of two, as Performer needs; the texture is served at {} x {}.",
            size[0], size[1]
        ));
    }
    let name = cli.name.clone().unwrap_or_else(|| default_name(&cli.out));
    let staging = Staging::begin(&cli.out, cli.force)?;
    let heights = src.heights();
    let written =
        clipmap::prep::cog_config::write(&layout, staging.path(), &name, &description, heights.as_ref(), &name_of_cog)?;
    // What was written must load and serve the COG, before it is put in place.
    let staged = staging.path().join(&written.ct);
    let loaded = clipmap::source::configured::load_clip_texture(&staged, &Default::default())
        .map_err(|e| PrepError::Geometry(format!("reading back the configuration written: {e}")))?;
    if loaded.plan.is_none() {
        return Err(PrepError::Geometry(format!(
            "the configuration written for {} does not load (nothing was written at {}):\n{}",
            shown(&input),
            cli.out.display(),
            loaded.render_from(clipmap::config::Severity::Error)
        )));
    }
    staging.commit()?;
    let ct = cli.out.join(&written.ct);
    let (ics, pyramid) = (layout.image_cache_levels().count(), layout.pyramid_levels().count());
    if cli.json {
        let v = serde_json::json!({
            "ct": ct,
            "cog": clipmap::place::redacted(&name_of_cog),
            "config_only": true,
            "levels": layout.levels.len(),
            "image_cache_levels": ics,
            "pyramid_levels": pyramid,
            "files": written.files,
            "bytes": written.bytes,
            "seconds": started.elapsed().as_secs_f64(),
            "size": size,
            "virt_size": virt,
            "clip": cli.clip,
            "tile": tile[0],
            "format": format.short_name(),
        });
        println!("{v}");
    } else if !cli.quiet {
        println!(
            "wrote {}: the configuration ({} files: {} levels, {ics} image cache, {pyramid} pyramid) that serves {} as it is ({} x {} texels, {format}, virt_size {} x {}); no tile written",
            ct.display(),
            written.files,
            layout.levels.len(),
            clipmap::place::redacted(&name_of_cog),
            size[0],
            size[1],
            virt[0],
            virt[1]
        );
    }
    Ok(())
}

/// The arguments with `--config-only` added when `--input` names a tile pyramid (`xyz:...`,
/// a `.pmtiles` or `.mbtiles`), which is always served as it is.
pub(crate) fn pyramid_means_config_only(mut args: Vec<std::ffi::OsString>) -> Vec<std::ffi::OsString> {
    let input = args.iter().enumerate().find_map(|(i, a)| {
        let a = a.to_str()?;
        match a.strip_prefix("--input=") {
            Some(v) => Some(v.to_string()),
            None if a == "--input" => args.get(i + 1)?.to_str().map(str::to_string),
            None => None,
        }
    });
    if input.as_deref().is_some_and(clipmap::plan::source_line::names_pyramid)
        && !args.iter().any(|a| a == "--config-only")
    {
        args.push("--config-only".into());
    }
    args
}

/// `--input` of a tile pyramid: the `.ct` (naming it with a `#clipmap source` line) and `.ic`
/// files that serve it as it is, its texture's size, texel format and tile size; nothing of the
/// pyramid is copied.
fn pyramid_config(cli: &Cli) -> Result<(), PrepError> {
    use clipmap::place::Place;
    use clipmap::source::tiles::{self, OpenOptions, PyramidOptions};
    use clipmap::source::TileSource;
    let started = Instant::now();
    let input = cli.input.clone().expect("a pyramid --input");
    let text = input.to_string_lossy().into_owned();
    if let Some((flag, why)) = conversion_option(cli) {
        return Err(PrepError::Geometry(format!(
            "{flag} asks for a conversion, and a tile source is served as it is (only its configuration is written): {why}; drop {flag}"
        )));
    }
    if let Some(url) = Place::from_path(cli.out.clone()).remote() {
        return Err(PrepError::Geometry(format!(
            "--out {url} is a remote location, and the configuration of a tile source is written into a local directory (configuration files are read from local disk only); give a local --out"
        )));
    }
    check_pow2("the clip size".into(), cli.clip, "; pass --clip with a power of two")?;
    // The name the configuration reads: a URL as given, a local path made absolute (the
    // configuration's directory is not where the pyramid lies).
    let (prefix, rest) = match text.strip_prefix("xyz:") {
        Some(t) => ("xyz:", t),
        None => ("", text.as_str()),
    };
    let name_of_source = match Place::parse(rest) {
        Place::Remote(_) => text.clone(),
        Place::Local(p) => format!("{prefix}{}", clipmap::plan::absolute(&p).display()),
    };
    let opts = OpenOptions {
        pyramid: PyramidOptions { clip_size: Some(cli.clip), ..Default::default() },
        ..Default::default()
    };
    let src = tiles::open(&name_of_source, &opts)
        .expect("a pyramid's name")
        .map_err(|e| PrepError::Geometry(format!("--input {}: {e}", shown(&input))))?;
    let desc = src.desc().clone();
    let format = desc.format();
    let size = desc.size();
    let tile = desc.level(0).tile[0];
    if let Some(f) = cli.format {
        if f.texel() != format {
            return Err(PrepError::Geometry(format!(
                "--format {}: {} is served as {format} texels, and a tile source is served as it is; give --format {format}, or leave --format out",
                f.texel().short_name(),
                shown(&input),
            )));
        }
    }
    if let Some(t) = cli.tile {
        if t != tile {
            return Err(PrepError::Geometry(format!(
                "--tile {t}: {} has tiles of {tile} texels, which are served as they are; give --tile {tile}, or leave --tile out",
                shown(&input)
            )));
        }
    }
    let layout = Layout::new(Spec {
        width: size[0],
        height: size[1],
        clip: cli.clip.min(size[0]),
        tile,
        format,
        tiles_in_file: (1, 1),
        header_bytes: 0,
        streams: None,
        inset: None,
        compression: None,
    })?;
    let info = src.info();
    let description = vec![format!(
        "Prepared by clipprep {} from the tile source {} (zooms {}..{}, {tile}-texel {} tiles): the texture is the pyramid served as it is, {} x {} texels, {format}.",
        env!("CARGO_PKG_VERSION"),
        clipmap::place::redacted(&name_of_source),
        info.min_zoom,
        info.max_zoom,
        info.encoding.map_or("PNG, JPEG or WebP", |e| e.name()),
        size[0],
        size[1]
    )];
    let name = cli.name.clone().unwrap_or_else(|| default_name(&cli.out));
    let staging = Staging::begin(&cli.out, cli.force)?;
    let written =
        clipmap::prep::cog_config::write_source(&layout, staging.path(), &name, &description, &name_of_source)?;
    // What was written must load, naming the pyramid, before it is put in place.
    let staged = staging.path().join(&written.ct);
    let loaded = clipmap::source::configured::load_clip_texture(&staged, &Default::default())
        .map_err(|e| PrepError::Geometry(format!("reading back the configuration written: {e}")))?;
    if loaded.plan.as_ref().is_none_or(|p| p.source.as_ref().is_none_or(|s| s.name != name_of_source)) {
        return Err(PrepError::Geometry(format!(
            "the configuration written for {} does not load (nothing was written at {}):\n{}",
            shown(&input),
            cli.out.display(),
            loaded.render_from(clipmap::config::Severity::Error)
        )));
    }
    staging.commit()?;
    let ct = cli.out.join(&written.ct);
    let (ics, pyramid) = (layout.image_cache_levels().count(), layout.pyramid_levels().count());
    if cli.json {
        let v = serde_json::json!({
            "ct": ct,
            "source": clipmap::place::redacted(&name_of_source),
            "config_only": true,
            "levels": layout.levels.len(),
            "image_cache_levels": ics,
            "pyramid_levels": pyramid,
            "files": written.files,
            "bytes": written.bytes,
            "seconds": started.elapsed().as_secs_f64(),
            "size": size,
            "virt_size": size,
            "clip": cli.clip.min(size[0]),
            "tile": tile,
            "format": format.short_name(),
        });
        println!("{v}");
    } else if !cli.quiet {
        println!(
            "wrote {}: the configuration ({} files: {} levels, {ics} image cache, {pyramid} pyramid) that serves the tile source {} as it is ({} x {} texels, {format}); no tile copied",
            ct.display(),
            written.files,
            layout.levels.len(),
            clipmap::place::redacted(&name_of_source),
            size[0],
            size[1]
        );
    }
    Ok(())
}
