//! The contrast modality: fluid injected through the needle (contrast, diluted contrast, saline,
//! local anaesthetic) spreads in the spinal compartments by `sim_core::contrast`, is published
//! as an iodine field that the fluoroscopy modality renders, and is scored by pattern
//! ([`scorers`]).
//!
//! # Time, replay and cost
//! The transport model steps on a fixed grid of simulated time, [`QUANTUM_MS`] apart, counted
//! from the session's start: every call brings the model to the last quantum at or before the
//! session clock, one quantum per `advance` call of the model. So the model's state at a quantum
//! depends only on the events (start, stop, puncture) and the quanta they happened at, never on
//! how the clock was chunked by commands (`tick`s, rejected commands, a restore from a snapshot
//! in the middle): replay is bit-identical. An event takes effect at the quantum it falls in.
//!
//! The model steps only while fluid moves: while an injection runs and for [`SETTLE_MS`] after
//! it ends (pressure relaxes, vascular contrast washes out); otherwise the field is frozen and an
//! idle session costs nothing. The model itself is built at the first injection or dural
//! puncture, so a station that lists contrast but never injects builds nothing.
//!
//! # Where the fluid goes
//! The outlet is the needle's: its tip and shaft direction, a Tuohy or a spinal (Quincke)
//! opening by the instrument's kind. A dural puncture (the tip inside the `dural_sac`
//! structure after a needle move, as `dural_puncture_bool` measures, and in the CSF of the
//! transport grid, past the subdural layer) opens the
//! epidural-subdural-intrathecal faces along the last [`PUNCTURE_DEPTH_MM`] of the needle's path
//! for good.
//!
//! # Grid
//! The phantom's domains are painted on a crop of [`CROP_HALF_MM`] around the station's primary
//! target at [`CELL_MM`] cells (the canal, the foramina and the paraspinal muscles at the
//! station's levels), built once per process for each phantom and crop. Another region with an
//! `epidural_space` structure (the real-CT region and its authored canal contents) is painted
//! from its structure meshes on the same crop ([`region_grid`]), its levels from its
//! `L1`..`L5_body_centre` landmarks; it has no added radicular vessels or epidural veins.

pub mod scorers;

use std::sync::{Arc, Mutex};

use serde::{Deserialize, Serialize};
use sim_core::anatomy::phantom::PhantomParams;
use sim_core::contrast::domains::{
    LevelSpan, crop_grid, domain_of, levels_from_centres, phantom_grid, phantom_levels,
    with_subdural_layer,
};
use sim_core::contrast::{
    Agent as ModelAgent, ContrastError, ContrastGrid, ContrastModel, Domain,
    Injection as ModelInjection, Ledger, ModelConfig, NeedleOutlet,
};
use sim_core::fluoro::IodineField;
use sim_core::rubric::Measurements;

use super::modality::{FluidDelivery, Modality, ModalityContext, ModalityError, ModalitySpec};
use crate::session::anatomy::primary_target;
use crate::session::command::{Agent, Command, CommandError, CommandSpec, Engagement, ErrorCode};
use crate::session::image::{ViewId, ViewImage};
use crate::session::region::Region;
use crate::session::world::{StationContext, World, WorldChange};

/// Length of one model time step of the session, ms. Simulator choice: 10 field updates a second
/// is smooth live fluoroscopy (pulsed fluoroscopy runs at 7.5 to 15 pulses a second), and the
/// model's own substeps are shorter than this during an injection anyway.
pub const QUANTUM_MS: u64 = 100;
/// How long the model keeps stepping after an injection ends, ms. Simulator choice: the outlet
/// pressure relaxes within about a second in the model, and vascular washout (clearance of the
/// order of 1 per second) has removed most vascular contrast after two seconds; later changes
/// (epidural clearance over tens of minutes) are too slow to see during a session.
pub const SETTLE_MS: u64 = 2000;
/// Transport cell size, mm. Simulator choice: the 1 mm cells of sim-core's contrast tests.
pub const CELL_MM: f64 = 1.0;
/// Half extent of the transport crop around the station's primary target, mm (x, y, z).
/// Simulator choice: 26 mm laterally reaches from a foraminal target past the midline canal;
/// 24 mm antero-posteriorly covers the canal, the foramen and the paraspinal muscle behind the
/// lamina; 26 mm axially spans the target's level and half of each neighbour.
pub const CROP_HALF_MM: [f64; 3] = [26.0, 24.0, 26.0];
/// Needle path behind the tip that a dural puncture opens, mm. Simulator choice: from a tip in
/// the sac back through the subdural layer, the dura and the posterior epidural space.
pub const PUNCTURE_DEPTH_MM: f64 = 20.0;

/// A needle opening, as recorded in the state (model frame, mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Outlet {
    /// Tip.
    pub tip_mm: [f64; 3],
    /// Shaft direction at the tip.
    pub direction: [f64; 3],
    /// Opening length along the shaft, mm.
    pub opening_mm: f64,
    /// Outer diameter, mm.
    pub outer_diameter_mm: f64,
}

impl Outlet {
    fn model(self) -> NeedleOutlet {
        NeedleOutlet {
            tip_mm: self.tip_mm,
            direction: self.direction,
            opening_mm: self.opening_mm,
            outer_diameter_mm: self.outer_diameter_mm,
        }
    }

    /// The outlet of the session's needle: a Tuohy opening for a `tuohy-needle` from the tray,
    /// a spinal (Quincke) one otherwise; `None` when no needle is in the body.
    pub fn of_needle(world: &World) -> Option<Outlet> {
        let n = world.needle.as_ref()?;
        if n.state.buried_mm() <= 0.0 {
            return None;
        }
        let kind = world
            .station
            .station
            .instruments
            .iter()
            .find(|i| i.id == n.instrument)
            .map(|i| i.kind.as_str());
        let tip = n.state.tip_mm().to_array();
        let dir = n.state.outlet().axis.to_array();
        let o = if kind == Some("tuohy-needle") {
            NeedleOutlet::tuohy(tip, dir)
        } else {
            NeedleOutlet::spinal(tip, dir)
        };
        Some(Outlet {
            tip_mm: o.tip_mm,
            direction: o.direction,
            opening_mm: o.opening_mm,
            outer_diameter_mm: o.outer_diameter_mm,
        })
    }
}

/// What changed the model (besides time).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Event {
    /// An injection began (replacing one under way).
    Start {
        /// Through this opening.
        outlet: Outlet,
        /// What the syringe held.
        agent: Agent,
        /// Volume, mL.
        volume_ml: f64,
        /// Rate, mL/s.
        rate_ml_s: f64,
    },
    /// The plunger was released.
    Stop,
    /// A dural puncture along the needle's last `depth_mm`.
    Puncture {
        /// The needle's opening when the tip was in the sac.
        outlet: Outlet,
        /// Path length opened behind the tip, mm.
        depth_mm: f64,
    },
}

/// An event and the quantum it took effect at.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TimedEvent {
    /// Quantum index (session time / [`QUANTUM_MS`]).
    pub quantum: u64,
    /// The event.
    pub event: Event,
}

/// Serializable contrast state: the events; the model is a function of them (see the module
/// docs), rebuilt by [`Modality::restore`].
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ContrastState {
    /// Every event, oldest first.
    pub events: Vec<TimedEvent>,
}

/// The transport model in memory.
struct Live {
    model: ContrastModel,
    /// The model stands at this quantum.
    quantum: u64,
    /// Quanta left to step after the last injection ended.
    settle_left: u64,
    /// Bumped on every change of the model (a step or an event).
    version: u64,
    field: Option<(u64, Arc<IodineField>)>,
    /// The ledger at the start of each injection (for per-injection patterns).
    starts: Vec<Ledger>,
}

impl Live {
    /// Steps quantum by quantum to `target` while fluid moves; jumps when idle.
    fn step_to(&mut self, target: u64) -> Result<(), ContrastError> {
        while self.quantum < target {
            if self.model.injecting() {
                self.settle_left = SETTLE_MS / QUANTUM_MS;
            } else if self.settle_left == 0 {
                self.quantum = target;
                break;
            } else {
                self.settle_left -= 1;
            }
            self.model.advance(QUANTUM_MS as f64 / 1000.0)?;
            self.quantum += 1;
            self.version += 1;
        }
        Ok(())
    }

    fn apply(&mut self, event: &Event) -> Result<(), ContrastError> {
        match event {
            Event::Start {
                outlet,
                agent,
                volume_ml,
                rate_ml_s,
            } => {
                let agent = match agent {
                    Agent::Saline => ModelAgent::Saline,
                    Agent::LocalAnaesthetic => ModelAgent::LocalAnaesthetic,
                    Agent::Contrast | Agent::DilutedContrast { .. } => ModelAgent::Contrast {
                        stock_fraction: agent.stock_fraction(),
                    },
                };
                let injection = ModelInjection {
                    agent,
                    volume_ml: *volume_ml,
                    rate_ml_s: *rate_ml_s,
                };
                self.model.start_injection(&outlet.model(), &injection)?;
                self.starts.push(*self.model.ledger());
            }
            Event::Stop => {
                if self.model.injecting() {
                    self.model.stop_injection();
                    self.settle_left = SETTLE_MS / QUANTUM_MS;
                }
            }
            Event::Puncture { outlet, depth_mm } => {
                self.model.puncture(&outlet.model(), *depth_mm)?;
            }
        }
        self.version += 1;
        Ok(())
    }

    fn field(&mut self) -> Arc<IodineField> {
        match &self.field {
            Some((v, f)) if *v == self.version => Arc::clone(f),
            _ => {
                let f = Arc::new(IodineField::new(self.model.density_stock()));
                self.field = Some((self.version, Arc::clone(&f)));
                f
            }
        }
    }
}

/// What a station's transport grid is painted from.
#[derive(Debug, Clone)]
enum SiteSource {
    /// The procedural phantom's solids (a pure function of its parameters).
    Phantom(Box<PhantomParams>),
    /// The analytic demo region: one uniform epidural box.
    Demo,
    /// Any other region with an `epidural_space` structure (an imported CT with authored canal
    /// contents): its structure meshes, by [`region_grid`].
    Region(Arc<Region>),
}

/// The crop and grid of a station (see the module docs).
#[derive(Debug, Clone)]
struct Site {
    source: SiteSource,
    crop_lo_mm: [f64; 3],
    crop_hi_mm: [f64; 3],
    levels: Vec<LevelSpan>,
}

/// Transport grids already built in this process, by phantom or region and crop (a handful at
/// most: one per station).
static GRIDS: Mutex<Vec<(String, Arc<ContrastGrid>)>> = Mutex::new(Vec::new());

impl Site {
    fn grid(&self) -> Arc<ContrastGrid> {
        let source_key = match &self.source {
            SiteSource::Phantom(p) => serde_json::to_string(p).unwrap_or_default(),
            SiteSource::Demo => "demo".to_string(),
            SiteSource::Region(r) => format!("{}|{:?}", r.name, r.asset_sha256),
        };
        let key = format!("{source_key}|{:?}|{:?}", self.crop_lo_mm, self.crop_hi_mm);
        let mut grids = GRIDS.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, g)) = grids.iter().find(|(k, _)| *k == key) {
            return Arc::clone(g);
        }
        let crop = crop_grid(self.crop_lo_mm, self.crop_hi_mm, CELL_MM);
        let g = Arc::new(match &self.source {
            SiteSource::Phantom(p) => phantom_grid(p, crop),
            SiteSource::Demo => {
                ContrastGrid::uniform(crop, Domain::Epidural, Domain::Epidural.default_props())
            }
            SiteSource::Region(r) => region_grid(r, crop),
        });
        if grids.len() >= 8 {
            grids.remove(0);
        }
        grids.push((key, Arc::clone(&g)));
        g
    }
}

/// The transport grid of a region from its structure meshes: each cell takes the domain
/// ([`domain_of`]) of the structure that owns its centre ([`Region::structure_at`]: the last in
/// painting order whose mesh contains it), solid outside the body; the sac's outer cell layer
/// against anything inside the body is subdural. Used for regions that are not the phantom
/// (an imported CT's authored `epidural_space` and `dural_sac`, its vessel and muscle masks).
pub fn region_grid(region: &Region, grid: sim_core::volume::VolumeGrid) -> ContrastGrid {
    let entries = region.scene.entries();
    let owner: Vec<Option<usize>> = (0..grid.len())
        .map(|c| {
            let [i, j, k] = grid.ijk(c);
            region
                .structure_at(grid.voxel_center_mm(i, j, k))
                .and_then(|name| region.entry(name))
        })
        .collect();
    let domain = owner
        .iter()
        .map(|o| {
            o.and_then(|e| match entries[e].material {
                sim_core::fluoro::FluoroMaterial::Tissue(m) => domain_of(&entries[e].name, m),
                sim_core::fluoro::FluoroMaterial::Steel => None,
            })
        })
        .collect();
    with_subdural_layer(grid, domain, |n| owner[n].is_some())
}

/// The contrast modality.
pub struct ContrastModality {
    state: ContrastState,
    site: Option<Site>,
    live: Option<Live>,
    /// The injection the last command started, until the session books it.
    delivered: Option<FluidDelivery>,
}

impl std::fmt::Debug for ContrastModality {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ContrastModality")
            .field("events", &self.state.events.len())
            .field("built", &self.live.is_some())
            .finish()
    }
}

/// Half extent of the analytic demo region's transport box around the demo target, mm (x, y,
/// z). Simulator choice: narrow across (whole-process tests inject in milliseconds) and long
/// along the demo's posterior needle approach (y), so a needle advanced part of the way from
/// the skin is inside it.
pub const DEMO_HALF_MM: [f64; 3] = [8.0, 60.0, 8.0];

/// The crop of a phantom region, or of another region with an `epidural_space` structure,
/// around the station's primary target; for the analytic demo region (boxes of known geometry,
/// no phantom), one uniform epidural box of [`DEMO_HALF_MM`] around the target, so
/// whole-process tests can inject and see contrast; no grid elsewhere.
fn site(region: &Arc<Region>, station: &StationContext) -> Option<Site> {
    let c = primary_target(station)
        .or_else(|| region.landmarks.get("L4_body_centre").copied())
        .unwrap_or([0.0; 3]);
    let (source, half, levels) = match &region.phantom {
        Some(p) => (
            SiteSource::Phantom(Box::new(p.clone())),
            CROP_HALF_MM,
            phantom_levels(p),
        ),
        None if region.name == crate::session::demo::DEMO_REGION_NAME => {
            (SiteSource::Demo, DEMO_HALF_MM, Vec::new())
        }
        None if region.entry("epidural_space").is_some() => {
            let centres: Vec<(String, f64)> = ["L1", "L2", "L3", "L4", "L5"]
                .iter()
                .filter_map(|n| {
                    region
                        .landmarks
                        .get(&format!("{n}_body_centre"))
                        .map(|p| (n.to_string(), p[2]))
                })
                .collect();
            (
                SiteSource::Region(Arc::clone(region)),
                CROP_HALF_MM,
                levels_from_centres(&centres),
            )
        }
        None => return None,
    };
    Some(Site {
        source,
        crop_lo_mm: std::array::from_fn(|a| c[a] - half[a]),
        crop_hi_mm: std::array::from_fn(|a| c[a] + half[a]),
        levels,
    })
}

/// The transport grid a contrast session of `station` in `region` uses (`None` outside a
/// phantom, a region with an `epidural_space` structure, or the demo region); built once per
/// process.
pub fn transport_grid(region: &Arc<Region>, station: &StationContext) -> Option<Arc<ContrastGrid>> {
    site(region, station).map(|s| s.grid())
}

/// The factory's builder: the crop around the station's primary target in a phantom region
/// (nothing is built until the first injection).
pub fn build(ctx: &ModalityContext<'_>) -> Box<dyn Modality> {
    Box::new(ContrastModality {
        state: ContrastState::default(),
        site: site(ctx.region, ctx.station),
        live: None,
        delivered: None,
    })
}

fn quantum_of(t_ms: u64) -> u64 {
    t_ms / QUANTUM_MS
}

/// A refusal of the transport model as a command error naming the field. A refusal of the
/// needle's outlet names the needle and says why without the model's words, which give the
/// tip's position: a learner's browser gets command errors as they are.
fn refused(e: &ContrastError) -> CommandError {
    let field = match e {
        ContrastError::OutOfRange { field, .. } | ContrastError::NotFinite { field, .. } => {
            match *field {
                "injection.volume_ml" => "command.volume_ml",
                "injection.rate_ml_s" => "command.rate_ml_per_s",
                f if f.starts_with("outlet.") => "needle",
                f => f,
            }
        }
        _ => "needle",
    };
    if field == "needle" {
        return CommandError::field(
            field,
            ErrorCode::Invalid,
            "the needle's outlet is outside the part of the body the contrast model covers: \
             nothing can be injected there",
        );
    }
    CommandError::field(field, ErrorCode::Invalid, e.to_string())
}

impl ContrastModality {
    /// The transport model, once built.
    pub fn model(&self) -> Option<&ContrastModel> {
        self.live.as_ref().map(|l| &l.model)
    }

    /// The vertebral levels spread is counted over.
    pub fn levels(&self) -> &[LevelSpan] {
        self.site.as_ref().map_or(&[], |s| &s.levels)
    }

    fn ensure_live(&mut self) -> Option<&mut Live> {
        if self.live.is_none() {
            let site = self.site.as_ref()?;
            let grid = site.grid();
            self.live = Some(Live {
                model: ContrastModel::new((*grid).clone(), ModelConfig::default()),
                quantum: 0,
                settle_left: 0,
                version: 0,
                field: None,
                starts: Vec::new(),
            });
        }
        self.live.as_mut()
    }

    /// Brings the model to the quantum of `t_ms`.
    fn sync(&mut self, t_ms: u64) {
        if let Some(live) = &mut self.live {
            // The model refuses only a step length outside (0, 3600] s; a quantum never is.
            let _ = live.step_to(quantum_of(t_ms));
        }
    }

    /// Applies `event` at `t_ms` and records it; the model is built if needed.
    fn record(&mut self, t_ms: u64, event: Event) -> Result<(), CommandError> {
        self.sync(t_ms);
        let Some(live) = self.ensure_live() else {
            return Err(CommandError::field(
                "command.type",
                ErrorCode::ModalityUnavailable,
                "contrast transport needs the phantom or a region with an epidural_space \
                 structure; this region has neither",
            ));
        };
        live.step_to(quantum_of(t_ms)).map_err(|e| refused(&e))?;
        live.apply(&event).map_err(|e| refused(&e))?;
        self.state.events.push(TimedEvent {
            quantum: quantum_of(t_ms),
            event,
        });
        Ok(())
    }

    /// Volume still to inject, mL.
    pub fn remaining_ml(&self) -> f64 {
        self.model().map_or(0.0, ContrastModel::remaining_ml)
    }

    fn outcome(&self) -> serde_json::Value {
        let l = self.model().map(|m| *m.ledger()).unwrap_or_default();
        serde_json::json!({
            "injecting": self.model().is_some_and(ContrastModel::injecting),
            "injected_ml": l.fluid_injected_mm3 / 1000.0,
            "remaining_ml": self.remaining_ml(),
            "iodine_injected_ml": l.injected / 1000.0,
        })
    }
}

/// What the contrast modality offers: injections through the needle; no view of its own (the
/// fluoroscopy modality images its iodine).
pub static SPEC: ModalitySpec = ModalitySpec {
    name: "contrast",
    label: "contrast injection",
    views: &[],
    commands: &[
        CommandSpec::new("inject", Some(Engagement::Injection)),
        CommandSpec::new("inject_stop", None),
    ],
    constants: &[
        ("tick_ms", QUANTUM_MS as f64),
        ("settle_ms", SETTLE_MS as f64),
    ],
};

impl Modality for ContrastModality {
    fn spec(&self) -> &'static ModalitySpec {
        &SPEC
    }

    fn take_fluid(&mut self) -> Option<FluidDelivery> {
        self.delivered.take()
    }

    fn apply(
        &mut self,
        command: &Command,
        world: &World,
    ) -> Result<serde_json::Value, CommandError> {
        match *command {
            Command::Inject {
                agent,
                volume_ml,
                rate_ml_per_s,
            } => {
                if world.hands.syringe.is_some() {
                    return Err(CommandError::field(
                        "command.type",
                        ErrorCode::State,
                        "the loss-of-resistance syringe is on the needle: detach it before injecting",
                    ));
                }
                let Some(outlet) = Outlet::of_needle(world) else {
                    return Err(CommandError::field(
                        "command.type",
                        ErrorCode::State,
                        "no needle in the body: place and advance a needle before injecting",
                    ));
                };
                self.record(
                    world.clock_ms,
                    Event::Start {
                        outlet,
                        agent,
                        volume_ml,
                        rate_ml_s: rate_ml_per_s,
                    },
                )?;
                self.delivered = Some(FluidDelivery {
                    agent,
                    volume_ml,
                    rate_ml_per_s,
                });
            }
            Command::InjectStop => {
                if self.model().is_some_and(ContrastModel::injecting) {
                    self.record(world.clock_ms, Event::Stop)?;
                }
            }
            ref other => {
                return Err(CommandError::field(
                    "command.type",
                    ErrorCode::ModalityUnavailable,
                    format!("contrast does not handle {}", other.name()),
                ));
            }
        }
        Ok(self.outcome())
    }

    fn advance(&mut self, _from_ms: u64, world: &World) {
        self.sync(world.clock_ms);
    }

    fn world_changed(&mut self, change: &WorldChange, world: &World) {
        if *change != WorldChange::Needle {
            return;
        }
        let Some(n) = &world.needle else {
            return;
        };
        let tip = n.state.tip_mm().to_array();
        if world.region.contains("dural_sac", tip) != Some(true) {
            return;
        }
        // Through the arachnoid into the CSF: a tip in the subdural layer (inside the dura,
        // outside the arachnoid) has opened nothing yet.
        let Some(grid) = self.site.as_ref().map(Site::grid) else {
            return;
        };
        if grid.cell_at(tip).and_then(|c| grid.domain[c]) != Some(Domain::Intrathecal) {
            return;
        }
        let Some(outlet) = Outlet::of_needle(world) else {
            return;
        };
        let event = Event::Puncture {
            outlet,
            depth_mm: PUNCTURE_DEPTH_MM.min(n.state.buried_mm()),
        };
        if self.state.events.last().map(|e| &e.event) == Some(&event) {
            return;
        }
        // A tip outside the transport crop punctures nothing the model holds.
        let _ = self.record(world.clock_ms, event);
    }

    fn iodine(&mut self, world: &World) -> Option<(u64, Arc<IodineField>)> {
        self.sync(world.clock_ms);
        let live = self.live.as_mut()?;
        Some((live.version, live.field()))
    }

    fn injecting(&self) -> bool {
        self.model().is_some_and(ContrastModel::injecting)
    }

    fn dirty_views(&self) -> Vec<ViewId> {
        Vec::new()
    }

    fn render(&mut self, _: ViewId, _: &World) -> Result<Option<ViewImage>, ModalityError> {
        Ok(None)
    }

    fn measure(&self, _world: &World, out: &mut Measurements) {
        out.insert(
            "injected_volume_ml".into(),
            self.model()
                .map_or(0.0, |m| m.ledger().fluid_injected_mm3 / 1000.0),
        );
        // Without iodine injected there is nothing to see, so no pattern to score.
        if let Some(live) = self
            .live
            .as_ref()
            .filter(|l| l.model.ledger().injected > 0.0)
        {
            scorers::measure(&live.model, self.levels(), out);
            let tips: Vec<[f64; 3]> = self
                .state
                .events
                .iter()
                .filter_map(|e| match &e.event {
                    Event::Start { outlet, .. } => Some(outlet.tip_mm),
                    _ => None,
                })
                .collect();
            scorers::measure_injections(&live.model, &live.starts, &tips, out);
        }
    }

    fn record(&self) -> serde_json::Value {
        serde_json::json!({
            "quantum_ms": QUANTUM_MS,
            "settle_ms": SETTLE_MS,
            "cell_mm": CELL_MM,
            "crop_mm": self.site.as_ref().map(|s| [s.crop_lo_mm, s.crop_hi_mm]),
            "model": format!("{:?}", ModelConfig::default()),
        })
    }

    fn state(&self) -> serde_json::Value {
        serde_json::to_value(&self.state).unwrap_or(serde_json::Value::Null)
    }

    fn restore(&mut self, state: serde_json::Value) -> Result<(), ModalityError> {
        let state: ContrastState =
            serde_json::from_value(state).map_err(|e| ModalityError::State {
                modality: "contrast",
                message: e.to_string(),
            })?;
        self.live = None;
        self.state = ContrastState::default();
        for e in state.events {
            self.record(e.quantum * QUANTUM_MS, e.event)
                .map_err(|e| ModalityError::State {
                    modality: "contrast",
                    message: e.to_string(),
                })?;
        }
        Ok(())
    }
}
