//! The debrief's reveal view: where the needle really went. The structures its tract passed
//! through, in the order the tip entered them, and each one's outline in the last fluoroscopy
//! image the learner saw ([`sim_core::fluoro::footprint`] over the region's meshes), for a
//! client to draw over that image. Only for a submitted attempt: this is what the session never
//! tells a learner while it runs.

use serde::{Deserialize, Serialize};
use sim_core::fluoro::footprint::{Run, footprint, outline_runs};

use super::hands::point_at_arc;
use super::machine::Session;

/// Step along the tract when looking for the structures it crosses, mm. Simulator choice: a
/// quarter of the thinnest layer the phantoms mesh (the 1 mm cortex), so none is stepped over.
pub const TRACT_STEP_MM: f64 = 0.25;

/// A structure whose footprint covers more than this share of the image is an envelope (the
/// skin, the deep soft tissue): its outline is the image's edge and shows nothing, so it is
/// named but not outlined. Simulator choice.
pub const ENVELOPE_SHARE: f64 = 0.5;

/// One structure's outline in the image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Outline {
    /// Structure name.
    pub structure: String,
    /// Outline pixels as runs `[row, first column, last column]`, top to bottom.
    pub runs: Vec<Run>,
}

/// Where the needle went.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Reveal {
    /// Image width, pixels (the last fluoroscopy image's).
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Structures the tract passed through, in the order the tip entered them.
    pub touched: Vec<String>,
    /// The touched structures' outlines (envelopes left out, see [`ENVELOPE_SHARE`]).
    pub outlines: Vec<Outline>,
}

/// The reveal of a session's current needle in its last fluoroscopy image (nothing touched
/// when there is no needle); `None` without an image.
pub fn reveal(session: &Session) -> Option<Reveal> {
    let projection = session.displayed_projection()?;
    let [width, height] = projection.detector_pixels;
    let Some(needle) = session.world().needle.as_ref() else {
        return Some(Reveal {
            width,
            height,
            touched: Vec::new(),
            outlines: Vec::new(),
        });
    };
    let region = &session.env().region;
    let depth = needle.state.buried_mm();
    let entry = needle.state.entry.position_mm;
    let steps = (depth / TRACT_STEP_MM).ceil() as usize;
    let mut touched: Vec<String> = Vec::new();
    for k in 1..=steps {
        let s = (k as f64 * TRACT_STEP_MM).min(depth);
        let p = point_at_arc(&needle.state.tract, entry, s);
        if let Some(name) = region.structure_at(p.to_array())
            && !touched.iter().any(|t| t == name)
        {
            touched.push(name.to_string());
        }
    }
    let pixels = f64::from(width) * f64::from(height);
    let outlines = touched
        .iter()
        .filter_map(|name| {
            let entry = region.entry(name)?;
            let tris = region.scene.entries()[entry].bvh.triangles_mm();
            let mask = footprint(tris, &projection);
            let covered = mask.iter().filter(|c| **c).count() as f64;
            (covered > 0.0 && covered <= ENVELOPE_SHARE * pixels).then(|| Outline {
                structure: name.clone(),
                runs: outline_runs(&mask, width, height),
            })
        })
        .collect();
    Some(Reveal {
        width,
        height,
        touched,
        outlines,
    })
}
