//! The render pipelines of the passes (see the module map in `fluoro`), their target
//! formats, the resolve pass's bind group layout and the per-size render targets: what the
//! L-buffer and resolve passes record with.

use std::sync::PoisonError;

use super::types::Vertex;
use crate::gpu::GpuContext;
use crate::interrupt::Interrupt;

/// Every pipeline of the renderer, built once per device.
pub(super) struct Pipelines {
    /// The needle's hull and chord pass.
    pub(super) needle: wgpu::RenderPipeline,
    /// The geometric anatomy pass into the four-channel L-buffer.
    pub(super) anatomy: wgpu::RenderPipeline,
    /// The geometric anatomy pass into the one-channel (water-basis) L-buffer.
    pub(super) anatomy_scalar: wgpu::RenderPipeline,
    /// The displaced anatomy pass.
    pub(super) displaced: wgpu::RenderPipeline,
    /// The resolve, `[iodine][needle]`: without and with the iodine ray march, and without
    /// and with the needle's inputs (drawn over the needle's pixel box only); one bind group
    /// layout (`resolve_layout`) serves all four.
    pub(super) resolve: [[wgpu::RenderPipeline; 2]; 2],
    pub(super) resolve_layout: wgpu::BindGroupLayout,
}

/// Render targets of one region size for one frame: the geometric L-buffer and the rest. A
/// renderer keeps only the full image's geometric part between frames (its cache); everything
/// else is written before it is read within each frame, so it is taken from the anatomy's
/// [`TargetPool`] when a frame starts and given back when it ends.
pub(super) struct Targets {
    pub(super) geometry: GeometryTargets,
    pub(super) frame: FrameTargets,
}

impl Targets {
    /// Samples per axis (both parts have the same).
    pub(super) fn size(&self) -> [u32; 2] {
        self.geometry.size
    }
}

/// The geometric L-buffer of one size.
pub(super) struct GeometryTargets {
    pub(super) size: [u32; 2],
    /// Geometric L-buffer (needle-independent): the non-scalar meshes in the transmission
    /// layout, every mesh in the chord layout.
    pub(super) a: wgpu::Texture,
    /// Geometric L-buffer of the scalar meshes, transmission layout (water-basis channel).
    pub(super) s: wgpu::Texture,
}

/// The targets a frame writes before it reads them (the needle's passes clear theirs, the
/// resolve writes every sample it reads back), so any renderer of the anatomy can use them next.
pub(super) struct FrameTargets {
    pub(super) size: [u32; 2],
    /// Displaced part (zero outside the needle's pixel box).
    pub(super) d: wgpu::Texture,
    pub(super) hull: wgpu::Texture,
    pub(super) chord: wgpu::Texture,
    pub(super) out_t: wgpu::Buffer,
    /// The resolve's render target: it only sizes the pass (write mask empty; cleared, one byte
    /// per sample, and discarded); the output is `out_t`.
    pub(super) resolve: wgpu::Texture,
    /// Mapped-readable copy of `out_t` (no allocation per frame).
    pub(super) staging: wgpu::Buffer,
}

/// Target sets no frame is using, shared by every renderer of one anatomy (see [`Targets`]).
/// Before, each renderer held all of its full-image and supersampled-region targets between
/// frames (14 MB at 512 x 512, 9 MB of it besides the kept L-buffer, plus a few MB for the
/// region), most of a session's memory. A set is taken when a frame starts (one of its size,
/// else a new one) and given back when it ends; at most [`POOL_KEEP`] sets of each kind stay
/// free, the oldest are dropped.
#[derive(Default)]
pub(super) struct TargetPool {
    free: std::sync::Mutex<FreeTargets>,
    /// Frames holding targets now and waiting for them (see [`IN_FLIGHT`], [`TargetPool::enter`]).
    gate: std::sync::Mutex<Gate>,
    turn: std::sync::Condvar,
}

/// Frames waiting for targets, and those holding them.
#[derive(Default)]
struct Gate {
    /// Tickets given so far (arrival order).
    issued: u64,
    /// Frames holding targets now, and how many of them are refinements.
    holders: u64,
    refining_holders: u64,
    /// Waiting frames in admission order, as (class, ticket, refining): class 0 a frame
    /// someone waits on (or a refinement that waited [`REFINING_PATIENCE`]), class 1 a
    /// refinement.
    waiting: std::collections::BTreeSet<(u8, u64, bool)>,
    /// Frames that gave their targets back (every admitted frame does once).
    returned: u64,
}

impl Gate {
    /// The waiting frame that goes in next: the first in admission order for which a turn is
    /// free (a refinement waits while another holds targets; the frames behind it need not).
    fn first_that_fits(&self) -> Option<(u8, u64, bool)> {
        let fits = |refining: bool| {
            self.holders < IN_FLIGHT && (!refining || self.refining_holders < IN_FLIGHT - 1)
        };
        self.waiting.iter().find(|w| fits(w.2)).copied()
    }
}

/// A frame's turn at the targets ([`TargetPool::enter`]); give it back with
/// [`TargetPool::leave`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[must_use = "every turn is given back with `TargetPool::leave`"]
pub(super) struct Turn {
    refining: bool,
}

/// How long a refinement (the full frame behind a draft already shown) lets frames someone waits
/// on go first before it queues with them in arrival order. Simulator choice: a learner who
/// stopped moving sees the full frame within about a second however busy the server is.
pub(super) const REFINING_PATIENCE: std::time::Duration = std::time::Duration::from_secs(1);

/// How often a refinement waiting for targets looks whether newer input has made it obsolete
/// (`crate::interrupt`): then it gives up its place. Simulator choice: the session thread's
/// own poll during a pause (2 ms).
const GATE_POLL: std::time::Duration = std::time::Duration::from_millis(2);

/// Frames of one anatomy that hold targets at once; the next one waits until one ends (in
/// the order [`TargetPool::enter`] gives: frames someone waits on before refinements). The
/// device runs one queue's submissions in order (lavapipe: one after the other), so a frame
/// admitted later would only wait in that queue, holding its
/// targets (9 MB for a 512^2 image): in a capacity bench run with 16 learners the pool made 44
/// full-image sets while frames queued behind each other. Two let one frame be recorded and read
/// back while another runs. Capacity bench, 16 learners, rows of 10 s: with the limit p50
/// 1,201 ms, p99 3,917 ms, server RSS 1,468 MiB; without it 909 ms, 4,895 ms, 1,552 MiB (one
/// run each). Before the resolve's leak was mended (`resolve.wgsl`), two runs with the limit
/// against four without: p50 1,092-1,126 against 569-1,085 ms, p99 3,266-3,689 against
/// 4,340-5,674 ms. The limit trades some median for the tail and bounds memory under load.
pub(super) const IN_FLIGHT: u64 = 2;

// A refinement holds at most `IN_FLIGHT - 1` turns (`TargetPool::enter`): with one turn in all
// none would ever be admitted.
const _: () = assert!(
    IN_FLIGHT >= 2,
    "refinements need a turn besides the one kept"
);

#[derive(Default)]
struct FreeTargets {
    geometry: Vec<GeometryTargets>,
    frame: Vec<FrameTargets>,
}

/// Free sets kept per kind. Each frame in flight holds a set from its encoding to its read-back;
/// sessions render when their learner acts and the device runs one queue's submissions in
/// order, so a few sets serve many sessions, and more would only hold memory (a set beyond is
/// dropped, and made again by the frame that needs it).
pub(super) const POOL_KEEP: usize = 4;

impl TargetPool {
    /// A free geometric L-buffer of `size`, or a new one. Its contents are undefined: the
    /// geometric pass clears it.
    pub(super) fn take_geometry(&self, device: &wgpu::Device, size: [u32; 2]) -> GeometryTargets {
        let found = take_sized(&mut self.lock().geometry, |g| g.size == size);
        found.unwrap_or_else(|| GeometryTargets::new(device, size))
    }

    /// Free frame targets of `size`, or new ones.
    pub(super) fn take_frame(&self, device: &wgpu::Device, size: [u32; 2]) -> FrameTargets {
        let found = take_sized(&mut self.lock().frame, |f| f.size == size);
        found.unwrap_or_else(|| FrameTargets::new(device, size))
    }

    /// Gives back what a frame used (the geometric part only where the renderer does not keep
    /// it), dropping the oldest free sets beyond [`POOL_KEEP`].
    pub(super) fn give_back(&self, geometry: Option<GeometryTargets>, frame: FrameTargets) {
        let evicted = {
            let mut free = self.lock();
            free.frame.push(frame);
            free.geometry.extend(geometry);
            (
                oldest_beyond_keep(&mut free.geometry),
                oldest_beyond_keep(&mut free.frame),
            )
        };
        // Freed outside the lock.
        drop(evicted);
    }

    /// Waits for a frame's turn to hold targets (see [`IN_FLIGHT`]); every turn is given back
    /// with one [`TargetPool::leave`]. Frames someone waits on (shots, needle steps, drafts,
    /// live pulses) go first, in arrival order; a `refining` frame (see
    /// `crate::priority::refining`) goes after them until it has waited
    /// [`REFINING_PATIENCE`], and at most `IN_FLIGHT - 1` refinements hold targets at once, so
    /// a turn is always left for a frame someone waits on. A refinement's CPU pass runs at a
    /// lower priority while it holds its turn (`crate::priority`); before, frames were admitted
    /// first come first served and a needle step's shot could wait behind two refinements.
    /// `None` where `interrupt` (the flags the frame's thread watches) says, while it waits,
    /// that newer input made the frame obsolete or that a command waits for its session (which
    /// the session then takes first, rendering what it needs at the priority of a frame someone
    /// waits on): it holds nothing.
    pub(super) fn enter(&self, refining: bool, interrupt: &Interrupt) -> Option<Turn> {
        self.enter_with_patience(refining, REFINING_PATIENCE, interrupt)
    }

    /// [`TargetPool::enter`] with a refinement's `patience` given.
    fn enter_with_patience(
        &self,
        refining: bool,
        patience: std::time::Duration,
        interrupt: &Interrupt,
    ) -> Option<Turn> {
        let started = std::time::Instant::now();
        let mut gate = self.gate.lock().unwrap_or_else(PoisonError::into_inner);
        let ticket = gate.issued;
        gate.issued += 1;
        let mut me = (u8::from(refining), ticket, refining);
        gate.waiting.insert(me);
        loop {
            if gate.first_that_fits() == Some(me) {
                gate.waiting.remove(&me);
                gate.holders += 1;
                gate.refining_holders += u64::from(refining);
                // The next in line may fit beside this one.
                self.turn.notify_all();
                return Some(Turn { refining });
            }
            if interrupt.is_raised() || interrupt.input_waits() {
                gate.waiting.remove(&me);
                self.turn.notify_all();
                return None;
            }
            if me.0 == 1 && started.elapsed() >= patience {
                gate.waiting.remove(&me);
                me.0 = 0;
                gate.waiting.insert(me);
                self.turn.notify_all();
                continue;
            }
            gate = if refining {
                // A refinement looks at its patience and at its interrupt now and then.
                let left = patience.saturating_sub(started.elapsed());
                let nap = if me.0 == 1 {
                    left.min(GATE_POLL)
                } else {
                    GATE_POLL
                };
                self.turn
                    .wait_timeout(gate, nap)
                    .unwrap_or_else(PoisonError::into_inner)
                    .0
            } else {
                self.turn.wait(gate).unwrap_or_else(PoisonError::into_inner)
            };
        }
    }

    /// A frame admitted by [`TargetPool::enter`] holds no targets any more.
    pub(super) fn leave(&self, turn: Turn) {
        {
            let mut gate = self.gate.lock().unwrap_or_else(PoisonError::into_inner);
            gate.holders -= 1;
            gate.refining_holders -= u64::from(turn.refining);
            gate.returned += 1;
        }
        self.turn.notify_all();
    }

    /// Free sets (geometric, frame) now.
    pub(super) fn free_sets(&self) -> (usize, usize) {
        let free = self.lock();
        (free.geometry.len(), free.frame.len())
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, FreeTargets> {
        // The lists stay consistent whatever panicked while holding them.
        self.free.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// The most recently given back of `free` that `fits`, taken out of the list.
fn take_sized<T>(free: &mut Vec<T>, fits: impl Fn(&T) -> bool) -> Option<T> {
    let i = free.iter().rposition(fits)?;
    Some(free.remove(i))
}

/// The oldest of `free` if it holds more than [`POOL_KEEP`], taken out of the list.
fn oldest_beyond_keep<T>(free: &mut Vec<T>) -> Option<T> {
    (free.len() > POOL_KEEP).then(|| free.remove(0))
}

const FMT_A: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
/// The scalar meshes' geometric L-buffer: the water-basis channel only. On lavapipe a fragment
/// blended into one float channel is markedly cheaper than one blended into four, and most of
/// the phantom's fragments are soft tissue.
const FMT_SCALAR: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
/// The resolve pass's colour target (write mask empty: it only sets the pass's size).
const FMT_RESOLVE: wgpu::TextureFormat = wgpu::TextureFormat::R8Unorm;
const FMT_HULL: wgpu::TextureFormat = wgpu::TextureFormat::Rg32Float;
const FMT_CHORD: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;

fn additive() -> wgpu::BlendState {
    let c = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::One,
        dst_factor: wgpu::BlendFactor::One,
        operation: wgpu::BlendOperation::Add,
    };
    wgpu::BlendState { color: c, alpha: c }
}

fn minimum() -> wgpu::BlendState {
    let c = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::One,
        dst_factor: wgpu::BlendFactor::One,
        operation: wgpu::BlendOperation::Min,
    };
    wgpu::BlendState { color: c, alpha: c }
}

fn target(format: wgpu::TextureFormat, blend: wgpu::BlendState) -> Option<wgpu::ColorTargetState> {
    Some(wgpu::ColorTargetState {
        format,
        blend: Some(blend),
        write_mask: wgpu::ColorWrites::ALL,
    })
}

impl Pipelines {
    pub(super) fn new(ctx: &GpuContext) -> Pipelines {
        let device = &ctx.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("fluoro lbuffer"),
            source: wgpu::ShaderSource::Wgsl(include_str!("lbuffer.wgsl").into()),
        });
        let resolve_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("fluoro resolve"),
            source: wgpu::ShaderSource::Wgsl(include_str!("resolve.wgsl").into()),
        });
        let vertex_layout = wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<Vertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Uint32, 2 => Float32x3],
        };
        // WGSL's fragment position w is 1 / w_clip; wgpu's D3D12 backend passes w_clip
        // (gfx-rs/wgpu#4963), so the geometric pass is told which it gets.
        let position_w_is_reciprocal = ctx.summary.backend != "dx12";
        let raster =
            |label: &str, vs: &str, fs: &str, targets: &[Option<wgpu::ColorTargetState>]| {
                device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some(label),
                    layout: None,
                    vertex: wgpu::VertexState {
                        module: &module,
                        entry_point: Some(vs),
                        compilation_options: Default::default(),
                        buffers: &[Some(vertex_layout.clone())],
                    },
                    primitive: wgpu::PrimitiveState {
                        topology: wgpu::PrimitiveTopology::TriangleList,
                        strip_index_format: None,
                        // Outward-wound (CCW seen from outside) triangles facing the source appear
                        // clockwise in clip space, because the detector's (u, up) frame has
                        // u x up = +n, pointing away from the source.
                        front_face: wgpu::FrontFace::Cw,
                        cull_mode: None,
                        unclipped_depth: false,
                        polygon_mode: wgpu::PolygonMode::Fill,
                        conservative: false,
                    },
                    depth_stencil: None,
                    multisample: wgpu::MultisampleState::default(),
                    fragment: Some(wgpu::FragmentState {
                        module: &module,
                        entry_point: Some(fs),
                        compilation_options: wgpu::PipelineCompilationOptions {
                            constants: &[(
                                "position_w_is_reciprocal",
                                f64::from(u8::from(position_w_is_reciprocal)),
                            )],
                            ..Default::default()
                        },
                        targets,
                    }),
                    multiview_mask: None,
                    cache: None,
                })
            };
        let needle_pipeline = raster(
            "fluoro needle",
            "vs_needle",
            "fs_needle",
            &[target(FMT_HULL, minimum()), target(FMT_CHORD, additive())],
        );
        let anatomy_pipeline = raster(
            "fluoro anatomy",
            "vs_geometry",
            "fs_anatomy",
            &[target(FMT_A, additive())],
        );
        let anatomy_scalar_pipeline = raster(
            "fluoro anatomy, water-basis channel",
            "vs_geometry",
            "fs_anatomy_scalar",
            &[target(FMT_SCALAR, additive())],
        );
        let displaced_pipeline = raster(
            "fluoro displaced",
            "vs_anatomy",
            "fs_displaced",
            &[target(FMT_A, additive())],
        );
        // Four specialisations of one shader sharing one layout: with and without the iodine
        // ray march and the needle's inputs (`has_iodine`, `has_needle` in the shader).
        let resolve_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("fluoro resolve"),
            entries: &resolve_layout_entries(),
        });
        let resolve_pipeline_layout =
            device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("fluoro resolve"),
                bind_group_layouts: &[Some(&resolve_layout)],
                immediate_size: 0,
            });
        let resolve_kernel = |label: &str, has_iodine: bool, has_needle: bool| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(&resolve_pipeline_layout),
                vertex: wgpu::VertexState {
                    module: &resolve_module,
                    entry_point: Some("vs_cover"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: None,
                multisample: wgpu::MultisampleState::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &resolve_module,
                    entry_point: Some("fs_resolve"),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants: &[
                            ("has_iodine", f64::from(u8::from(has_iodine))),
                            ("has_needle", f64::from(u8::from(has_needle))),
                        ],
                        ..Default::default()
                    },
                    targets: &[Some(wgpu::ColorTargetState {
                        format: FMT_RESOLVE,
                        blend: None,
                        write_mask: wgpu::ColorWrites::empty(),
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let resolve_pipelines = [false, true].map(|iodine| {
            [false, true].map(|needle| {
                let label = format!("fluoro resolve (iodine {iodine}, needle {needle})");
                resolve_kernel(&label, iodine, needle)
            })
        });
        Pipelines {
            needle: needle_pipeline,
            anatomy: anatomy_pipeline,
            anatomy_scalar: anatomy_scalar_pipeline,
            displaced: displaced_pipeline,
            resolve: resolve_pipelines,
            resolve_layout,
        }
    }
}

fn texture(
    device: &wgpu::Device,
    size: [u32; 2],
    label: &str,
    format: wgpu::TextureFormat,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: size[0],
            height: size[1],
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT
            | wgpu::TextureUsages::TEXTURE_BINDING
            | wgpu::TextureUsages::COPY_SRC
            | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    })
}

impl GeometryTargets {
    fn new(device: &wgpu::Device, size: [u32; 2]) -> GeometryTargets {
        GeometryTargets {
            size,
            a: texture(device, size, "fluoro lbuffer", FMT_A),
            s: texture(
                device,
                size,
                "fluoro lbuffer, water-basis channel",
                FMT_SCALAR,
            ),
        }
    }
}

impl FrameTargets {
    fn new(device: &wgpu::Device, size: [u32; 2]) -> FrameTargets {
        let bytes = u64::from(size[0]) * u64::from(size[1]) * 4;
        FrameTargets {
            size,
            d: texture(device, size, "fluoro displaced lbuffer", FMT_A),
            hull: texture(device, size, "fluoro needle hull", FMT_HULL),
            chord: texture(device, size, "fluoro needle chord", FMT_CHORD),
            resolve: texture(device, size, "fluoro resolve target", FMT_RESOLVE),
            out_t: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("fluoro transmission"),
                size: bytes,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            staging: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("fluoro transmission readback"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        }
    }
}

/// The resolve pass's bindings (see `resolve.wgsl`): its uniforms, the L-buffer, the needle's
/// chord, the spectral bins, the iodine grid, the transmission out, the `ln T` table, the
/// displaced L-buffer and the scalar meshes' L-buffer.
fn resolve_layout_entries() -> [wgpu::BindGroupLayoutEntry; 9] {
    let entry = |binding: u32, ty: wgpu::BindingType| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty,
        count: None,
    };
    let buffer = |ty: wgpu::BufferBindingType| wgpu::BindingType::Buffer {
        ty,
        has_dynamic_offset: false,
        min_binding_size: None,
    };
    let texture = |view_dimension: wgpu::TextureViewDimension| wgpu::BindingType::Texture {
        sample_type: wgpu::TextureSampleType::Float { filterable: false },
        view_dimension,
        multisampled: false,
    };
    let read = wgpu::BufferBindingType::Storage { read_only: true };
    [
        entry(0, buffer(wgpu::BufferBindingType::Uniform)),
        entry(1, texture(wgpu::TextureViewDimension::D2)),
        entry(2, texture(wgpu::TextureViewDimension::D2)),
        entry(3, buffer(read)),
        entry(4, texture(wgpu::TextureViewDimension::D3)),
        entry(
            5,
            buffer(wgpu::BufferBindingType::Storage { read_only: false }),
        ),
        entry(6, buffer(read)),
        entry(7, texture(wgpu::TextureViewDimension::D2)),
        entry(8, texture(wgpu::TextureViewDimension::D2)),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame takes a pooled set of its size when there is one, a set of another size is never
    /// handed out, and at most `POOL_KEEP` sets of each kind stay free (the oldest go).
    #[test]
    fn the_pool_hands_out_sets_of_the_asked_size_and_keeps_a_few() {
        let Some(ctx) = crate::gpu::context_for_tests() else {
            return;
        };
        let device = &ctx.device;
        let pool = TargetPool::default();
        let (small, large) = ([8, 4], [16, 8]);
        let taken: Vec<_> = (0..POOL_KEEP + 2)
            .map(|_| {
                (
                    pool.take_geometry(device, small),
                    pool.take_frame(device, small),
                )
            })
            .collect();
        assert_eq!(pool.free_sets(), (0, 0));
        for (g, f) in taken {
            pool.give_back(Some(g), f);
        }
        assert_eq!(pool.free_sets(), (POOL_KEEP, POOL_KEEP));
        let f = pool.take_frame(device, large);
        assert_eq!(f.size, large);
        assert_eq!(
            pool.free_sets(),
            (POOL_KEEP, POOL_KEEP),
            "a new set, none taken"
        );
        let g = pool.take_geometry(device, small);
        assert_eq!(g.size, small);
        assert_eq!(pool.free_sets(), (POOL_KEEP - 1, POOL_KEEP));
        pool.give_back(None, f);
        assert_eq!(
            pool.free_sets(),
            (POOL_KEEP - 1, POOL_KEEP),
            "the oldest went"
        );
        assert_eq!(pool.take_frame(device, large).size, large);
        assert_eq!(
            pool.free_sets(),
            (POOL_KEEP - 1, POOL_KEEP - 1),
            "the pooled one"
        );
        drop(g);
    }

    /// However many frames ask at once (half of them refinements, some of which run out of
    /// patience), at most `IN_FLIGHT` hold targets, at most `IN_FLIGHT - 1` of them
    /// refinements, and every one gets its turn.
    #[test]
    fn at_most_in_flight_frames_hold_targets_at_once() {
        use std::sync::atomic::{AtomicU64, Ordering};
        let pool = std::sync::Arc::new(TargetPool::default());
        // Frames inside and refinements inside: now, and the most seen.
        let counts: std::sync::Arc<[AtomicU64; 4]> = Default::default();
        let threads: Vec<_> = (0..8)
            .map(|k| {
                let (pool, counts) = (pool.clone(), counts.clone());
                let refining = k % 2 == 1;
                std::thread::spawn(move || {
                    for _ in 0..5 {
                        let patience = std::time::Duration::from_millis(3);
                        let turn = pool
                            .enter_with_patience(refining, patience, &Interrupt::default())
                            .expect("no interrupt");
                        let now = counts[0].fetch_add(1, Ordering::SeqCst) + 1;
                        counts[2].fetch_max(now, Ordering::SeqCst);
                        if refining {
                            let now = counts[1].fetch_add(1, Ordering::SeqCst) + 1;
                            counts[3].fetch_max(now, Ordering::SeqCst);
                        }
                        std::thread::sleep(std::time::Duration::from_millis(1));
                        counts[0].fetch_sub(1, Ordering::SeqCst);
                        if refining {
                            counts[1].fetch_sub(1, Ordering::SeqCst);
                        }
                        pool.leave(turn);
                    }
                })
            })
            .collect();
        for t in threads {
            t.join().expect("frame thread");
        }
        assert!((1..=IN_FLIGHT).contains(&counts[2].load(Ordering::SeqCst)));
        assert!((1..IN_FLIGHT).contains(&counts[3].load(Ordering::SeqCst)));
        let gate = pool.gate.lock().expect("gate");
        assert_eq!((gate.issued, gate.returned), (40, 40));
        assert_eq!((gate.holders, gate.refining_holders), (0, 0));
    }

    /// Waits (up to a minute) until the pool's waiting frames are `want` (class, refining).
    fn await_waiting(pool: &TargetPool, want: &[(u8, bool)]) {
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
        loop {
            let now: Vec<(u8, bool)> = {
                let gate = pool.gate.lock().expect("gate");
                gate.waiting.iter().map(|&(c, _, r)| (c, r)).collect()
            };
            if now == want {
                return;
            }
            assert!(
                std::time::Instant::now() < deadline,
                "waiting {now:?}, not {want:?}"
            );
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
    }

    /// A turn for a frame someone waits on, nothing watched.
    fn turn_now(pool: &TargetPool) -> Turn {
        pool.enter(false, &Interrupt::default())
            .expect("no interrupt")
    }

    /// A frame (`refining` or not, with a refinement's `patience`) that asks for a turn on a
    /// thread of its own and says `name` once it has it.
    fn waiter(
        pool: &std::sync::Arc<TargetPool>,
        tx: &std::sync::mpsc::Sender<&'static str>,
        (name, refining, patience): (&'static str, bool, std::time::Duration),
    ) -> std::thread::JoinHandle<Turn> {
        let (pool, tx) = (pool.clone(), tx.clone());
        std::thread::spawn(move || {
            let turn = pool
                .enter_with_patience(refining, patience, &Interrupt::default())
                .expect("no interrupt");
            tx.send(name).expect("send");
            turn
        })
    }

    const HOUR: std::time::Duration = std::time::Duration::from_secs(3600);

    /// A frame someone waits on (a shot, a needle step) goes in before a refinement that came
    /// first, and a refinement never takes the last turn.
    #[test]
    fn frames_someone_waits_on_go_before_refinements_and_keep_a_turn() {
        let pool = std::sync::Arc::new(TargetPool::default());
        let (a, b) = (turn_now(&pool), turn_now(&pool));
        let (tx, rx) = std::sync::mpsc::channel();
        let refinement = waiter(&pool, &tx, ("refinement", true, HOUR));
        await_waiting(&pool, &[(1, true)]);
        let shot = waiter(&pool, &tx, ("shot", false, HOUR));
        await_waiting(&pool, &[(0, false), (1, true)]);
        pool.leave(a);
        assert_eq!(rx.recv().expect("first in"), "shot");
        let shot = shot.join().expect("shot thread");
        pool.leave(b);
        assert_eq!(rx.recv().expect("second in"), "refinement");
        let refinement = refinement.join().expect("refinement thread");
        // One refinement holds targets and one shot: a second refinement waits although a
        // turn is free once the shot ends, and a shot behind it does not.
        pool.leave(shot);
        let second = waiter(&pool, &tx, ("second refinement", true, HOUR));
        await_waiting(&pool, &[(1, true)]);
        let late_shot = turn_now(&pool);
        assert!(
            rx.try_recv().is_err(),
            "no second refinement beside the first"
        );
        pool.leave(late_shot);
        pool.leave(refinement);
        assert_eq!(rx.recv().expect("third in"), "second refinement");
        pool.leave(second.join().expect("second refinement thread"));
        let gate = pool.gate.lock().expect("gate");
        assert_eq!((gate.holders, gate.issued, gate.returned), (0, 6, 6));
    }

    /// A refinement that has waited its patience queues with the other frames in arrival order:
    /// a server kept busy by shots still shows it.
    #[test]
    fn a_refinement_that_waited_its_patience_goes_in_arrival_order() {
        let pool = std::sync::Arc::new(TargetPool::default());
        let (a, b) = (turn_now(&pool), turn_now(&pool));
        let (tx, rx) = std::sync::mpsc::channel();
        let patience = std::time::Duration::from_millis(20);
        let refinement = waiter(&pool, &tx, ("refinement", true, patience));
        // Once it has waited 20 ms it counts as a frame someone waits on, ahead of a later shot.
        await_waiting(&pool, &[(0, true)]);
        let shot = waiter(&pool, &tx, ("shot", false, HOUR));
        await_waiting(&pool, &[(0, true), (0, false)]);
        pool.leave(a);
        assert_eq!(rx.recv().expect("first in"), "refinement");
        pool.leave(b);
        assert_eq!(rx.recv().expect("second in"), "shot");
        pool.leave(refinement.join().expect("refinement thread"));
        pool.leave(shot.join().expect("shot thread"));
    }

    /// A refinement waiting for targets gives its place up once newer input makes it obsolete
    /// (the flag its thread watches), or once any command waits for its session (the input
    /// flag), and the frames behind it go on.
    #[test]
    fn a_waiting_refinement_stops_when_its_input_is_superseded_or_a_command_waits() {
        use std::sync::atomic::{AtomicBool, Ordering};
        for input in [false, true] {
            let pool = std::sync::Arc::new(TargetPool::default());
            let (a, b) = (turn_now(&pool), turn_now(&pool));
            let flag = std::sync::Arc::new(AtomicBool::new(false));
            let refinement = {
                let (pool, flag) = (pool.clone(), flag.clone());
                std::thread::spawn(move || {
                    let _watching = if input {
                        crate::interrupt::watching_input(&flag)
                    } else {
                        crate::interrupt::watching(&flag)
                    };
                    pool.enter_with_patience(true, HOUR, &Interrupt::of_this_thread())
                })
            };
            await_waiting(&pool, &[(1, true)]);
            flag.store(true, Ordering::SeqCst);
            assert_eq!(refinement.join().expect("refinement thread"), None);
            await_waiting(&pool, &[]);
            pool.leave(a);
            pool.leave(b);
            let gate = pool.gate.lock().expect("gate");
            assert_eq!((gate.holders, gate.issued, gate.returned), (0, 3, 2));
        }
    }
}
