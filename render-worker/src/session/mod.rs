//! Live training sessions: one station's state on one simulation clock, driven by typed,
//! sequenced commands, rendered on demand, snapshotted and replayed exactly.
//!
//! # Pieces
//! - [`Session`] ([`machine`]): the state machine. It owns the shared [`world::World`] (anatomy, station, clock,
//!   needle, injections) and one [`modalities::Modality`] per imaging modality the station lists,
//!   built by the [`modalities::ModalityFactory`]. Commands ([`command::Command`]) are validated
//!   once, routed by class, applied, acknowledged and logged. A station without ultrasound never
//!   builds ultrasound resources; a view is rendered only when its content changed and it is
//!   visible.
//! - [`modalities`]: the modality seam and one folder per modality ([`modalities::fluoro`]: the
//!   C-arm over a [`modalities::fluoro::FluoroBackend`], the CPU reference or the GPU renderer).
//! - [`devices`]: the renderers of a device, chosen once ([`devices::Backends`]).
//! - [`anatomy`]: targets, sides and structure geometry that scorers of every modality share.
//! - [`hands`]: needle handling (skin marker, puncture, hub tilt, insertion force, the
//!   loss-of-resistance syringe, aspiration) and its tallies.
//! - [`scoring`]: needle measurements, the rubric result and the reproducibility record.
//! - [`image`] and [`frame`]: the modality-neutral grey image and its JPEG frame with a small
//!   binary header.
//! - [`host`]: [`host::SessionHost`], the in-process API (one actor thread per session, which
//!   sleeps while no input arrives), and [`protocol`]: the websocket protocol over any
//!   `Sink`/`Stream` of messages, with latest-frame-wins delivery.
//!
//! # Determinism
//! Everything a session does is a function of its initial snapshot and its log: the clock only
//! advances with accepted commands (each log entry carries its simulation time; `tick` moves it
//! with nothing else), modalities step their time-dependent models only on those advances, noise
//! seeds are derived from the session seed and the image number, and sim-core's models are
//! deterministic. [`Session::restore`] from any snapshot plus the log therefore reaches the same
//! state bytes and, with the same renderer, the same frame bytes. Scores never depend on
//! rendering.
//!
//! ```
//! # use std::sync::Arc;
//! # use render_worker::session::*;
//! # fn demo(env: SessionEnv) {
//! let mut s = Session::new(env, SessionConfig::default());
//! let ack = s.apply(Envelope { seq: 1, command: Command::Shot }, 0).unwrap();
//! assert_eq!(ack.seq, 1);
//! let frames = s.render_dirty(&[ViewId::FLUOROSCOPY].into()).unwrap();
//! assert_eq!(frames.len(), 1);
//! # }
//! ```

pub mod anatomy;
pub mod calibration;
pub mod command;
pub mod config;
pub mod demo;
pub mod devices;
pub mod error;
pub mod frame;
pub mod hands;
pub mod host;
pub mod http;
pub mod image;
pub mod loader;
pub mod machine;
pub mod modalities;
pub mod offer;
pub mod preparation;
pub mod protocol;
pub mod region;
pub mod reveal;
pub mod scoring;
pub mod world;

pub use command::{
    Agent, Command, CommandClass, CommandError, CommandSpec, Engagement, Envelope, ErrorCode,
    LogEntry, ModalityCommand, SyringeAction,
};
pub use config::SessionConfig;
pub use devices::Backends;
pub use error::SessionError;
pub use frame::EncodedFrame;
pub use host::{HostConfig, HostError, SessionHandle, SessionHost, SessionInfo};
pub use image::{ViewId, ViewImage};
pub use machine::{
    Ack, RenderedView, Replay, SNAPSHOT_FORMAT, Session, SessionEnv, SessionSnapshot,
    region_fingerprint, replay_attempt,
};
pub use modalities::fluoro::{
    BackendProfile, CpuFluoroBackend, FluoroBackend, FluoroConfig, FluoroModality, FluoroRenderer,
    GpuFluoroBackend,
};
pub use modalities::{
    FluidDelivery, Modality, ModalityContext, ModalityError, ModalityFactory, ModalitySpec,
    RegistrationError, Renderers,
};
pub use offer::{CommandInfo, ProtocolInfo, ViewInfo};
pub use region::Region;
pub use scoring::{ReproducibilityRecord, SubmitResult};
pub use sim_core::hash::sha256_hex;
pub use world::{Injection, NeedleInstrument, StationContext, World, WorldChange};
