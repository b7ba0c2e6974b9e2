//! The views block of a mapping as a reader finds it at attach (docs/SHM.md, "Views"): where it
//! is, whether this reader knows its version, and the view a client is bound to. Below both the
//! client and its views code, so that neither needs the other to know the block.

use super::layout::{self, header, views as v};
use super::raw::Region;

/// What the header's views block offset leads to, checked at attach.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) enum ViewsBlock {
    /// No views block: only the primary view, `main`.
    Absent,
    /// A block this reader knows: its byte offset, record count and version (1 or 2: version 1
    /// has no record in state [`v::STATE_OWN`]).
    Known { at: usize, records: usize, version: u32 },
    /// A block of a magic or version this reader does not know: `main` is read, and binding to
    /// any other view is refused with this reason.
    Unknown(String),
}

/// The view a client reads in the mapping it attached to: its record, and the incarnation it had
/// when the client bound to it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct Binding {
    pub(super) name: String,
    pub(super) record: usize,
    pub(super) incarnation: u64,
}

/// Checks the views block the header names, if any, as the C and Python readers do: a block
/// placed outside the mapping, or one of a known version whose record count or size is wrong,
/// refuses the whole mapping (`Err` saying which field holds what and what was expected); a block
/// of a magic or version this reader does not know is kept as [`ViewsBlock::Unknown`], so `main`
/// stays readable and only binding to a view is refused. `slots_end` is the end of the last
/// level's slots, `total` the mapping's size.
pub(super) fn check(region: &Region, slots_end: u64, total: u64) -> Result<ViewsBlock, String> {
    let at = region.read_u64(header::VIEWS_OFFSET);
    if at == 0 {
        return Ok(ViewsBlock::Absent);
    }
    let field = |o: usize, name: &str| {
        format!(
            "views block (header byte {} says it is at {at}), byte {} ({name})",
            header::VIEWS_OFFSET,
            at + o as u64
        )
    };
    if !at.is_multiple_of(layout::PAGE) || at < slots_end || at.checked_add(v::FIRST as u64).is_none_or(|e| e > total) {
        return Err(format!(
            "header byte {} (views block offset): found {at}, expected 0 or a multiple of 4096 at or after the end of the last level's slots ({slots_end}) and inside the {total}-byte mapping",
            header::VIEWS_OFFSET
        ));
    }
    let b = at as usize;
    let magic = region.read_u64(b + v::MAGIC).to_le_bytes();
    if magic != v::MAGIC_BYTES {
        return Ok(ViewsBlock::Unknown(format!(
            "{}: found {magic:02x?}, expected \"CLIPVIEW\"",
            field(v::MAGIC, "magic")
        )));
    }
    let version = region.read_u32(b + v::VERSION);
    if !(1..=v::BLOCK_VERSION).contains(&version) {
        return Ok(ViewsBlock::Unknown(format!(
            "{}: found {version}, this reader knows versions 1 to {}: use a reader of the service's release",
            field(v::VERSION, "views block version"),
            v::BLOCK_VERSION
        )));
    }
    let records = region.read_u32(b + v::RECORDS) as usize;
    if records == 0 || records > v::MAX_RECORDS {
        return Err(format!("{}: found {records}, expected 1..={}", field(v::RECORDS, "view records"), v::MAX_RECORDS));
    }
    let bytes = region.read_u32(b + v::RECORD_BYTES_AT) as usize;
    if bytes != v::RECORD_BYTES {
        return Err(format!(
            "{}: found {bytes}, expected {}",
            field(v::RECORD_BYTES_AT, "record bytes"),
            v::RECORD_BYTES
        ));
    }
    if at.checked_add(v::block_bytes(records)).is_none_or(|e| e > total) {
        return Err(format!(
            "{}: {records} records of {bytes} bytes end past the {total}-byte mapping",
            field(v::RECORDS, "view records")
        ));
    }
    Ok(ViewsBlock::Known { at: b, records, version })
}
