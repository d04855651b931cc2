//! The tissues the masks lack, authored at the CT's voxel size and marked as such: the canal's
//! contents, the ligamentum flavum, the interspinous ligament, and skin, fat and muscle from HU
//! (see the docs of [`super`]).

use super::super::asset::Landmark;
use super::super::error::AnatomyError;
use super::super::mask::StructureMask;
use super::landmarks::{LEVELS, posterior_canal_voxel};
use super::masks::{
    BoolVolume, body_mask, components_2d, drop_small, erode_2d, holes_2d, majority,
};
use crate::material::MaterialClass;
use crate::volume::Volume;

/// Fat band, HU: about -190 to -30 HU (Kalender, *Computed Tomography*, 3rd ed., Fig. 1.8).
pub const FAT_HU: (f32, f32) = (-190.0, -30.0);
/// Muscle and soft tissue band, HU: -30 to 150 HU (the soft-tissue band of
/// [`super::labels`]; skeletal muscle is about 40 HU).
pub const MUSCLE_HU: (f32, f32) = (-30.0, 150.0);
/// Connected components of an HU-derived tissue smaller than this are dropped (noise and
/// partial volumes; 8 voxels of 3 mm are 0.2 ml); our choice.
pub const MIN_COMPONENT_VOXELS: usize = 8;

/// Depth of the subcutaneous fat layer at most, voxels below the skin layer (10 of 3 mm: lumbar
/// subcutaneous fat is up to a few centimetres thick); our choice.
pub const SUBCUTANEOUS_MAX_DEPTH_VOXELS: usize = 10;

/// The authored structures, in painting order, and the notes that mark them as authored (see
/// the module docs). `masks` are the imported structures (none of their voxels is given to an
/// authored tissue); `canal` comes from [`canal`]; `landmarks` from [`spine_landmarks`].
pub fn authored_structures(
    ct_hu: &Volume<f32>,
    masks: &[StructureMask],
    canal: &BoolVolume,
    landmarks: &[Landmark],
) -> Result<(Vec<StructureMask>, Vec<String>), AnatomyError> {
    let g = ct_hu.grid;
    let [nx, ny, nz] = g.dims;
    let mut claimed = BoolVolume::empty(g);
    let mut bone = BoolVolume::empty(g);
    for m in masks {
        let b = BoolVolume::of_mask(g, m)?;
        for (idx, &x) in b.data.iter().enumerate() {
            if x {
                claimed.data[idx] = true;
                if m.material.is_bone() {
                    bone.data[idx] = true;
                }
            }
        }
    }
    let mut notes = Vec::new();
    let z_of = |name: &str| {
        landmarks
            .iter()
            .find(|l| l.name == name)
            .map(|l| g.world_to_voxel(l.position_mm)[2].round().max(0.0) as usize)
    };
    let lumbar_z: Vec<usize> = LEVELS
        .iter()
        .filter_map(|(l, _)| z_of(&format!("{l}_body_centre")))
        .collect();
    let (z_lo, z_hi) = (
        lumbar_z.iter().copied().min().unwrap_or(0),
        lumbar_z.iter().copied().max().unwrap_or(0),
    );
    // Canal contents.
    let canal_free = BoolVolume {
        grid: g,
        data: canal
            .data
            .iter()
            .zip(&claimed.data)
            .map(|(&c, &m)| c && !m)
            .collect(),
    };
    let sac = {
        let mut s = erode_2d(&canal_free);
        drop_small(&mut s, MIN_COMPONENT_VOXELS);
        s
    };
    let mut epidural = BoolVolume::empty(g);
    for idx in 0..g.len() {
        epidural.data[idx] = canal_free.data[idx] && !sac.data[idx];
    }
    // Body envelope: the skin is its outer voxel layer.
    let mut body = body_mask(ct_hu);
    for idx in 0..g.len() {
        body.data[idx] |= claimed.data[idx] || canal.data[idx];
    }
    let deep0 = erode_2d(&body);
    let mut flavum = BoolVolume::empty(g);
    let mut interspinous = BoolVolume::empty(g);
    for k in z_lo..=z_hi.min(nz - 1) {
        for i in 0..nx {
            let Some(j) = (0..ny).find(|&j| canal.at(i, j, k)) else {
                continue;
            };
            if j > 0 && !claimed.at(i, j - 1, k) && !canal.at(i, j - 1, k) {
                flavum.data[g.index(i, j - 1, k)] = true;
            }
        }
        if let Some(p) = posterior_canal_voxel(canal, k) {
            for j in (0..p[1].saturating_sub(1)).rev() {
                let idx = g.index(p[0], j, k);
                if claimed.data[idx] {
                    continue;
                }
                if !deep0.data[idx] || ct_hu.data[idx] < FAT_HU.1 {
                    break;
                }
                interspinous.data[idx] = true;
            }
        }
    }
    let mut deep = deep0;
    for idx in 0..g.len() {
        deep.data[idx] |=
            claimed.data[idx] || canal.data[idx] || flavum.data[idx] || interspinous.data[idx];
    }
    let taken = |idx: usize| {
        claimed.data[idx] || canal.data[idx] || flavum.data[idx] || interspinous.data[idx]
    };
    let in_band = |h: f32, band: (f32, f32)| h >= band.0 && h < band.1;
    // Fat (majority-filtered) within the outer layer, connected through fat to the skin layer,
    // per slice.
    let mut outer = deep.clone();
    for _ in 0..SUBCUTANEOUS_MAX_DEPTH_VOXELS {
        outer = erode_2d(&outer);
    }
    let fat_hu = majority(&BoolVolume {
        grid: g,
        data: (0..g.len())
            .map(|idx| deep.data[idx] && !taken(idx) && in_band(ct_hu.data[idx], FAT_HU))
            .collect(),
    });
    let mut subcut = BoolVolume::empty(g);
    for k in 0..nz {
        let off = k * nx * ny;
        let fat: Vec<bool> = (0..nx * ny)
            .map(|p| fat_hu.data[off + p] && !taken(off + p) && !outer.data[off + p])
            .collect();
        for comp in components_2d(&fat, nx, ny) {
            let at_skin = comp.iter().any(|&p| {
                let (i, j) = (p % nx, p / nx);
                [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)]
                    .iter()
                    .any(|(di, dj)| {
                        let (a, b) = (i as i64 + di, j as i64 + dj);
                        a >= 0
                            && b >= 0
                            && (a as usize) < nx
                            && (b as usize) < ny
                            && !deep.data[off + b as usize * nx + a as usize]
                    })
            });
            if at_skin {
                for p in comp {
                    subcut.data[off + p] = true;
                }
            }
        }
        // Septa and speckle enclosed by the layer are part of it (fewer, smoother surfaces).
        let layer = subcut.data[off..off + nx * ny].to_vec();
        for (p, h) in holes_2d(&layer, nx, ny).into_iter().enumerate() {
            if h && !taken(off + p) && deep.data[off + p] {
                subcut.data[off + p] = true;
            }
        }
    }
    drop_small(&mut subcut, MIN_COMPONENT_VOXELS);
    let canal_y = |k: usize| posterior_canal_voxel(canal, k).map(|p| p[1]);
    let mut muscle = BoolVolume::empty(g);
    for k in 0..nz {
        let Some(cy) = canal_y(k) else { continue };
        for j in 0..cy {
            for i in 0..nx {
                let idx = g.index(i, j, k);
                muscle.data[idx] = deep.data[idx]
                    && !taken(idx)
                    && !subcut.data[idx]
                    && in_band(ct_hu.data[idx], MUSCLE_HU);
            }
        }
    }
    let mut muscle = majority(&muscle);
    for idx in 0..g.len() {
        muscle.data[idx] &= !taken(idx) && !subcut.data[idx];
    }
    drop_small(&mut muscle, MIN_COMPONENT_VOXELS);
    let out = vec![
        body.to_structure("skin", MaterialClass::SoftTissue),
        deep.to_structure("deep_soft_tissue", MaterialClass::SoftTissue),
        subcut.to_structure("subcutaneous_fat", MaterialClass::Fat),
        muscle.to_structure("muscle_other", MaterialClass::Muscle),
        interspinous.to_structure("interspinous_ligament", MaterialClass::SoftTissue),
        flavum.to_structure("ligamentum_flavum", MaterialClass::LigamentumFlavum),
        epidural.to_structure("epidural_space", MaterialClass::EpiduralSpace),
        sac.to_structure("dural_sac", MaterialClass::DuraCsf),
    ];
    for s in &out {
        let n = s.mask.data.iter().filter(|&&v| v >= 0.5).count();
        notes.push(format!(
            "{}: authored ({} voxels; {})",
            s.name,
            n,
            match s.name.as_str() {
                "skin" => "body outline above -500 HU, holes filled per slice, meshed whole",
                "deep_soft_tissue" => "body less its outer voxel layer, meshed whole",
                "subcutaneous_fat" => "-190..-30 HU, majority-filtered, within 30 mm of and connected to the skin layer",
                "muscle_other" => "-30..150 HU, majority-filtered, posterior to the canal, outside every mask",
                "interspinous_ligament" => "midline column behind the flavum, lumbar levels",
                "ligamentum_flavum" => "first non-bone voxel behind the canal, lumbar levels",
                "epidural_space" => "canal less the dural sac (one voxel layer)",
                _ => "canal eroded by one pixel in plane",
            }
        ));
    }
    Ok((out, notes))
}
