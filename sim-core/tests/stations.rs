//! Every station's targets lie in the tissue their names say, on the region the station runs on:
//! the target as a session resolves it (the region's landmark where the station names one and
//! the region publishes it, else the typed position), classified by the region's own anatomy
//! (the phantoms' painted solids, exactly; the real-CT region's meshes).

use std::path::Path;

use glam::DVec3;
use sim_core::anatomy::asset::RegionAsset;
use sim_core::anatomy::phantom::model::Anatomy;
use sim_core::anatomy::phantom::{self, PhantomParams, cervical};
use sim_core::geom::Bvh;
use sim_core::rubric::load_station_dir;

/// The frame note of stations typed relative to the L4 body centre (`assets/stations/README.md`;
/// the same words `render_worker::session::L4_ORIGIN_NOTE` looks for).
const L4_ORIGIN_NOTE: &str = "origin at the L4 vertebral body centre";

/// What a target's name promises about the tissue it lies in.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Tissue {
    /// Epidural fat (the posterior epidural space, the ventral interlaminar line).
    EpiduralFat,
    /// A facet joint's space: not bone, the two articulating bones both within 4 mm (the 2 mm
    /// space and a 2 mm step into each process, as the phantom's landmark test).
    JointSpace,
    /// The subpedicular "safe triangle": not bone, not the dural sac or a nerve root, a
    /// pedicle's bone within 5 mm and a nerve root within 8 mm.
    SafeTriangle,
    /// Just below a pedicle's inferior cortex: not bone, that vertebra's bone within 2 mm.
    PedicleFloor,
    /// On the lateral surface of an articular pillar: not bone, the vertebra's bone within 2 mm.
    PillarSurface,
}

fn tissue_of(target: &str) -> Tissue {
    if target.contains("epidural") || target.contains("interlaminar_line") {
        Tissue::EpiduralFat
    } else if target.contains("facet") {
        Tissue::JointSpace
    } else if target.contains("subpedicular") {
        Tissue::SafeTriangle
    } else if target.contains("pedicle_6_oclock") {
        Tissue::PedicleFloor
    } else if target.contains("pillar") {
        Tissue::PillarSurface
    } else {
        panic!("no tissue rule for target {target}: name what it should lie in here")
    }
}

/// The bone a phantom structure belongs to (`L5` for `L5_cortical`), or `None` for soft tissue.
pub(crate) fn bone_of(name: &str) -> Option<&str> {
    name.strip_suffix("_cortical")
        .or_else(|| name.strip_suffix("_cancellous"))
}

/// The name of the phantom structure that owns `p` (empty outside the body).
pub(crate) fn name_at(a: &Anatomy, p: DVec3) -> String {
    a.structure_at(p.to_array())
        .map(|i| a.parts[i].name.clone())
        .unwrap_or_default()
}

/// Names of the structures within `radius_mm` of `centre`: a 1 mm lattice over the ball.
fn within(a: &Anatomy, centre: DVec3, radius_mm: f64) -> Vec<String> {
    let n = radius_mm.ceil() as i32;
    let mut out: Vec<String> = Vec::new();
    for i in -n..=n {
        for j in -n..=n {
            for k in -n..=n {
                let d = DVec3::new(f64::from(i), f64::from(j), f64::from(k));
                if d.length() <= radius_mm {
                    let name = name_at(a, centre + d);
                    if !out.contains(&name) {
                        out.push(name);
                    }
                }
            }
        }
    }
    out
}

/// The vertebrae a target's name mentions (`left_l4_l5_facet_...` gives L4 and L5), as the
/// phantoms name their bones.
fn levels_of(target: &str) -> Vec<String> {
    target
        .split('_')
        .filter(|w| {
            w.len() >= 2
                && w.starts_with(['l', 'c', 't', 's'])
                && w[1..].chars().all(|c| c.is_ascii_digit())
        })
        .map(|w| match w {
            // The phantoms name the first sacral vertebra's bone `sacrum`.
            "s1" => "sacrum".to_string(),
            other => other.to_uppercase(),
        })
        .collect()
}

/// Whether `p` lies in `tissue` on a phantom's anatomy, with the bones of `levels` where the
/// tissue's rule names bone; `Err` says what it lies in instead.
fn check_phantom(a: &Anatomy, p: DVec3, tissue: Tissue, levels: &[String]) -> Result<(), String> {
    let here = name_at(a, p);
    let bones = |r: f64| -> Vec<String> {
        within(a, p, r)
            .iter()
            .filter_map(|n| bone_of(n).map(str::to_string))
            .collect()
    };
    let fail = |why: &str| Err(format!("{why}; the point lies in {here:?}"));
    if bone_of(&here).is_some() {
        return fail("in bone");
    }
    match tissue {
        Tissue::EpiduralFat if here == "epidural_space" => Ok(()),
        Tissue::EpiduralFat => fail("not in the epidural space"),
        Tissue::JointSpace => {
            let near = bones(4.0);
            if levels.len() == 2 && levels.iter().all(|l| near.contains(l)) {
                Ok(())
            } else {
                fail(&format!("not between {levels:?} within 4 mm: {near:?}"))
            }
        }
        Tissue::SafeTriangle => {
            let nerve = within(a, p, 8.0).iter().any(|n| n.contains("root"));
            if here == "dural_sac" || here.contains("root") {
                fail("in the dural sac or a root")
            } else if !levels.iter().all(|l| bones(5.0).contains(l)) || levels.is_empty() {
                fail(&format!("no {levels:?} bone within 5 mm: {:?}", bones(5.0)))
            } else if !nerve {
                fail("no nerve root within 8 mm")
            } else {
                Ok(())
            }
        }
        Tissue::PedicleFloor | Tissue::PillarSurface => {
            if levels.len() == 1 && bones(2.0).contains(&levels[0]) {
                Ok(())
            } else {
                fail(&format!("no {levels:?} bone within 2 mm: {:?}", bones(2.0)))
            }
        }
    }
}

#[test]
fn station_targets_lie_in_the_tissue_their_names_say() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/stations");
    let stations = load_station_dir(&dir).expect("stations");
    let lumbar = phantom::anatomy(&PhantomParams::default());
    let cervical = cervical::anatomy(&cervical::default_params());
    let ct = RegionAsset::load(&dir.join("../lumbar-ct")).expect("lumbar-ct");
    let ct_epidural = Bvh::new(&ct.structure("epidural_space").expect("epidural").mesh);
    let mut checked = 0;
    let mut failures = Vec::new();
    for file in &stations {
        let st = &file.station;
        for t in &st.targets {
            let tissue = tissue_of(&t.name);
            let landmarks: Vec<(String, [f64; 3])> = match st.region.as_str() {
                "lumbar-phantom" => lumbar
                    .landmarks
                    .iter()
                    .map(|l| (l.name.clone(), l.position_mm))
                    .collect(),
                "cervical-phantom" => cervical
                    .landmarks
                    .iter()
                    .map(|l| (l.name.clone(), l.position_mm))
                    .collect(),
                "lumbar-ct" => ct
                    .landmarks
                    .iter()
                    .map(|l| (l.name.clone(), l.position_mm))
                    .collect(),
                other => panic!("{}: no rule for region {other}", st.id),
            };
            // Typed positions of stations authored relative to the L4 body centre are shifted by
            // the region's (as `render_worker::session::StationContext` resolves them).
            let offset = if st.frame_note.contains(L4_ORIGIN_NOTE) {
                landmarks
                    .iter()
                    .find(|(n, _)| n == "L4_body_centre")
                    .map_or(DVec3::ZERO, |(_, p)| DVec3::from_array(*p))
            } else {
                DVec3::ZERO
            };
            let typed = DVec3::from_array(t.position_mm) + offset;
            let landmark = t
                .landmark
                .as_ref()
                .and_then(|l| landmarks.iter().find(|(n, _)| n == l))
                .map(|(_, p)| DVec3::from_array(*p));
            // On a phantom, a landmark target's fallback is the landmark's own position (in the
            // station's frame, to the 0.01 mm it is typed to), so a region without the landmark
            // still aims at the same anatomy.
            if let (Some(l), true) = (landmark, st.region.ends_with("-phantom")) {
                if (l - typed).abs().max_element() > 0.005 + 1e-9 {
                    failures.push(format!(
                        "{} target {}: fallback {typed} is not the landmark {l} (type {:?})",
                        st.id,
                        t.name,
                        (l - offset).to_array().map(|v| (v * 100.0).round() / 100.0)
                    ));
                }
            }
            let p = landmark.unwrap_or(typed);
            let verdict = match st.region.as_str() {
                "lumbar-phantom" => check_phantom(&lumbar, p, tissue, &levels_of(&t.name)),
                "cervical-phantom" => check_phantom(&cervical, p, tissue, &levels_of(&t.name)),
                _ => match tissue {
                    Tissue::EpiduralFat if ct_epidural.contains(p.to_array()) => Ok(()),
                    other => Err(format!("{other:?} is not checked on the CT region")),
                },
            };
            checked += 1;
            if let Err(why) = verdict {
                failures.push(format!(
                    "{} target {} ({tissue:?}) at {p}: {why}",
                    st.id, t.name
                ));
            }
            // A target that names a landmark has it on its region (the fallback is for regions
            // without it, and a station names one region).
            if let Some(l) = &t.landmark {
                assert!(
                    landmarks.iter().any(|(n, _)| n == l),
                    "{} target {}: {} has no landmark {l}",
                    st.id,
                    t.name,
                    st.region
                );
            }
        }
    }
    assert!(checked >= 12, "{checked} targets");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
