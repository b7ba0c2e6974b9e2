//! A source said to cover the whole Earth: a procedural texture (the `hash` verification
//! texture) georeferenced as a global geographic raster, so that it wraps in longitude as a
//! global COG or a tile service does (docs/GEOREF.md, "The antimeridian").

use super::{Delivered, SourceError, TextureDesc, TileId, TileSource};
use crate::georef::{Crs, GeoTransform, Georef};
use std::sync::Arc;

/// `inner`'s texels, georeferenced in EPSG:4326 from longitude -180 to 180 and latitude -90 to
/// 90 (level 0's W x H texels: each 360 / W degrees wide, 180 / H high): it spans 360 degrees of
/// longitude ([`Georef::is_global_in_longitude`]).
pub struct GlobalSource {
    inner: Arc<dyn TileSource>,
    georef: Georef,
}

impl GlobalSource {
    /// `inner` placed on the whole Earth.
    pub fn new(inner: Arc<dyn TileSource>) -> Self {
        let [w, h] = inner.desc().size();
        let transform = GeoTransform([-180.0, 360.0 / w as f64, 0.0, 90.0, 0.0, -180.0 / h as f64]);
        let georef = Georef::new(Crs::wgs84(), transform, [w, h]).expect("a texture has at least one texel a side");
        GlobalSource { inner, georef }
    }
}

impl TileSource for GlobalSource {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.inner.read_tile(tile, out)
    }

    fn read_into(&self, tile: TileId, out: &mut [u8]) -> Result<Delivered, SourceError> {
        self.inner.read_into(tile, out)
    }

    fn wrapped(&self) -> Option<&dyn TileSource> {
        Some(self.inner.as_ref())
    }

    fn georef(&self) -> Option<Georef> {
        Some(self.georef.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::HashSource;
    use crate::texel::TexelFormat;

    #[test]
    fn a_global_source_spans_360_degrees_and_reads_its_inner_texels() {
        let desc = TextureDesc::new([4096, 2048], 256, TexelFormat::RGBA8, [64, 64]).unwrap();
        let inner: Arc<dyn TileSource> = Arc::new(HashSource::new(desc.clone()));
        let g = GlobalSource::new(Arc::clone(&inner));
        let geo = g.georef().unwrap();
        assert!(geo.is_global_in_longitude());
        assert_eq!(geo.texel_to_lonlat(0, [0.0, 0.0]).unwrap(), [-180.0, -90.0]);
        assert_eq!(geo.texel_to_lonlat(0, [4096.0, 2048.0]).unwrap(), [180.0, 90.0]);
        let (mut a, mut b) = (vec![0u8; desc.tile_bytes(0)], vec![0u8; desc.tile_bytes(0)]);
        g.read_tile(TileId::new(0, 63, 5), &mut a).unwrap();
        inner.read_tile(TileId::new(0, 63, 5), &mut b).unwrap();
        assert_eq!(a, b);
    }
}
