//! The georeferencing lines of the `#clipmap` extension (docs/GEOREF.md, "Prepared pyramids"): a
//! `.ct` that `clipprep` prepared from a georeferenced input records where the texture is on the
//! Earth, `#clipmap georef_epsg CODE` and `#clipmap georef_transform G0,G1,G2,G3,G4,G5` (level 0's
//! geotransform in GDAL's order, for the texture's own pixel / line: line 0 the top edge of its
//! top row, `virt_size`'s height from the bottom). Performer 3.0 reads the lines as comments, so
//! each file's first is a portability note (an error under `validate --strict`).

use super::fields::Reader;
use super::portability;
use crate::config::{Severity, Span};
use crate::georef::{Crs, GeoTransform, Georef};
use std::fmt::Write;

/// The settings a georeferencing line may give.
pub(crate) const SETTINGS: [&str; 2] = ["georef_epsg", "georef_transform"];

/// The `#clipmap georef_…` lines that record `g` (level 0's transform, for a texture of `g`'s
/// size); empty for a CRS without an EPSG code, which the lines cannot name.
pub fn lines(g: &Georef) -> String {
    let Some(code) = g.crs().epsg_code() else { return String::new() };
    let t = g.geotransform().0;
    let mut out = String::from(
        "# Where the texture is on the Earth (docs/GEOREF.md): its CRS, and level 0's geotransform in GDAL's order.\n",
    );
    let _ = writeln!(out, "#clipmap georef_epsg {code}");
    let _ = writeln!(out, "#clipmap georef_transform {},{},{},{},{},{}", t[0], t[1], t[2], t[3], t[4], t[5]);
    out
}

/// Reads the georeferencing lines of a `.ct` whose level 0 is `size` (`None` when it was
/// refused, reported already): `None` when there are none or one was refused.
pub(crate) fn read(r: &mut Reader<'_>, size: Option<[u64; 3]>) -> Option<Georef> {
    let settings = r.extension_settings(&SETTINGS);
    let mut epsg: Option<(u32, Span)> = None;
    let mut transform: Option<([f64; 6], Span)> = None;
    let mut failed = false;
    // Once a file, at its first line.
    if let Some((key, _)) = settings.first() {
        let d = r
            .diag(
                Severity::Warning,
                "georef-extension",
                Some(key.span),
                format!("`#clipmap {}` records where the texture is, which Performer 3.0 does not know", key.value),
            )
            .hint("Performer reads the `#clipmap` lines as comments; keep them for this engine (docs/GEOREF.md)");
        r.push(portability(d));
    }
    for (key, value) in &settings {
        let mut bad = |r: &mut Reader<'_>, expected: String| {
            r.bad_extension_value(key, value, expected);
            failed = true;
        };
        if key.value == "georef_epsg" {
            match value.value.parse::<u32>().ok().map(|c| (c, Crs::epsg(c))) {
                Some((c, Ok(_))) => epsg = Some((c, key.span)),
                Some((_, Err(e))) => bad(r, format!("an EPSG code this engine knows ({e})")),
                None => bad(r, "an EPSG code, a whole number (e.g. 32633)".into()),
            }
            continue;
        }
        let numbers: Vec<Option<f64>> =
            value.value.split(',').map(|n| n.trim().parse::<f64>().ok().filter(|v| v.is_finite())).collect();
        match numbers.iter().copied().collect::<Option<Vec<f64>>>() {
            Some(v) if v.len() == 6 && GeoTransform([v[0], v[1], v[2], v[3], v[4], v[5]]).check().is_ok() => {
                transform = Some(([v[0], v[1], v[2], v[3], v[4], v[5]], key.span));
            }
            _ => bad(
                r,
                "six finite numbers separated by commas, no spaces: level 0's geotransform in GDAL's order, invertible (e.g. 400000,10,0,4700000,0,-10)"
                    .into(),
            ),
        }
    }
    if failed {
        return None;
    }
    let (epsg, transform, size) = match (epsg, transform, size) {
        (Some((c, _)), Some((t, _)), Some(size)) => (c, t, size),
        (None, None, _) | (_, _, None) => return None,
        (Some((_, at)), None, _) | (None, Some((_, at)), _) => {
            let (has, lacks) =
                if epsg.is_some() { ("georef_epsg", "georef_transform") } else { ("georef_transform", "georef_epsg") };
            let d = r
                .diag(
                    Severity::Error,
                    "georef-incomplete",
                    Some(at),
                    format!("`#clipmap {has}` without `#clipmap {lacks}`"),
                )
                .expected("both `#clipmap georef_epsg CODE` and `#clipmap georef_transform G0,G1,G2,G3,G4,G5`")
                .hint(format!("add the `#clipmap {lacks}` line, or remove `#clipmap {has}`"));
            r.push(d);
            return None;
        }
    };
    let crs = Crs::epsg(epsg).ok()?;
    Georef::new(crs, GeoTransform(transform), [size[0], size[1]]).ok()
}

/// The transform of a texture whose level 0 holds an image `image` texels high at its bottom
/// (rows `0..image` from the south, as `clipprep` pads an image north and east to the layout's
/// size) and is `texture` texels high, given the image's own transform `gt`: the image's line
/// `l` is the texture's line `l + texture - image`, so the texture's origin lies that many lines
/// north of the image's.
pub fn padded_transform(gt: GeoTransform, image: u64, texture: u64) -> GeoTransform {
    let d = texture as f64 - image as f64;
    let g = gt.0;
    GeoTransform([g[0] - d * g[2], g[1], g[2], g[3] - d * g[5], g[4], g[5]])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_padded_texture_keeps_each_image_pixel_where_the_image_put_it() {
        let gt = GeoTransform([400000.5, 10.25, 1.5, 4700000.75, 0.5, -10.25]);
        let (image, texture) = (600u64, 1024u64);
        let padded = padded_transform(gt, image, texture);
        // Image pixel (p, l) is texel (s, t) = (p, image - l): the texture's line texture - t.
        for (p, l) in [(0.0, 0.0), (17.5, 3.25), (599.0, 600.0)] {
            let want = gt.apply([p, l]);
            let t = image as f64 - l;
            let got = padded.apply([p, texture as f64 - t]);
            assert!((got[0] - want[0]).abs() < 1e-6 && (got[1] - want[1]).abs() < 1e-6, "{got:?} {want:?}");
        }
        assert_eq!(padded_transform(gt, 512, 512), gt, "no padding: the image's transform");
    }

    #[test]
    fn the_lines_name_the_code_and_the_transform_and_a_crs_without_a_code_writes_none() {
        let g = Georef::new(
            Crs::epsg(32633).unwrap(),
            GeoTransform([400000.5, 10.25, 0.0, 4700000.75, 0.0, -10.25]),
            [1024, 1024],
        )
        .unwrap();
        let text = lines(&g);
        assert!(text.contains("#clipmap georef_epsg 32633\n"), "{text}");
        assert!(text.contains("#clipmap georef_transform 400000.5,10.25,0,4700000.75,0,-10.25\n"), "{text}");
        let custom = Georef::new(Crs::unknown(None, "custom"), g.geotransform(), [1024, 1024]).unwrap();
        assert_eq!(lines(&custom), "");
    }
}
