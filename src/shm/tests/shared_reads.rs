//! Tiles an own view takes from the service's mapping instead of its source.

use super::*;

/// A source that records what it is told and asked.
struct Told {
    inner: HashSource,
    announced: std::sync::Mutex<Vec<TileId>>,
    withdrawn: std::sync::Mutex<Vec<TileId>>,
    read: std::sync::Mutex<Vec<TileId>>,
}

impl TileSource for Told {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }
    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), crate::source::SourceError> {
        self.read.lock().unwrap().push(tile);
        self.inner.read_tile(tile, out)
    }
    fn will_read(&self, tiles: &[TileId]) {
        self.announced.lock().unwrap().extend_from_slice(tiles);
    }
    fn withdraw(&self, tile: TileId) {
        self.withdrawn.lock().unwrap().push(tile);
    }
}

#[test]
fn tiles_the_mapping_holds_are_not_announced_to_the_source_and_one_taken_from_it_is_withdrawn() {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, _w) = hash_service(dir.path(), "main", 1 << 12, 128, 32);
    let c = Client::attach(dir.path(), "main").unwrap();
    let (held, far) = (TileId::new(0, 62, 62), TileId::new(0, 0, 0));
    for _ in 0..100 {
        map.tick([2000, 2000], None);
        map.wait_for_reads();
        if c.holds_tile(0, [62, 62]) {
            break;
        }
    }
    assert!(c.holds_tile(0, [62, 62]), "the tile under the centre is held");
    assert!(!c.holds_tile(0, [0, 0]) && !c.holds_tile(0, [-1, 0]) && !c.holds_tile(99, [0, 0]));
    let told = Arc::new(Told {
        inner: HashSource::new(desc(1 << 12, 128, 32)),
        announced: Default::default(),
        withdrawn: Default::default(),
        read: Default::default(),
    });
    let from = FromMapping::new(told.clone(), Client::attach(dir.path(), "main").unwrap());
    from.will_read(&[held, far]);
    assert_eq!(*told.announced.lock().unwrap(), vec![far], "only the tile the mapping lacks is announced");
    let d = desc(1 << 12, 128, 32);
    let (mut got, mut want) = (vec![0u8; d.tile_bytes(0)], vec![0u8; d.tile_bytes(0)]);
    from.read_tile(held, &mut got).unwrap();
    told.inner.read_tile(held, &mut want).unwrap();
    assert!(got == want, "the held tile's texels");
    assert!(told.read.lock().unwrap().is_empty(), "taken from the mapping, not read");
    assert_eq!(*told.withdrawn.lock().unwrap(), vec![held], "and withdrawn from the source");
    from.read_tile(far, &mut got).unwrap();
    assert_eq!(*told.read.lock().unwrap(), vec![far]);
    assert_eq!(from.hits(), 1);
}

/// The hash texture, with tile (62, 62) of level 0 delivered as the configuration's default
/// tile (its texels the hash's all the same).
struct DefaultAt(HashSource);

impl TileSource for DefaultAt {
    fn desc(&self) -> &TextureDesc {
        self.0.desc()
    }
    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), crate::source::SourceError> {
        self.0.read_tile(tile, out)
    }
    fn read_into(&self, tile: TileId, out: &mut [u8]) -> Result<crate::source::Delivered, crate::source::SourceError> {
        self.0.read_tile(tile, out)?;
        Ok(if tile == TileId::new(0, 62, 62) {
            crate::source::Delivered::Default
        } else {
            crate::source::Delivered::Tile
        })
    }
}

#[test]
fn a_default_tile_taken_from_the_mapping_is_delivered_as_the_default_tile() {
    use crate::source::Delivered;
    let dir = tempfile::tempdir().unwrap();
    let (mut map, _w) = service(dir.path(), "main", Arc::new(DefaultAt(HashSource::new(desc(1 << 12, 128, 32)))));
    let c = Client::attach(dir.path(), "main").unwrap();
    for _ in 0..100 {
        map.tick([2000, 2000], None);
        map.wait_for_reads();
        if c.holds_tile(0, [62, 62]) && c.holds_tile(0, [63, 62]) {
            break;
        }
    }
    let from = FromMapping::new(Arc::new(HashSource::new(desc(1 << 12, 128, 32))), c);
    let mut buf = vec![0u8; desc(1 << 12, 128, 32).tile_bytes(0)];
    assert_eq!(from.read_into(TileId::new(0, 62, 62), &mut buf).unwrap(), Delivered::Default);
    assert_eq!(from.read_into(TileId::new(0, 63, 62), &mut buf).unwrap(), Delivered::Tile);
    assert_eq!(from.hits(), 2);
}
