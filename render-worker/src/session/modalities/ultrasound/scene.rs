//! What one B-mode frame depends on besides the tissue, and the needle as the scanner sees it.

use serde::{Deserialize, Serialize};
use sim_core::ultrasound::{
    NeedleShaft, NeedleView, ProbeKind, ProbePose, Sampling, ScanGeometry, Settings, needle_view,
};

use crate::session::world::World;

/// Everything one B-mode frame depends on besides the tissue.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ScanScene {
    /// The array.
    pub probe: ProbeKind,
    /// Where it is.
    pub pose: ProbePose,
    /// Its controls.
    pub settings: Settings,
    /// The needle shaft in the body, if any.
    pub needle: Option<NeedleShaft>,
}

/// The needle as the scanner sees it: a straight shaft from the hub to the tip, when buried.
pub fn needle_shaft(world: &World) -> Option<NeedleShaft> {
    let n = world.needle.as_ref()?;
    if n.state.buried_mm() <= 0.0 {
        return None;
    }
    let line = n.state.shaft_polyline(2.0);
    let hub = *line.first()?;
    let tip = n.state.tip_mm();
    (hub != tip).then_some(NeedleShaft {
        hub_mm: hub,
        tip_mm: tip,
        diameter_mm: n.state.profile.outer_diameter_mm,
    })
}

/// What a frame of `scene` shows of its needle.
pub fn scene_needle_view(scene: &ScanScene) -> Option<NeedleView> {
    let n = scene.needle?;
    let spec = scene.probe.spec();
    let frame = scene.pose.frame().ok()?;
    let sampling = Sampling::for_settings(&spec, &scene.settings);
    let geo = ScanGeometry {
        spec,
        frame,
        lines: sampling.lines,
        depth_mm: scene.settings.depth_mm,
    };
    Some(needle_view(&n, &geo, &scene.settings.beam(&spec)))
}
