//! Attaching to a mapping: the file opened without blocking and checked before it is mapped,
//! its header and every level's description checked, the request mapping beside it.

use super::*;

impl Client {
    /// Attaches to the mapping `name` in `dir` (and its request mapping, when it may be written).
    pub fn attach(dir: &Path, name: &str) -> Result<Client, ShmError> {
        check_name(name)?;
        let path = map_path(dir, name);
        if !path.exists() {
            return Err(ShmError::NotFound { name: name.to_string(), dir: dir.to_path_buf() });
        }
        let mut client = Self::attach_path(&path)?;
        client.open_requests(&request_path(dir, name), None);
        Ok(client)
    }

    /// Attaches to a texel mapping file, read-only; requests then go nowhere unless the request
    /// mapping beside it (`.req` for `.map`) can be opened for writing.
    ///
    /// The file is opened without blocking and its type checked on the open descriptor before
    /// anything is mapped, so a FIFO or device planted at the name is refused at once.
    pub fn attach_path(path: &Path) -> Result<Client, ShmError> {
        Self::attach_path_owned(path, None)
    }

    /// [`attach_path`](Self::attach_path); with `owner`, the name is not followed when it is a
    /// symbolic link and the file must be owned by that user (see [`open_regular`]).
    pub(crate) fn attach_path_owned(path: &Path, owner: Option<u32>) -> Result<Client, ShmError> {
        let file = open_regular(path, false, owner)?;
        let meta = file.metadata().map_err(super::super::io(path))?;
        if meta.len() < layout::header::END as u64 {
            return Err(invalid(
                path,
                format!("truncated: {} bytes, a mapping has at least {}", meta.len(), layout::header::END),
            ));
        }
        let region = Region::map_read_only(&file).map_err(super::super::io(path))?;
        // The writer stores the magic last with a release store: acquire it, then the header.
        let magic = region.load(header::MAGIC, Ordering::Acquire).to_le_bytes();
        if magic == *b"CLIPMAP1" {
            return Err(invalid(
                path,
                "layout version 1 (a texel-window mapping of an older clipmapd); this client reads layout 2 only: run the service of this release",
            ));
        }
        if magic != layout::MAGIC {
            return Err(invalid(
                path,
                format!("wrong magic {magic:02x?}: not a clipmap mapping (expected \"CLIPMAP2\")"),
            ));
        }
        let version = region.read_u32(header::VERSION);
        if version != layout::VERSION {
            return Err(invalid(
                path,
                format!("layout version {version}; this client reads version {}", layout::VERSION),
            ));
        }
        let total = region.read_u64(header::TOTAL_BYTES);
        if total != meta.len() {
            return Err(invalid(path, format!("the header says {total} bytes but the file has {}", meta.len())));
        }
        let bpt = region.read_u32(header::BYTES_PER_TEXEL) as u64;
        let clip = region.read_u32(header::CLIP_SIZE) as u64;
        let count = region.read_u32(header::LEVEL_COUNT) as usize;
        if bpt == 0 || bpt > 64 || clip == 0 || count == 0 || count > layout::MAX_LEVELS {
            return Err(invalid(path, format!("implausible header: {bpt} bytes per texel, clip {clip}, {count} levels (expected 1..=64, > 0, 1..=32)")));
        }
        let format_code = region.read_u32(header::TEXEL_FORMAT);
        if let Some(f) = layout::format_from_code(format_code) {
            if u64::from(f.bytes_per_texel()) != bpt {
                return Err(invalid(
                    path,
                    format!(
                        "texel format {format_code} ({}) has {} bytes per texel, the header says {bpt}",
                        f.short_name(),
                        f.bytes_per_texel()
                    ),
                ));
            }
        }
        // Texels a side of a slot's unit of storage: 4 for a block-compressed format.
        let block: u64 = if layout::is_block_code(format_code) { 4 } else { 1 };
        let heights = {
            use layout::heights as ht;
            let b = header::HEIGHTS;
            let block = layout::HeightsBlock {
                is_heights: region.read_u32(b + ht::IS_HEIGHTS),
                rule: region.read_u32(b + ht::RULE),
                scale: region.read_u64(b + ht::SCALE),
                offset: region.read_u64(b + ht::OFFSET),
                nodata: region.read_u64(b + ht::NODATA),
            };
            layout::check_heights(format_code, &block).map_err(|why| invalid(path, why))?
        };
        let georef = {
            let block: Vec<u8> = (0..layout::GEOREF_BYTES / 4)
                .flat_map(|i| region.read_u32(header::GEOREF + 4 * i).to_le_bytes())
                .collect();
            let descs: Vec<[u64; 4]> = (0..count)
                .map(|k| {
                    let b = header::LEVEL_DESCS + k * layout::DESC_BYTES + desc::GEOREF;
                    [0, 1, 2, 3].map(|i| region.read_u64(b + 8 * i))
                })
                .collect();
            crate::GeorefBlock::read(&block, &descs).map_err(|why| invalid(path, why))?
        };
        let header_bytes = region.read_u32(header::HEADER_BYTES) as u64;
        if header_bytes < layout::header::END as u64 || !header_bytes.is_multiple_of(layout::PAGE) {
            return Err(invalid(
                path,
                format!("header bytes {header_bytes}: expected a multiple of 4096 of at least {}", layout::header::END),
            ));
        }
        let size0 = [region.read_u64(header::LEVEL0_S), region.read_u64(header::LEVEL0_T)];
        if size0.iter().any(|&e| e == 0 || e > clipmap_base::limits::MAX_TEXTURE_SIZE) {
            return Err(invalid(
                path,
                format!("level 0 is {size0:?} texels: expected 1..={} a side", clipmap_base::limits::MAX_TEXTURE_SIZE),
            ));
        }
        let mut levels: Vec<LevelDesc> = Vec::with_capacity(count);
        let mut end = header_bytes;
        for i in 0..count {
            let b = header::LEVEL_DESCS + i * layout::DESC_BYTES;
            let g = |o: usize| region.read_u64(b + o);
            let d = LevelDesc {
                size: [g(desc::SIZE_S), g(desc::SIZE_T)],
                tile: [g(desc::TILE_S), g(desc::TILE_T)],
                grid: [g(desc::GRID_S), g(desc::GRID_T)],
                slot_bytes: g(desc::SLOT_BYTES),
                tags: g(desc::TAGS_OFFSET),
                slots: g(desc::SLOTS_OFFSET),
                pyramid: g(desc::KIND) == 1,
                ranges: g(desc::RANGES_OFFSET),
            };
            let bad = |why: String| invalid(path, format!("level {i}'s description is inconsistent: {why} ({d:?})"));
            let want = clipmap_base::tile::level_size(size0, i as u32);
            if d.size != want {
                return Err(bad(format!("size {:?}, expected {want:?} (level 0 halved {i} times)", d.size)));
            }
            layout::check_level(&d.shape(), clip, bpt).map_err(bad)?;
            if block == 1 && d.slot_bytes != d.tile[0] * d.tile[1] * bpt {
                return Err(bad(format!("slot bytes {}, expected tile width x height x {bpt}", d.slot_bytes)));
            }
            if block > 1 && Some(d.slot_bytes) != layout::slot_bytes(d.tile, block, bpt) {
                return Err(bad(format!(
                    "slot bytes {}, expected ceil(tile width / 4) x ceil(tile height / 4) blocks x {bpt} bytes (block format {format_code})",
                    d.slot_bytes
                )));
            }
            if d.pyramid != (d.size[0] <= clip && d.size[1] <= clip) || g(desc::KIND) > 1 {
                return Err(bad(format!("kind {} does not match the level's size against clip {clip}", g(desc::KIND))));
            }
            let n = d.grid[0] * d.grid[1];
            let tags_end = n.checked_mul(layout::TAG_BYTES as u64).and_then(|x| x.checked_add(d.tags));
            let slots_end = n.checked_mul(d.slot_bytes).and_then(|x| x.checked_add(d.slots));
            let ok = d.tags >= end
                && d.tags.is_multiple_of(layout::PAGE)
                && d.slots.is_multiple_of(layout::PAGE)
                && tags_end.is_some_and(|e| e <= d.slots)
                && slots_end.is_some_and(|e| e <= total);
            if !ok {
                return Err(bad(format!(
                    "tags at {} and slots at {} do not lie in order inside the {total}-byte mapping after byte {end}",
                    d.tags, d.slots
                )));
            }
            if d.ranges != 0 {
                let at = b + desc::RANGES_OFFSET;
                let tags_end = tags_end.unwrap_or(u64::MAX);
                let ranges_end = n.checked_mul(layout::RANGE_BYTES as u64).and_then(|x| x.checked_add(d.ranges));
                if heights.is_none() {
                    return Err(invalid(
                        path,
                        format!("level {i} descriptor, byte {at} (tile ranges offset): found {}, expected 0: the texels are not heights (heights block all zero)", d.ranges),
                    ));
                }
                if !d.ranges.is_multiple_of(layout::PAGE)
                    || d.ranges < tags_end
                    || ranges_end.is_none_or(|e| e > d.slots)
                {
                    return Err(invalid(
                        path,
                        format!(
                            "level {i} descriptor, byte {at} (tile ranges offset): found {}, expected 0 or a multiple of 4096 at or after the tags' end ({tags_end}) whose {n} entries of {} bytes end at or before the slots ({})",
                            d.ranges,
                            layout::RANGE_BYTES,
                            d.slots
                        ),
                    ));
                }
            }
            end = slots_end.unwrap_or(total);
            levels.push(d);
        }
        let views = super::super::view_block::check(&region, end, total).map_err(|why| invalid(path, why))?;
        Ok(Client {
            views,
            view: None,
            own_view: None,
            inode: (meta.dev(), meta.ino()),
            uid: meta.uid(),
            generation: region.read_u64(header::GENERATION),
            format_code,
            tick_period: Duration::from_nanos(region.read_u64(header::TICK_PERIOD_NS)),
            heights,
            georef,
            region,
            request: None,
            path: path.to_path_buf(),
            bytes_per_texel: bpt as usize,
            block,
            clip_size: clip,
            levels,
        })
    }

    /// Opens the request mapping `path` for writing, if it is one of this mapping's (with
    /// `owner`: not through a symbolic link, and owned by that user; see [`open_regular`]).
    pub(crate) fn open_requests(&mut self, path: &Path, owner: Option<u32>) {
        let Ok(file) = open_regular(path, true, owner) else { return };
        if file.metadata().map(|m| m.len() != layout::REQUEST_BYTES).unwrap_or(true) {
            return;
        }
        let Ok(region) = Region::map(&file) else { return };
        let magic = region.load(request::MAGIC, Ordering::Acquire).to_le_bytes();
        if magic == layout::REQUEST_MAGIC && region.read_u64(request::GENERATION) == self.generation {
            self.request = Some(region);
        }
    }
}
