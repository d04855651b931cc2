//! Step 3 of the family meshing (see [`super`]): Taubin smoothing of all welded vertices at once,
//! with junction vertices kept on their junction curves and a volume guard per structure.

use super::surface::ExtractedSurface;
use super::weld::Family;
use crate::anatomy::smooth::{TaubinParams, laplacian_step};

/// Taubin smoothing of the whole family (see the module doc); returns one note per mesh.
pub(super) fn smooth_family(
    fam: &mut Family,
    items: &[ExtractedSurface],
    params: &TaubinParams,
) -> Vec<String> {
    let source: Vec<Vec<[u32; 3]>> = fam.patches.iter().map(|p| p.triangles.clone()).collect();
    let all = fam.neighbours();
    let curve = fam.curve_neighbours();
    let nb: Vec<Vec<u32>> = (0..fam.positions.len())
        .map(|g| {
            if !fam.junction[g] {
                all[g].clone()
            } else if curve[g].len() == 2 {
                curve[g].clone()
            } else {
                Vec::new()
            }
        })
        .collect();
    let vertices_of: Vec<Vec<u32>> = (0..items.len())
        .map(|m| {
            let mut v: Vec<u32> = fam
                .mesh_triangles(m, &source)
                .into_iter()
                .flatten()
                .collect();
            v.sort_unstable();
            v.dedup();
            v
        })
        .collect();
    let original = fam.positions.clone();
    let rel_err = |vols: &[f64], m: usize| {
        (vols[m] - items[m].mask_volume_mm3).abs() / items[m].mask_volume_mm3.max(f64::MIN_POSITIVE)
    };
    let vols0 = fam.mesh_volumes(&source, &original);
    let err0: Vec<f64> = (0..items.len()).map(|m| rel_err(&vols0, m)).collect();
    let allowed: Vec<f64> = err0
        .iter()
        .map(|&e| params.max_volume_change.max(e))
        .collect();
    let mut movable = vec![true; original.len()];
    let mut stopped = vec![false; items.len()];
    let mut done = vec![0u32; items.len()];
    let mut capped = vec![0u32; original.len()];
    let mut current = original.clone();
    for _ in 0..params.iterations {
        if stopped.iter().all(|&s| s) {
            break;
        }
        let step = laplacian_step(&current, &nb, Some(&movable), params.lambda);
        let mut step = laplacian_step(&step, &nb, Some(&movable), params.mu);
        let mut capped_now = vec![false; original.len()];
        for (g, (p, o)) in step.iter_mut().zip(&original).enumerate() {
            let d = [p[0] - o[0], p[1] - o[1], p[2] - o[2]];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if len > params.max_displacement_mm {
                let s = params.max_displacement_mm / len;
                *p = std::array::from_fn(|a| o[a] + d[a] * s);
                capped_now[g] = true;
            }
        }
        // A structure whose volume error would pass its limit stops: its vertices go back to
        // their last positions and stay. Restoring them can push a neighbour over its own limit,
        // so repeat until no structure is over (each round stops at least one more).
        loop {
            let vols = fam.mesh_volumes(&source, &step);
            let over: Vec<usize> = (0..items.len())
                .filter(|&m| !stopped[m] && rel_err(&vols, m) > allowed[m])
                .collect();
            if over.is_empty() {
                break;
            }
            for m in over {
                stopped[m] = true;
                for &g in &vertices_of[m] {
                    step[g as usize] = current[g as usize];
                    movable[g as usize] = false;
                    capped_now[g as usize] = false;
                }
            }
        }
        for (c, now) in capped.iter_mut().zip(&capped_now) {
            *c += u32::from(*now);
        }
        for (d, s) in done.iter_mut().zip(&stopped) {
            *d += u32::from(!s);
        }
        current = step;
    }
    let vols = fam.mesh_volumes(&source, &current);
    let notes = (0..items.len())
        .map(|m| {
            let moves: u32 = vertices_of[m].iter().map(|&g| capped[g as usize]).sum();
            format!(
                "{}: Taubin smoothing {}/{} pairs{}, volume error vs mask {:.2}% -> {:.2}%, {moves} vertex moves capped at {} mm",
                items[m].name,
                done[m],
                params.iterations,
                if stopped[m] {
                    " (stopped by the volume guard)"
                } else {
                    ""
                },
                100.0 * err0[m],
                100.0 * rel_err(&vols, m),
                params.max_displacement_mm
            )
        })
        .collect();
    fam.positions = current;
    notes
}
