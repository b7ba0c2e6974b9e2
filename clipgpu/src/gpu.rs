//! The GPU side: a headless wgpu device (Vulkan), one texture array layer per clipmap level that
//! mirrors the level's image cache slot for slot, a storage buffer of the slots' tags as this
//! client holds them, and the ground-plane pipeline of `ground.wgsl` drawing into an offscreen
//! RGBA8 target that is read back, with two more targets saying where each pixel sampled (and, for
//! a height texture, a fourth with the sampled height).
//!
//! Every device operation runs inside error scopes ([`Gpu::checked`]) and an uncaptured-error
//! handler is installed, so a validation or out-of-memory error is an error with its context, not
//! wgpu's default panic.

use anyhow::{anyhow, Context, Result};
use clipmap::accuracy::render::Camera;
use clipmap::sample::Filter;
use clipmap::shm::{Client, Snapshot};
use clipmap::texel::Bc;
use std::sync::{Arc, Mutex};

/// At most this many levels (the mapping's bound, docs/SHM.md).
pub const MAX_LEVELS: usize = 32;
const LEVEL_BYTES: usize = 48;
const FRAME_HEAD_BYTES: usize = 112;

/// The adapter, device and queue.
pub struct Gpu {
    /// Adapter name, backend and driver, as the JSON reports it.
    pub adapter: String,
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    /// The adapter decodes BC1 to BC7 textures (`TEXTURE_COMPRESSION_BC`, asked for when the
    /// adapter has it): a block-compressed mapping's tiles go to the GPU as they are.
    pub bc: bool,
    /// Errors no scope caught (the handler wgpu calls instead of panicking).
    uncaptured: Arc<Mutex<Vec<String>>>,
}

/// A wgpu error as text: what it was and the driver's description.
fn describe(e: &wgpu::Error) -> String {
    match e {
        wgpu::Error::OutOfMemory { .. } => "the GPU is out of memory".to_string(),
        wgpu::Error::Validation { description, .. } => format!("validation error: {}", description.trim()),
        wgpu::Error::Internal { description, .. } => format!("internal error: {}", description.trim()),
    }
}

impl Gpu {
    /// The first Vulkan adapter (lavapipe on a machine without a GPU); an error that says how to
    /// get one when there is none.
    pub fn new() -> Result<Gpu> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::VULKAN,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|e| {
            anyhow!(
                "no Vulkan adapter found ({e}): clipgpu needs a Vulkan driver; on Debian or Ubuntu \
                 `apt-get install mesa-vulkan-drivers` installs lavapipe, a software one \
                 (expected a file /usr/share/vulkan/icd.d/lvp_icd*.json afterwards)"
            )
        })?;
        let info = adapter.get_info();
        let name = format!("{} ({:?}, {} {})", info.name, info.backend, info.driver, info.driver_info);
        let bc = adapter.features().contains(wgpu::Features::TEXTURE_COMPRESSION_BC);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("clipgpu"),
            required_features: if bc { wgpu::Features::TEXTURE_COMPRESSION_BC } else { wgpu::Features::empty() },
            required_limits: wgpu::Limits::downlevel_defaults().using_resolution(adapter.limits()),
            ..Default::default()
        }))
        .with_context(|| format!("the adapter {name} refused a device"))?;
        let uncaptured = Arc::new(Mutex::new(Vec::new()));
        let sink = uncaptured.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut v) = sink.lock() {
                v.push(describe(&e));
            }
        }));
        Ok(Gpu { adapter: name, device, queue, bc, uncaptured })
    }

    /// Runs `f` (device work: creating resources, writing, submitting) inside out-of-memory,
    /// validation and internal error scopes; an error any of them caught, or that reached the
    /// uncaptured-error handler meanwhile, is returned as `what` failed, with the driver's
    /// description and `hint` (how to avoid it).
    pub fn checked<T>(&self, what: &str, hint: &str, f: impl FnOnce() -> T) -> Result<T> {
        let internal = self.device.push_error_scope(wgpu::ErrorFilter::Internal);
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out = f();
        let errors = [validation.pop(), oom.pop(), internal.pop()].map(pollster::block_on);
        let mut found: Vec<String> = errors.iter().flatten().map(describe).collect();
        if let Ok(mut v) = self.uncaptured.lock() {
            found.append(&mut v);
        }
        if found.is_empty() {
            return Ok(out);
        }
        let hint = if hint.is_empty() { String::new() } else { format!("; {hint}") };
        Err(anyhow!("{what} failed on {}: {}{hint}", self.adapter, found.join("; ")))
    }

    /// The adapter's largest 2D texture side.
    pub fn max_texture_side(&self) -> u32 {
        self.device.limits().max_texture_dimension_2d
    }

    /// Waits for everything submitted so far.
    pub fn wait(&self) -> Result<()> {
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| anyhow!("waiting for the GPU: {e}"))?;
        Ok(())
    }
}

/// What the GPU holds per texel: the published components, 8 or 16 bits each, widened to four;
/// or heights in metres.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Texels {
    /// RGBA8 (`Rgba8Uint`), from L8, RGB8, RGBA8.
    Bits8,
    /// RGBA16 (`Rgba16Uint`), from L16, LA16, RGB16, RGBA16.
    Bits16,
    /// Heights, metres in 32-bit floats (`R32Float`): `l32f` as published, `l16` and `l16i`
    /// converted on upload (`crate::shading::HeightShading::to_gpu`).
    Float32,
    /// A block-compressed mapping's blocks as published (`Bc1RgbaUnorm`, `Bc4RUnorm`,
    /// `Bc5RgUnorm`, `Bc7RgbaUnorm`), decoded by the GPU; on an adapter without BC textures
    /// they are decoded on the CPU and uploaded as [`Texels::Bits8`] instead.
    Blocks(Bc),
}

impl Texels {
    fn format(self) -> wgpu::TextureFormat {
        match self {
            Texels::Bits8 => wgpu::TextureFormat::Rgba8Uint,
            Texels::Bits16 => wgpu::TextureFormat::Rgba16Uint,
            Texels::Float32 => wgpu::TextureFormat::R32Float,
            Texels::Blocks(Bc::Bc1) => wgpu::TextureFormat::Bc1RgbaUnorm,
            Texels::Blocks(Bc::Bc4) => wgpu::TextureFormat::Bc4RUnorm,
            Texels::Blocks(Bc::Bc5) => wgpu::TextureFormat::Bc5RgUnorm,
            Texels::Blocks(Bc::Bc7) => wgpu::TextureFormat::Bc7RgbaUnorm,
        }
    }

    /// The GPU texture format's name, as the JSON reports it.
    pub fn gpu_format(self) -> String {
        format!("{:?}", self.format())
    }

    /// How the shader widens a block format's channels (the frame's `params.w`): 1 for `bc4`
    /// (one channel as grey, L L L 1), 2 for `bc5` (two as grey and alpha, R R R G), as the CPU
    /// reads the decoded texels (`clipmap::sample::blocks::decoded_format`); 0 otherwise.
    fn widen(self) -> f64 {
        match self {
            Texels::Blocks(Bc::Bc4) => 1.0,
            Texels::Blocks(Bc::Bc5) => 2.0,
            _ => 0.0,
        }
    }

    /// Bytes of one texel on the GPU (for blocks: of a texel's RGBA8 decode, the components
    /// the shader reads).
    pub fn bytes(self) -> u32 {
        match self {
            Texels::Bits8 | Texels::Float32 | Texels::Blocks(_) => 4,
            Texels::Bits16 => 8,
        }
    }

    /// Whether the texels are heights (the shader's `heights` variant).
    pub fn heights(self) -> bool {
        self == Texels::Float32
    }

    /// Component value c to [0, 1], as `clipmap::texel::TexelFormat::decode` computes it (no table
    /// for heights).
    fn decode_table(self) -> Option<Vec<u8>> {
        let v: Vec<f32> = match self {
            Texels::Bits8 | Texels::Blocks(_) => (0..=255u32).map(|c| c as u8 as f32 / 255.0).collect(),
            Texels::Bits16 => (0..=65535u32).map(|c| c as u16 as f32 / 65535.0).collect(),
            Texels::Float32 => return None,
        };
        Some(v.iter().flat_map(|x| x.to_le_bytes()).collect())
    }

    /// The render targets: the colour, where it sampled, its LOD, and for heights the sampled
    /// height (f32 bits) and what the pixel is.
    fn targets(self) -> Vec<(wgpu::TextureFormat, u32)> {
        let mut t = TARGETS.to_vec();
        if self.heights() {
            t.push((wgpu::TextureFormat::Rg32Uint, 8));
        }
        t
    }
}

/// The shader for `texels`: ground.wgsl with the lines of the other variants' sections
/// (`//#if colour`, `//#if blocks` or `//#if heights` up to `//#end`; a section may name
/// several) blanked, so that line numbers in a
/// compiler's message are the file's.
pub fn shader_source(texels: Texels) -> String {
    let keep = match texels {
        Texels::Float32 => "heights",
        Texels::Blocks(_) => "blocks",
        Texels::Bits8 | Texels::Bits16 => "colour",
    };
    let mut out = String::new();
    let mut section: Option<bool> = None;
    for line in include_str!("ground.wgsl").lines() {
        let t = line.trim();
        if let Some(names) = t.strip_prefix("//#if ") {
            section = Some(names.split_whitespace().any(|n| n == keep));
        } else if t == "//#end" {
            section = None;
        } else if section != Some(false) {
            out.push_str(line);
        }
        out.push('\n');
    }
    out
}

/// What a pixel of a height frame is (`Frame::height`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HeightPixel {
    /// Sky, or off the texture.
    Sky,
    /// The sampled height, metres (the shader's f32).
    Metres(f32),
    /// The filter touched a texel without data.
    Nodata,
    /// No level holds the footprint (nothing published yet).
    Nothing,
}

/// A frame read back: the pixels, and per pixel where the shader sampled.
pub struct Frame {
    /// RGBA8, rows top to bottom.
    pub rgba: Vec<u8>,
    /// Per pixel: level-0 texel s, t and their fractions times 2^24 (u = s + fs 2^-24 exactly).
    pub at: Vec<[u32; 4]>,
    /// Per pixel: its LOD clamped to the levels (before min LOD); negative for sky.
    pub lod: Vec<f32>,
    /// Per pixel, for a height texture: the sampled height's f32 bits and what the pixel is (0
    /// sky, 1 a height, 2 nodata, 3 nothing); empty for colour.
    pub heights: Vec<[u32; 2]>,
}

impl Frame {
    /// Pixel `n`'s footprint as the shader used it (`None`: sky): (u, v) in level-0 texels,
    /// exactly, and the LOD.
    pub fn footprint(&self, n: usize) -> Option<([f64; 2], f64)> {
        let lod = self.lod[n];
        if lod < 0.0 {
            return None;
        }
        let a = self.at[n];
        let c = |i: u32, q: u32| i as i32 as f64 + q as f64 / (1u64 << 24) as f64;
        Some(([c(a[0], a[2]), c(a[1], a[3])], lod as f64))
    }

    /// Pixel `n` of a height frame; `None` for a colour frame or a status the shader never
    /// writes.
    pub fn height(&self, n: usize) -> Option<HeightPixel> {
        let [bits, what] = *self.heights.get(n)?;
        Some(match what {
            0 => HeightPixel::Sky,
            1 => HeightPixel::Metres(f32::from_bits(bits)),
            2 => HeightPixel::Nodata,
            3 => HeightPixel::Nothing,
            _ => return None,
        })
    }
}

/// One level's static shape on the GPU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelShape {
    /// Level size in texels.
    pub size: [u64; 2],
    /// Tile size.
    pub tile: [u64; 2],
    /// Slots per axis.
    pub grid: [u64; 2],
    /// Index of the level's first slot in the tag buffer.
    pub tag_base: u32,
    /// The texture wraps in longitude (the mapping's georef flag): column s is column s mod the
    /// width, and the published region may run past the width (docs/SHM.md, "How a region
    /// wraps").
    pub wraps: bool,
}

impl LevelShape {
    /// Tile column `s` of the level itself: `s mod` the tiles across where the texture wraps.
    pub fn real_tile(&self, s: i64) -> i64 {
        if self.wraps {
            clipmap::geom::wrap(s, self.size[0].div_ceil(self.tile[0])) as i64
        } else {
            s
        }
    }

    /// Column `s` where the region `r` sees it (a width away across the seam where the texture
    /// wraps).
    pub fn near_window(&self, s: i64, r: clipmap::geom::Rect) -> i64 {
        if self.wraps && !r.is_empty() {
            clipmap::geom::shift_near(clipmap::geom::Rect::new(s, 0, s + 1, 1), self.size[0], (r.s0 + r.s1) / 2).s0
        } else {
            s
        }
    }
}

/// The textures, tags and pipeline for one mapping's shape.
pub struct Renderer {
    /// Levels.
    pub levels: Vec<LevelShape>,
    /// What a texel is on the GPU.
    pub texels: Texels,
    /// For heights: the nodata value and false-colour range the shader uses.
    pub heights: Option<crate::shading::HeightShading>,
    texture: wgpu::Texture,
    tags: wgpu::Buffer,
    frame: wgpu::Buffer,
    bind: wgpu::BindGroup,
    pipeline: wgpu::RenderPipeline,
    target: Option<Target>,
    /// Slots of all levels.
    pub slot_count: usize,
}

/// The shape of a mapping's levels (what [`Renderer::new`] builds for).
pub fn shapes(client: &Client) -> Vec<LevelShape> {
    let mut base = 0u32;
    client
        .levels
        .iter()
        .map(|d| {
            let s = LevelShape { size: d.size, tile: d.tile, grid: d.grid, tag_base: base, wraps: client.wraps() };
            base += (d.grid[0] * d.grid[1]) as u32;
            s
        })
        .collect()
}

/// The render targets of a frame size and their read-back buffers.
struct Target {
    size: [u32; 2],
    /// (texture, read-back buffer, bytes a pixel, bytes a row in the buffer).
    planes: Vec<(wgpu::Texture, wgpu::Buffer, u32, u32)>,
}

/// The targets' formats: the colour, where it sampled, its LOD.
const TARGETS: [(wgpu::TextureFormat, u32); 3] =
    [(wgpu::TextureFormat::Rgba8Uint, 4), (wgpu::TextureFormat::Rgba32Uint, 16), (wgpu::TextureFormat::R32Float, 4)];

fn push_i32(out: &mut Vec<u8>, v: [i64; 4]) {
    for x in v {
        out.extend_from_slice(&(x as i32).to_le_bytes());
    }
}

fn push_f32(out: &mut Vec<u8>, v: [f64; 4]) {
    for x in v {
        out.extend_from_slice(&(x as f32).to_le_bytes());
    }
}

impl Renderer {
    /// Textures sized for `levels` (a layer each, as large as the largest image cache).
    pub fn new(gpu: &Gpu, levels: Vec<LevelShape>, texels: Texels) -> Result<Renderer> {
        gpu.checked(
            "creating the textures, buffers and pipeline",
            "the image caches may be too large for this adapter: use a smaller clip size",
            || Renderer::build(gpu, levels, texels),
        )?
    }

    fn build(gpu: &Gpu, levels: Vec<LevelShape>, texels: Texels) -> Result<Renderer> {
        if levels.is_empty() || levels.len() > MAX_LEVELS {
            return Err(anyhow!("{} levels: expected 1 to {MAX_LEVELS}", levels.len()));
        }
        let w = levels.iter().map(|l| l.tile[0] * l.grid[0]).max().unwrap_or(1);
        let h = levels.iter().map(|l| l.tile[1] * l.grid[1]).max().unwrap_or(1);
        // A block-compressed texture is whole blocks.
        let (w, h) =
            if matches!(texels, Texels::Blocks(_)) { (w.next_multiple_of(4), h.next_multiple_of(4)) } else { (w, h) };
        let lim = gpu.device.limits();
        if w > lim.max_texture_dimension_2d as u64 || h > lim.max_texture_dimension_2d as u64 {
            return Err(anyhow!(
                "an image cache of {w}x{h} texels is larger than the adapter's textures ({} a side): \
                 use a smaller clip size or mem_region_size",
                lim.max_texture_dimension_2d
            ));
        }
        let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("image caches"),
            size: wgpu::Extent3d { width: w as u32, height: h as u32, depth_or_array_layers: levels.len() as u32 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: texels.format(),
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let slot_count: usize = levels.iter().map(|l| (l.grid[0] * l.grid[1]) as usize).sum();
        let tags = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("slot tags"),
            size: (slot_count.max(1) * 16) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let frame = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("frame"),
            size: (FRAME_HEAD_BYTES + MAX_LEVELS * LEVEL_BYTES) as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let decode = texels.decode_table().map(|table| {
            let decode = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("decode"),
                size: table.len() as u64,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            gpu.queue.write_buffer(&decode, 0, &table);
            decode
        });
        let shader = gpu.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(match texels {
                Texels::Float32 => "ground.wgsl (heights)",
                Texels::Blocks(_) => "ground.wgsl (blocks)",
                Texels::Bits8 | Texels::Bits16 => "ground.wgsl (colour)",
            }),
            source: wgpu::ShaderSource::Wgsl(shader_source(texels).into()),
        });
        let sample_type = match texels {
            Texels::Float32 => wgpu::TextureSampleType::Float { filterable: false },
            Texels::Blocks(_) => wgpu::TextureSampleType::Float { filterable: true },
            Texels::Bits8 | Texels::Bits16 => wgpu::TextureSampleType::Uint,
        };
        let entry = |binding, ty| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty,
            count: None,
        };
        let mut entries = vec![
            entry(
                0,
                wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
            ),
            entry(
                1,
                wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only: true },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
            ),
            entry(
                2,
                wgpu::BindingType::Texture {
                    sample_type,
                    view_dimension: wgpu::TextureViewDimension::D2Array,
                    multisampled: false,
                },
            ),
        ];
        if decode.is_some() {
            entries.push(entry(
                3,
                wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only: true },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
            ));
        }
        let layout = gpu
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("clipmap"), entries: &entries });
        let view = texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let mut bound = vec![
            wgpu::BindGroupEntry { binding: 0, resource: frame.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 1, resource: tags.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 2, resource: wgpu::BindingResource::TextureView(&view) },
        ];
        if let Some(decode) = &decode {
            bound.push(wgpu::BindGroupEntry { binding: 3, resource: decode.as_entire_binding() });
        }
        let bind = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("clipmap"),
            layout: &layout,
            entries: &bound,
        });
        let pipeline_layout = gpu.device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("ground"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = gpu.device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("ground"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &shader,
                entry_point: Some("vs"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &shader,
                entry_point: Some("fs"),
                compilation_options: Default::default(),
                targets: &texels
                    .targets()
                    .into_iter()
                    .map(|(format, _)| {
                        Some(wgpu::ColorTargetState { format, blend: None, write_mask: wgpu::ColorWrites::ALL })
                    })
                    .collect::<Vec<_>>(),
            }),
            multiview_mask: None,
            cache: None,
        });
        let r =
            Renderer { levels, texels, heights: None, texture, tags, frame, bind, pipeline, target: None, slot_count };
        r.clear_tags(gpu);
        Ok(r)
    }

    /// Marks every slot empty (nothing held).
    pub fn clear_tags(&self, gpu: &Gpu) {
        let mut empty = Vec::with_capacity(self.slot_count * 16);
        for _ in 0..self.slot_count {
            push_i32(&mut empty, [i32::MIN as i64, i32::MIN as i64, 0, 0]);
        }
        if !empty.is_empty() {
            gpu.queue.write_buffer(&self.tags, 0, &empty);
        }
    }

    /// Writes the tags of slots `first..first + tags.len()` (tile S, T, held).
    pub fn write_tags(&self, gpu: &Gpu, first: usize, tags: &[([i64; 2], bool)]) {
        let mut bytes = Vec::with_capacity(tags.len() * 16);
        for &(tile, held) in tags {
            push_i32(&mut bytes, [tile[0], tile[1], held as i64, 0]);
        }
        gpu.queue.write_buffer(&self.tags, (first * 16) as u64, &bytes);
    }

    /// Writes texels (RGBA, [`Texels`]) of a `w` x `h` rectangle at (x, y) of level `k`'s layer;
    /// for [`Texels::Blocks`], the `ceil(w / 4)` x `ceil(h / 4)` blocks of a tile whose corner
    /// (x, y) starts a block (a tile narrower than a block is its level's only one, at 0, 0).
    pub fn write_texels(&self, gpu: &Gpu, k: usize, at: [u32; 2], size: [u32; 2], rgba: &[u8]) {
        let (size, bytes_per_row) = match self.texels {
            Texels::Blocks(bc) => {
                let blocks = [size[0].div_ceil(4), size[1].div_ceil(4)];
                ([blocks[0] * 4, blocks[1] * 4], blocks[0] * bc.block_bytes())
            }
            t => (size, size[0] * t.bytes()),
        };
        gpu.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &self.texture,
                mip_level: 0,
                origin: wgpu::Origin3d { x: at[0], y: at[1], z: k as u32 },
                aspect: wgpu::TextureAspect::All,
            },
            rgba,
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(bytes_per_row), rows_per_image: None },
            wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 },
        );
    }

    /// Submits what was written (uploads go with the next submission otherwise).
    pub fn flush(&self, gpu: &Gpu) {
        gpu.queue.submit(std::iter::empty());
    }

    fn frame_bytes(&self, cam: &Camera, snap: &Snapshot, filter: Filter) -> Vec<u8> {
        let mut b = Vec::with_capacity(FRAME_HEAD_BYTES + MAX_LEVELS * LEVEL_BYTES);
        let (ei, et) = (cam.eye[0].floor(), cam.eye[1].floor());
        let tan = (cam.fov_deg.to_radians() / 2.0).tan();
        push_f32(&mut b, [cam.eye[0] - ei, cam.eye[1] - et, cam.eye[2], tan]);
        push_i32(&mut b, [ei as i64, et as i64, cam.width as i64, cam.height as i64]);
        let (f, r, u) = cam.basis();
        push_f32(&mut b, [f[0], f[1], f[2], 0.0]);
        push_f32(&mut b, [r[0], r[1], r[2], 0.0]);
        push_f32(&mut b, [u[0], u[1], u[2], 0.0]);
        let filter = match filter {
            Filter::Point => 0.0,
            Filter::Bilinear => 1.0,
            Filter::Trilinear => 2.0,
        };
        push_f32(&mut b, [snap.min_lod, self.levels.len() as f64, filter, self.texels.widen()]);
        match &self.heights {
            Some(h) => h.uniform().iter().for_each(|x| b.extend_from_slice(&x.to_le_bytes())),
            None => b.extend_from_slice(&[0u8; 16]),
        }
        for k in 0..MAX_LEVELS {
            match (self.levels.get(k), snap.levels.get(k)) {
                (Some(l), Some(st)) => {
                    push_i32(&mut b, st.valid);
                    // Bit 0: enabled; bit 1: the texture wraps in longitude.
                    let flags = st.enabled as i64 | (i64::from(l.wraps) << 1);
                    push_i32(&mut b, [l.size[0] as i64, l.size[1] as i64, flags, l.tag_base as i64]);
                    push_i32(&mut b, [l.tile[0] as i64, l.tile[1] as i64, l.grid[0] as i64, l.grid[1] as i64]);
                }
                _ => b.extend_from_slice(&[0u8; LEVEL_BYTES]),
            }
        }
        b
    }

    /// Draws the camera's view from what the textures hold under `snap` and reads it back.
    pub fn draw(&mut self, gpu: &Gpu, cam: &Camera, snap: &Snapshot, filter: Filter) -> Result<Frame> {
        let size = [cam.width, cam.height];
        let max = gpu.max_texture_side();
        let what = format!("drawing a frame of {}x{} pixels", size[0], size[1]);
        let hint = format!("this adapter's render targets are at most {max} pixels a side: use a smaller --size");
        let planes = gpu.checked(&what, &hint, || self.render(gpu, cam, snap, filter))??;
        gpu.wait()?;
        let mut out = Vec::new();
        for (_, buf, bpp, pitch) in &planes.planes {
            let (tx, rx) = std::sync::mpsc::channel();
            buf.slice(..).map_async(wgpu::MapMode::Read, move |r| {
                let _ = tx.send(r);
            });
            gpu.wait()?;
            rx.recv().context("the GPU dropped the read-back")?.map_err(|e| anyhow!("reading the frame back: {e}"))?;
            let mut bytes = Vec::with_capacity((size[0] * size[1] * bpp) as usize);
            {
                let data = buf.slice(..).get_mapped_range().map_err(|e| anyhow!("reading the frame back: {e}"))?;
                for row in data.chunks(*pitch as usize).take(size[1] as usize) {
                    bytes.extend_from_slice(&row[..(size[0] * bpp) as usize]);
                }
            }
            buf.unmap();
            out.push(bytes);
        }
        self.target = Some(planes);
        let mut out = out.into_iter();
        let (rgba, at, lod, heights) = (
            out.next().unwrap_or_default(),
            out.next().unwrap_or_default(),
            out.next().unwrap_or_default(),
            out.next().unwrap_or_default(),
        );
        let word = |b: &[u8]| u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        Ok(Frame {
            rgba,
            at: at.chunks_exact(16).map(|p| [word(&p[0..]), word(&p[4..]), word(&p[8..]), word(&p[12..])]).collect(),
            lod: lod.chunks_exact(4).map(|p| f32::from_bits(word(p))).collect(),
            heights: heights.chunks_exact(8).map(|p| [word(&p[0..]), word(&p[4..])]).collect(),
        })
    }

    /// Records and submits the frame's pass and copies; returns the targets (made here when the
    /// frame size changed).
    fn render(&mut self, gpu: &Gpu, cam: &Camera, snap: &Snapshot, filter: Filter) -> Result<Target> {
        gpu.queue.write_buffer(&self.frame, 0, &self.frame_bytes(cam, snap, filter));
        let size = [cam.width, cam.height];
        let target = match self.target.take() {
            Some(t) if t.size == size => t,
            _ => Target {
                size,
                planes: self
                    .texels
                    .targets()
                    .into_iter()
                    .map(|(format, bpp)| {
                        let pitch = (size[0] * bpp).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
                            * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
                        let tex = gpu.device.create_texture(&wgpu::TextureDescriptor {
                            label: Some("frame"),
                            size: wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 },
                            mip_level_count: 1,
                            sample_count: 1,
                            dimension: wgpu::TextureDimension::D2,
                            format,
                            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
                            view_formats: &[],
                        });
                        let buf = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                            label: Some("readback"),
                            size: (pitch as u64) * size[1] as u64,
                            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                            mapped_at_creation: false,
                        });
                        (tex, buf, bpp, pitch)
                    })
                    .collect(),
            },
        };
        let views: Vec<wgpu::TextureView> =
            target.planes.iter().map(|p| p.0.create_view(&wgpu::TextureViewDescriptor::default())).collect();
        let mut enc = gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("frame") });
        {
            let attachments: Vec<Option<wgpu::RenderPassColorAttachment>> = views
                .iter()
                .map(|view| {
                    Some(wgpu::RenderPassColorAttachment {
                        view,
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                            store: wgpu::StoreOp::Store,
                        },
                    })
                })
                .collect();
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("ground"),
                color_attachments: &attachments,
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.bind, &[]);
            pass.draw(0..3, 0..1);
        }
        for (tex, buf, _, pitch) in &target.planes {
            enc.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture: tex,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: buf,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(*pitch),
                        rows_per_image: Some(size[1]),
                    },
                },
                wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 },
            );
        }
        gpu.queue.submit([enc.finish()]);
        Ok(target)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_shader_variant_keeps_its_own_section_and_the_file_s_line_numbers() {
        let file = include_str!("ground.wgsl");
        let colour = shader_source(Texels::Bits8);
        let heights = shader_source(Texels::Float32);
        let blocks = shader_source(Texels::Blocks(Bc::Bc1));
        assert_eq!(shader_source(Texels::Bits16), colour);
        assert_eq!(shader_source(Texels::Blocks(Bc::Bc7)), blocks);
        for (name, src, cache, other) in [
            ("colour", &colour, "texture_2d_array<u32>", "texture_2d_array<f32>"),
            ("heights", &heights, "texture_2d_array<f32>", "texture_2d_array<u32>"),
            ("blocks", &blocks, "texture_2d_array<f32>", "texture_2d_array<u32>"),
        ] {
            assert_eq!(src.lines().count(), file.lines().count(), "{name}");
            assert_eq!(src.matches("var cache").count(), 1, "{name}");
            assert!(src.contains(cache) && !src.contains(other), "{name}");
            assert_eq!(src.matches("struct Out {").count(), 1, "{name}");
            assert_eq!(src.matches("fn load(").count(), 1, "{name}");
            assert!(!src.contains("//#"), "{name}: a marker left in");
            // The shared parts are the file's, line for line.
            for (a, b) in src.lines().zip(file.lines()) {
                assert!(a.is_empty() || a == b, "{name}: {a:?} is not the file's {b:?}");
            }
        }
        assert!(colour.contains("var<storage, read> decode") && !heights.contains("var<storage, read> decode"));
        // Blocks: the GPU's unorm decode back to 8-bit codes, then the colour's table and output.
        let back = "round(clamp(f, vec4<f32>(0.0), vec4<f32>(1.0)) * 255.0)";
        assert!(blocks.contains("var<storage, read> decode") && blocks.contains(back));
        assert!(!colour.contains(back) && !heights.contains(back));
        assert_eq!(Texels::Blocks(Bc::Bc4).widen(), 1.0);
        assert_eq!(Texels::Blocks(Bc::Bc5).widen(), 2.0);
        assert_eq!(Texels::Blocks(Bc::Bc7).widen(), 0.0);
        assert!(heights.contains("@location(3) height") && !colour.contains("@location(3)"));
    }
}
