//! What a COG is served as, for `cliptex info`: [`CogInfo`] (the texture, each level's
//! [`LevelOrigin`], an alpha or nodata rule) and its words ([`CogInfo::human`]).

use super::level::{IfdLevel, Level, LevelOrigin};
use super::CogSource;
use crate::texel::TexelFormat;
use serde::Serialize;
use std::path::PathBuf;

/// A COG's texture and the origin of each level ([`CogSource::info`]).
#[derive(Clone, Debug, Serialize)]
pub struct CogInfo {
    /// The file.
    pub path: PathBuf,
    /// Level-0 size in texels.
    pub size: [u64; 2],
    /// The clip size it is served with.
    pub clip_size: u64,
    /// The texel format (8-bit samples as stored).
    pub format: TexelFormat,
    /// Every level, finest first.
    pub levels: Vec<CogLevelInfo>,
    /// Why the overviews stop being used before the coarsest level, when levels are built.
    pub built_because: Option<String>,
    /// The levels past the overviews are built when one is first read (a remote object, whose
    /// open reads its structure only), not at open.
    pub built_on_first_read: bool,
    /// Where a colour image's alpha comes from, when it is served with one added (its mask, its
    /// GDAL_NODATA; docs/COG.md, "Masks and nodata"); `null` otherwise.
    pub alpha: Option<String>,
    /// A height image's nodata value and where its nodata texels come from (its GDAL_NODATA,
    /// its internal mask; docs/COG.md, "Masks and nodata"); `null` for colours and for heights
    /// without nodata.
    pub nodata: Option<String>,
}

/// One level of a [`CogInfo`].
#[derive(Clone, Debug, Serialize)]
pub struct CogLevelInfo {
    /// The level.
    pub level: u32,
    /// Its size in texels.
    pub size: [u64; 2],
    /// The tiles it is read in.
    pub tile: [u64; 2],
    /// Where its texels come from.
    pub origin: LevelOrigin,
}

impl CogInfo {
    /// The text `cliptex info` prints.
    pub fn human(&self) -> String {
        use std::fmt::Write;
        let mut out = format!(
            "{}: tiled TIFF served as it is: {} x {} texels, {}, clip size {}\n{:<6} {:<13} {:<13} from\n",
            self.path.display(),
            self.size[0],
            self.size[1],
            self.format,
            self.clip_size,
            "level",
            "size",
            "tile"
        );
        for l in &self.levels {
            let from = match l.origin {
                LevelOrigin::Ifd { ifd, tile, compression, predictor_tag, .. } => format!(
                    "IFD {ifd}, {} x {} tiles, {compression}{}",
                    tile[0],
                    tile[1],
                    match predictor_tag {
                        2 => ", predictor 2",
                        3 => ", predictor 3 (floating point)",
                        _ => "",
                    }
                ),
                LevelOrigin::Built { from } if self.built_on_first_read => {
                    format!("built when first read from level {from} (2 x 2 box)")
                }
                LevelOrigin::Built { from } => format!("built at open from level {from} (2 x 2 box)"),
            };
            let _ = writeln!(
                out,
                "{:<6} {:<13} {:<13} {from}",
                l.level,
                format!("{} x {}", l.size[0], l.size[1]),
                format!("{} x {}", l.tile[0], l.tile[1])
            );
        }
        if let Some(why) = &self.built_because {
            let _ = writeln!(out, "levels are built because {why}");
        }
        if let Some(alpha) = &self.alpha {
            let _ = writeln!(out, "alpha: {alpha}");
        }
        if let Some(nodata) = &self.nodata {
            let _ = writeln!(out, "nodata: {nodata}");
        }
        out
    }
}

impl CogSource {
    /// The texture served and where each level comes from, for `cliptex info`.
    pub fn info(&self) -> CogInfo {
        let levels = (0..self.desc.level_count())
            .map(|k| {
                let l = self.desc.level(k as u32);
                CogLevelInfo { level: k as u32, size: l.size, tile: l.tile, origin: self.origins[k] }
            })
            .collect();
        CogInfo {
            path: self.path.clone(),
            size: self.desc.size(),
            clip_size: self.desc.clip_size(),
            format: self.desc.format(),
            levels,
            built_because: self.built_because.clone(),
            built_on_first_read: self.bytes.is_remote(),
            alpha: self.alpha.map(|rule| {
                let mut zero = Vec::new();
                if let Some(Level::Ifd(IfdLevel { mask: Some(m), .. })) = self.levels.first() {
                    zero.push(format!("the internal mask is 0 (IFD {} for level 0)", m.lv.ifd));
                }
                if let Some(v) = rule.nodata {
                    zero.push(format!("every colour sample is GDAL_NODATA {v}"));
                }
                format!("0 where {}, else full; colour samples as stored", zero.join(" or "))
            }),
            nodata: self.height_nodata.clone(),
        }
    }
}
