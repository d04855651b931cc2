//! The lumbosacral anatomy as implicit solids: dimensions, placement and painting order.
//!
//! # Model frame
//! The platform's RAS frame (see `crate::fluoro::geometry`): millimetres, `x` = patient right,
//! `y` = anterior, `z` = cranial, right-handed; origin at the centre of the L3 vertebral body
//! (midway between its endplates, on its mid-sagittal plane). Left-sided structures have `x < 0`.
//! Inside the model, `s` is the side sign: [`LEFT`] = -1, [`RIGHT`] = +1.
//!
//! # Sources (adult morphometry; values rounded to the nearest 0.5 mm)
//! - Vertebral body endplate width and depth, posterior body height, canal width and depth,
//!   transverse-process span: approximate level means after Panjabi MM et al., "Human lumbar
//!   vertebrae: quantitative three-dimensional anatomy", Spine 1992;17(3):299-306, cross-checked
//!   against the lower-lumbar CT dimensions of Zhou SH et al., Eur Spine J 2000;9(3):242-248.
//! - Pedicle isthmus width, height and transverse angle: Zindrick MR et al., "Analysis of the
//!   morphometric characteristics of the thoracic and lumbar pedicles", Spine 1987;12(2):160-166.
//! - Segmental lordosis concentrated at L4-S1: Bernhardt M, Bridwell KH, Spine 1989;14(7):717-721;
//!   sacral slope about 40 degrees: Legaye J et al., Eur Spine J 1998;7(2):99-103.
//! - Facet-joint orientation growing more coronal caudally: Masharawi Y et al., Spine
//!   2004;29(16):1755-1763 (angles here are rounded approximations).
//! - Conus medullaris at the L1-L2 level and dural sac ending at S2: Saifuddin A et al., J Anat
//!   1998;193(2):273-279; Macdonald A et al., Clin Radiol 1999;54(3):163-166.
//! - Aortic bifurcation at L4 and IVC confluence at L4-L5: Chithriki M et al., Clin Anat
//!   2002;15(4):264-269.
//!
//! Everything else (soft-tissue thicknesses, muscle sections, the pelvis outline, roots' courses)
//! is **our assumption**, sized to typical adult CT appearance and said so where it is set.
//!
//! # Painting order
//! Structures are listed from back to front: a later structure overwrites an earlier one where
//! they overlap, so each voxel belongs to exactly one structure and the masks are disjoint.
//! Shells come out of this for free: the skin is the whole body envelope, overwritten inside by
//! the subcutaneous fat, overwritten by the deep soft tissue; a bone is painted whole as cortical
//! bone and then its inset as cancellous bone.

use glam::DVec3;

use super::sdf::Sdf;

mod canal;
mod dims;
mod frames;
mod landmarks;
mod parts;
mod sacrum;
mod soft_tissue;
mod spine;
mod vertebra;

pub use dims::{AnatomyParams, BODY_CENTRE_Y_MM, LEFT, RIGHT};
pub use frames::LevelFrame;
pub use landmarks::Landmark;
pub(crate) use parts::Parts;
pub use parts::PhantomPart;
use spine::Spine;

/// The whole phantom: parts in painting order plus landmarks.
#[derive(Debug, Clone)]
pub struct Anatomy {
    /// Solids in painting order (later overwrites earlier).
    pub parts: Vec<PhantomPart>,
    /// Named points.
    pub landmarks: Vec<Landmark>,
}

/// Pushes every bone (L1..L5, sacrum, left and right ilium) as its cortical solid followed by its
/// cancellous inset, each clipped to `under_skin` before the split so the cortex covers the cut
/// as well.
fn push_bones(parts: &mut Parts, spine: &Spine, p: &AnatomyParams, under_skin: &Sdf) {
    let gap = p.facet_gap_mm;
    let mut bones: Vec<(String, Sdf)> = spine
        .lumbar
        .iter()
        .enumerate()
        .map(|(i, vert)| {
            let bone = vertebra::lumbar_vertebra(spine, i, gap);
            (vert.dims.name.to_string(), bone)
        })
        .collect();
    let sacrum = sacrum::sacrum_with_processes(spine, gap);
    let ilia: Vec<(String, Sdf)> = [(LEFT, "left"), (RIGHT, "right")]
        .into_iter()
        .map(|(s, side)| {
            let ilium = sacrum::ilium(spine, &sacrum, s, p.si_gap_mm);
            (format!("ilium_{side}"), ilium)
        })
        .collect();
    bones.push(("sacrum".to_string(), sacrum));
    bones.extend(ilia);
    for (name, bone) in bones {
        parts.push_bone(&name, bone, under_skin, p.cortical_thickness_mm);
    }
}

/// Each lumbar level's frame and aiming points, then the S1 frame (see [`LevelFrame`]).
pub fn level_frames() -> Vec<LevelFrame> {
    frames::level_frames(&Spine::new())
}

impl Anatomy {
    /// Index of the structure that owns point `p` under the painting order (the last solid that
    /// contains it), or `None` outside the body. This is what the voxelizer computes at voxel
    /// centres, evaluated at an arbitrary point.
    pub fn structure_at(&self, p: [f64; 3]) -> Option<usize> {
        let p = DVec3::from(p);
        self.parts.iter().rposition(|part| part.sdf.eval(p) <= 0.0)
    }

    /// Index of a structure by name.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.parts.iter().position(|part| part.name == name)
    }

    /// Builds the default lumbosacral phantom: the body envelope, muscles, canal contents, nerve
    /// roots, vessels, discs and bones, in painting order (see the module docs), and the
    /// landmarks.
    pub fn new(p: &AnatomyParams) -> Anatomy {
        let spine = Spine::new();
        let mut parts = Parts::default();
        let under_skin = soft_tissue::push_envelope(&mut parts, p);
        soft_tissue::push_muscles(&mut parts, &spine, &under_skin);
        canal::push_canal_contents(&mut parts, &spine);
        canal::push_nerve_roots(&mut parts, &spine);
        soft_tissue::push_vessels(&mut parts, &spine.lumbar);
        vertebra::push_discs(&mut parts, &spine);
        push_bones(&mut parts, &spine, p, &under_skin);
        let mut anatomy = Anatomy {
            parts: parts.0,
            landmarks: landmarks::landmarks(&spine),
        };
        anatomy.fit_flavum_landmarks(&spine);
        anatomy.add_pedicle_floor_landmarks(&spine);
        anatomy
    }

    /// Adds `{L}_pedicle_6_oclock_{side}` for every lumbar pedicle: 1 mm below the pedicle's
    /// inferior cortex, found by a march down the vertebra's axis from the isthmus centre as the
    /// painted solids have it (0.05 mm steps). In the AP view it is the pedicle's 6 o'clock, the
    /// reference of a subpedicular (transforaminal) approach. A march that never leaves the
    /// vertebra's bone within 20 mm adds nothing.
    fn add_pedicle_floor_landmarks(&mut self, spine: &Spine) {
        let mut found = Vec::new();
        for v in &spine.lumbar {
            let name = &v.dims.name;
            for side in ["left", "right"] {
                let Some(centre) = self
                    .landmarks
                    .iter()
                    .find(|l| l.name == format!("{name}_pedicle_{side}"))
                    .map(|l| DVec3::from(l.position_mm))
                else {
                    continue;
                };
                let down = -v.up();
                let bone = |p: DVec3| {
                    self.structure_at(p.to_array()).is_some_and(|i| {
                        let n = self.parts[i].name.as_str();
                        n == format!("{name}_cortical") || n == format!("{name}_cancellous")
                    })
                };
                if let Some(t) = (0..=400)
                    .map(|k| f64::from(k) * 0.05)
                    .find(|t| !bone(centre + down * *t))
                {
                    found.push(Landmark {
                        name: format!("{name}_pedicle_6_oclock_{side}"),
                        position_mm: (centre + down * (t + 1.0)).to_array(),
                        description: "1 mm below the inferior cortex of the pedicle (its 6 \
                                      o'clock in the AP view)"
                            .to_string(),
                        inside_structure: None,
                    });
                }
            }
        }
        self.landmarks.extend(found);
    }

    /// Puts each lumbar interspace's interlaminar window centre in the middle of the ligamentum
    /// flavum on the midline, and its posterior epidural space 1.5 mm in front of the flavum, as
    /// the painted solids have them: a march backwards from the canal along the upper vertebra's
    /// anterior axis (0.05 mm steps). A landmark whose march finds no flavum keeps its placement.
    fn fit_flavum_landmarks(&mut self, spine: &Spine) {
        for pair in spine.lumbar.windows(2) {
            let (upper, lower) = (&pair[0], &pair[1]);
            let key = format!("{}_{}", upper.dims.name, lower.dims.name);
            let window_name = format!("{key}_interlaminar_window_centre");
            let Some(window) = self.landmarks.iter().find(|l| l.name == window_name) else {
                continue;
            };
            let back = -upper.frame.rotation.y_axis;
            let start = DVec3::from(window.position_mm) - back * 10.0;
            let owner = |p: DVec3| {
                self.structure_at(p.to_array())
                    .map(|i| self.parts[i].name.as_str())
            };
            let steps: Vec<f64> = (0..=600).map(|k| f64::from(k) * 0.05).collect();
            let Some(&enter) = steps
                .iter()
                .find(|t| owner(start + back * **t) == Some("ligamentum_flavum"))
            else {
                continue;
            };
            let leave = steps
                .iter()
                .copied()
                .find(|t| *t > enter && owner(start + back * *t) != Some("ligamentum_flavum"))
                .unwrap_or(enter);
            let centre = start + back * (0.5 * (enter + leave));
            let epidural = start + back * (enter - 1.5);
            let epidural_ok = owner(epidural) == Some("epidural_space");
            for l in &mut self.landmarks {
                if l.name == window_name {
                    l.position_mm = centre.to_array();
                } else if epidural_ok && l.name == format!("{key}_posterior_epidural_space") {
                    l.position_mm = epidural.to_array();
                }
            }
        }
    }
}
