//! Where a tile lives: file name, byte offset and length, and stream server
//! (docs/PERFORMER-REFERENCE.md §1.9, §1.11, §1.12).

use super::params::Param;
use super::printf::Arg;
use super::{ClipTexturePlan, ImageCachePlan, LevelKind};
use crate::place::{Place, RemoteName};
use serde::Serialize;

/// The place of one tile's texels.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct TileLocation {
    /// The file: a local path (absolute) or a remote location.
    pub path: Place,
    /// Byte offset of the tile's first texel in the file.
    pub offset: u64,
    /// Bytes of texels.
    pub length: u64,
    /// The stream server path prefix chosen for the tile (`""` without streams).
    pub stream: String,
    /// Index of the stream server's read queue: (axis, index) with axis 0, 1, 2 for S, T, R;
    /// `None` without streams.
    #[serde(skip)]
    pub queue: Option<(usize, usize)>,
}

/// A tile that cannot be located.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum TileError {
    /// The tile index is outside the cache.
    #[error("tile ({s}, {t}) is outside the cache, which has {count_s} x {count_t} tiles (valid: s 0..{count_s}, t 0..{count_t})")]
    OutOfRange {
        /// Requested S.
        s: u64,
        /// Requested T.
        t: u64,
        /// Tiles along S.
        count_s: u64,
        /// Tiles along T.
        count_t: u64,
    },
    /// The level does not exist.
    #[error("level {level} does not exist; the clip texture has levels 0..{count}")]
    NoLevel {
        /// Requested level.
        level: u32,
        /// Level count.
        count: u32,
    },
    /// The level's `.ic` was not opened (a `.ct`-only plan).
    #[error("level {level}'s image cache {} was not opened (.ct-only): its tiles are unknown", path.display())]
    NotOpened {
        /// The level.
        level: u32,
        /// The `.ic` named.
        path: std::path::PathBuf,
    },
    /// A pyramid level is one tile.
    #[error("level {level} is a pyramid level held in a single tile: use s 0 and t 0")]
    PyramidTile {
        /// The level.
        level: u32,
    },
    /// The configuration names no file for this pyramid level.
    #[error("level {level} has no file name in the configuration (no tile_files or tile_format)")]
    Unnamed {
        /// The level.
        level: u32,
    },
    /// The configuration names a COG (`#clipmap cog`, docs/COG.md): its tiles are the COG's,
    /// not tile files of the configuration.
    #[error("tile ({s}, {t}) is read from the COG {place} (the `#clipmap cog` line), not from a tile file of the configuration; `cliptex info {place}` shows its levels and TIFF tiles")]
    Cog {
        /// S.
        s: u64,
        /// T.
        t: u64,
        /// The COG.
        place: Place,
    },
    /// Arithmetic overflow in the byte offset.
    #[error("the byte offset of tile ({s}, {t}) overflows 64 bits")]
    Overflow {
        /// S.
        s: u64,
        /// T.
        t: u64,
    },
}

impl ImageCachePlan {
    /// Tiles along S, T, R.
    pub fn tile_count(&self) -> [u64; 3] {
        [0, 1, 2].map(|i| self.size[i].div_ceil(self.tile_size[i]))
    }

    /// Bytes of one tile.
    pub fn tile_bytes(&self) -> u64 {
        if self.texel.block().is_some() {
            // Block-compressed: whole 4 x 4 blocks of the tile (docs/CONFIG.md).
            let [w, h, d] = self.tile_size;
            return self.texel.bytes_for(w, h).unwrap_or(u64::MAX).saturating_mul(d);
        }
        self.tile_size.iter().product::<u64>() * self.bytes_per_texel as u64
    }

    /// Locates tile (s, t, r) with idle read queues (the S server wins when S has servers).
    pub fn locate(&self, s: u64, t: u64, r: u64) -> Result<TileLocation, TileError> {
        if let Some(cog) = &self.cog {
            return Err(TileError::Cog { s, t, place: cog.place.clone() });
        }
        self.locate_with(s, t, r, |_, _| 0)
    }

    /// Locates tile (s, t, r); `pending(axis, index)` gives the number of requests queued on a
    /// stream server, and among the servers the axes propose the least busy wins, ties going to
    /// S, then T, then R.
    pub fn locate_with(
        &self,
        s: u64,
        t: u64,
        r: u64,
        pending: impl Fn(usize, usize) -> usize,
    ) -> Result<TileLocation, TileError> {
        let count = self.tile_count();
        if s >= count[0] || t >= count[1] || r >= count[2] {
            return Err(TileError::OutOfRange { s, t, count_s: count[0], count_t: count[1] });
        }
        let idx = [s, t, r];
        let mut queue: Option<(usize, usize, usize)> = None;
        for (axis, (list, &at)) in self.streams.iter().zip(&idx).enumerate() {
            if list.is_empty() {
                continue;
            }
            let i = (at % list.len() as u64) as usize;
            let load = pending(axis, i);
            if queue.is_none_or(|(_, _, best)| load < best) {
                queue = Some((axis, i, load));
            }
        }
        let stream = queue.map(|(a, i, _)| self.streams[a][i].clone()).unwrap_or_default();
        let [w, h, d] = self.tile_size;
        let [ns, nt, nr] = self.tiles_in_file;
        let path = self.naming.render(|p| match p {
            Param::VsizeS => Arg::Int(self.size[0] as i64),
            Param::VsizeT => Arg::Int(self.size[1] as i64),
            Param::VsizeR => Arg::Int(self.size[2] as i64),
            Param::TilenumS => Arg::Int(s as i64),
            Param::TilenumT => Arg::Int(t as i64),
            Param::TilenumR => Arg::Int(r as i64),
            Param::TileorgS => Arg::Int((s * w) as i64),
            Param::TileorgT => Arg::Int((t * h) as i64),
            Param::TileorgR => Arg::Int((r * d) as i64),
            Param::FilenumS => Arg::Int((s / ns) as i64),
            Param::FilenumT => Arg::Int((t / nt) as i64),
            Param::FilenumR => Arg::Int((r / nr) as i64),
            Param::StreamServerName => Arg::Str(stream.clone()),
            Param::CacheName => Arg::Str(self.naming.cache_name.clone()),
            Param::Level | Param::ImageCacheBase => Arg::Int(0),
        });
        let (fs, ft, fr) = (s % ns, t % nt, r % nr);
        let length = self.tile_bytes();
        let offset = (|| {
            fs.checked_add(ns.checked_mul(ft.checked_add(nt.checked_mul(fr)?)?)?)?
                .checked_mul(length)?
                .checked_add(self.header_offset)
        })()
        .ok_or(TileError::Overflow { s, t })?;
        Ok(TileLocation { path, offset, length, stream, queue: queue.map(|(a, i, _)| (a, i)) })
    }
}

impl ClipTexturePlan {
    /// Locates tile (s, t) of a level (pyramid levels: s = t = 0).
    pub fn locate(&self, level: u32, s: u64, t: u64) -> Result<TileLocation, TileError> {
        if let Some(cog) = &self.cog {
            return Err(TileError::Cog { s, t, place: cog.place.clone() });
        }
        let l = self.level(level).ok_or(TileError::NoLevel { level, count: self.levels.len() as u32 })?;
        match &l.kind {
            LevelKind::Icache(ic) => ic.locate(s, t, 0),
            LevelKind::IcacheNotOpened { path } => Err(TileError::NotOpened { level, path: path.clone() }),
            LevelKind::Pyramid(p) => {
                if s != 0 || t != 0 {
                    return Err(TileError::PyramidTile { level });
                }
                let path = p.path.clone().ok_or(TileError::Unnamed { level })?;
                Ok(TileLocation { path, offset: p.header_offset, length: p.length, stream: String::new(), queue: None })
            }
        }
    }
}

impl ImageCachePlan {
    /// Whether the cache names a remote location: its default tile, a stream server (a prefix of
    /// tile names), or its tiles' names themselves (tile 0's stands for all: only a stream
    /// server's prefix can make names of one cache differ in kind).
    pub fn names_remote(&self) -> bool {
        self.default_tile.as_ref().is_some_and(|p| p.remote().is_some())
            || self.streams.iter().flatten().any(|s| RemoteName::parse(s).is_some())
            || self.locate(0, 0, 0).is_ok_and(|loc| loc.path.remote().is_some())
    }
}

impl ClipTexturePlan {
    /// Whether the plan names any remote location (a tile, a default tile, a stream server, a
    /// pyramid file): then it is served through the `remote` feature's source.
    pub fn names_remote(&self) -> bool {
        self.levels.iter().any(|l| match &l.kind {
            LevelKind::Icache(ic) => ic.names_remote(),
            LevelKind::Pyramid(p) => p.path.as_ref().is_some_and(|p| p.remote().is_some()),
            LevelKind::IcacheNotOpened { .. } => false,
        })
    }
}
