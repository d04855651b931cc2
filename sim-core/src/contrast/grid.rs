//! The transport grid: a box of cubic cells in the model frame (mm), each either solid or open in
//! one [`Domain`] with its porosity, directional mobility, diffusivity, clearance and compliance.
//!
//! The numerics ([`super::pressure`], [`super::transport`]) see only this struct, so tests build
//! synthetic grids directly; [`super::domains`] fills one from the phantom.

use crate::volume::VolumeGrid;

/// A fluid compartment a cell can belong to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Domain {
    /// Epidural space (fat and venous plexus between ligamentum flavum and dura).
    Epidural,
    /// Intrathecal CSF inside the dural sac (cauda equina rootlets included).
    Intrathecal,
    /// The potential space between dura and arachnoid (the sac's outermost cell layer).
    Subdural,
    /// Blood vessels: radicular and segmental vessels, the epidural venous plexus.
    Vascular,
    /// Inside an exiting nerve root.
    Intraneural,
    /// Local pooling in muscle, fat and soft tissue around the needle tip.
    Pooling,
}

impl Domain {
    /// Every domain, in index order.
    pub const ALL: [Domain; 6] = [
        Domain::Epidural,
        Domain::Intrathecal,
        Domain::Subdural,
        Domain::Vascular,
        Domain::Intraneural,
        Domain::Pooling,
    ];
    /// Number of domains.
    pub const COUNT: usize = 6;

    /// Index in [`Domain::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// Stable snake_case name.
    pub fn name(self) -> &'static str {
        match self {
            Domain::Epidural => "epidural",
            Domain::Intrathecal => "intrathecal",
            Domain::Subdural => "subdural",
            Domain::Vascular => "vascular",
            Domain::Intraneural => "intraneural",
            Domain::Pooling => "pooling",
        }
    }

    /// The default cell properties of the domain. Pressure is an uncalibrated potential ("pu");
    /// every value is an authored scenario parameter unless a source is named.
    pub fn default_props(self) -> CellProps {
        match self {
            // Porosity 0.5: the fluid-accessible fraction of the epidural space used by the
            // reference workshop model (atlas methods, "Contrast transport"), itself a provisional
            // storage assumption. Axial mobility twice the transverse one: spread follows the
            // canal (our choice). Clearance: epidural contrast is absorbed over tens of minutes
            // (our choice, 1/1200 s).
            Domain::Epidural => CellProps {
                porosity: 0.5,
                mobility: [1.0, 1.0, 2.0],
                diffusivity: DISPERSION_MM2_S,
                clearance_per_s: 1.0 / 1200.0,
                compliance: 0.02,
            },
            // Free CSF: all pore, mobile (10x the epidural fat, our choice), no clearance over a
            // session; CSF leaves the crop through its cranial and caudal faces.
            Domain::Intrathecal => CellProps {
                porosity: 1.0,
                mobility: [10.0; 3],
                diffusivity: DISPERSION_MM2_S,
                clearance_per_s: 0.0,
                compliance: 0.01,
            },
            // A potential space: little storage, spread along the dura but not across it
            // (our choice).
            Domain::Subdural => CellProps {
                porosity: 0.3,
                mobility: [0.5, 0.5, 1.5],
                diffusivity: DISPERSION_MM2_S,
                clearance_per_s: 1.0 / 1200.0,
                compliance: 0.005,
            },
            // Blood: all pore, 1000x the epidural mobility (the benchmark's contrast), washed out
            // within seconds (clearance 0.5 /s, our choice: venous transit is a few seconds).
            Domain::Vascular => CellProps {
                porosity: 1.0,
                mobility: [1000.0; 3],
                diffusivity: DISPERSION_MM2_S,
                clearance_per_s: 0.5,
                compliance: 0.001,
            },
            // Inside the root: tight endoneurium, little storage, high pressure (our choice).
            Domain::Intraneural => CellProps {
                porosity: 0.1,
                mobility: [0.01, 0.01, 0.05],
                diffusivity: DISPERSION_MM2_S,
                clearance_per_s: 1.0 / 1200.0,
                compliance: 0.002,
            },
            // Muscle/fat pooling: tissue accommodates the volume (a linear storage term, as in
            // the reference's uncalibrated pressure relaxation), slow lymphatic clearance.
            Domain::Pooling => CellProps {
                porosity: 0.2,
                mobility: [0.1; 3],
                diffusivity: DISPERSION_MM2_S,
                clearance_per_s: 1.0 / 1800.0,
                compliance: 0.5,
            },
        }
    }

    /// Whether fluid may leave through the grid's outer faces in this domain (the compartment
    /// continues beyond the crop: canal, dural sac and vessels do, local pooling does not).
    pub fn open_at_crop(self) -> bool {
        matches!(
            self,
            Domain::Epidural | Domain::Intrathecal | Domain::Vascular
        )
    }
}

/// Effective dispersion, mm^2/s. The free diffusivity of an iodinated monomer in water is of the
/// order of 1e-3 mm^2/s (small-molecule diffusion); tissue mixing is larger; 0.05 is our choice.
pub const DISPERSION_MM2_S: f64 = 0.05;

/// Venous return: every vascular cell drains to the systemic circulation with this conductance
/// per mm^3 of cell, relative to its mobility (our choice; makes vessels wash out within seconds).
pub const VENOUS_RETURN: f64 = 0.05;

/// Physical properties of an open cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellProps {
    /// Fluid-accessible fraction of the cell (0 < phi <= 1).
    pub porosity: f64,
    /// Hydraulic mobility along x, y, z, mm^2 / (s pu).
    pub mobility: [f64; 3],
    /// Diffusivity (dispersion) of iodine in the pore fluid, mm^2/s.
    pub diffusivity: f64,
    /// First-order clearance rate of iodine, 1/s.
    pub clearance_per_s: f64,
    /// Storage per unit pressure, mm^3 per (mm^3 of cell) per pu.
    pub compliance: f64,
}

/// Inter-domain face multiplier: the fraction of the harmonic conductance a face between two
/// domains keeps. Compartments are separated by membranes (dura, vessel wall, perineurium, the
/// ligamentum flavum and fascia around pooling tissue), so different domains exchange nothing
/// unless a puncture opens a face or a mixed outlet couples them (our choice). The epidural space
/// and the root sleeve keep a small leak along the foramen.
pub fn interdomain_multiplier(a: Domain, b: Domain) -> f64 {
    if a == b {
        return 1.0;
    }
    match (a.min(b), a.max(b)) {
        (Domain::Epidural, Domain::Intraneural) => 0.01,
        _ => 0.0,
    }
}

/// The grid: geometry plus per-cell domain and properties. Solid cells have `domain = None`.
#[derive(Debug, Clone, PartialEq)]
pub struct ContrastGrid {
    /// Cell geometry (cubic cells expected; `spacing_mm` may differ per axis).
    pub grid: VolumeGrid,
    /// Domain per cell, `None` for solid (bone, ligament, air, the canal envelope).
    pub domain: Vec<Option<Domain>>,
    /// Properties per cell (ignored for solid cells).
    pub props: Vec<CellProps>,
    /// Conductance to a fixed zero-pressure sink per cell, mm^3/(s pu) (venous return, or a
    /// drain a test places).
    pub drain: Vec<f64>,
    /// Whether an open cell on the grid's outer faces drains through them, per domain.
    pub open_at_crop: [bool; Domain::COUNT],
}

impl ContrastGrid {
    /// A grid from per-cell domains, with each domain's default properties, venous return in
    /// vascular cells and the default crop openings.
    pub fn from_domains(grid: VolumeGrid, domain: Vec<Option<Domain>>) -> ContrastGrid {
        assert_eq!(domain.len(), grid.len(), "one domain entry per cell");
        let vc = grid.voxel_volume_mm3();
        let solid = Domain::Pooling.default_props();
        let props: Vec<CellProps> = domain
            .iter()
            .map(|d| d.map_or(solid, Domain::default_props))
            .collect();
        let drain = domain
            .iter()
            .zip(&props)
            .map(|(d, p)| {
                if *d == Some(Domain::Vascular) {
                    VENOUS_RETURN * p.mobility[0] * vc.cbrt()
                } else {
                    0.0
                }
            })
            .collect();
        ContrastGrid {
            grid,
            domain,
            props,
            drain,
            open_at_crop: Domain::ALL.map(Domain::open_at_crop),
        }
    }

    /// A grid whose every cell is open in `domain` with `props`, no drains and closed crop faces
    /// (tests and benchmarks modify it from there).
    pub fn uniform(grid: VolumeGrid, domain: Domain, props: CellProps) -> ContrastGrid {
        ContrastGrid {
            grid,
            domain: vec![Some(domain); grid.len()],
            props: vec![props; grid.len()],
            drain: vec![0.0; grid.len()],
            open_at_crop: [false; Domain::COUNT],
        }
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        self.grid.len()
    }

    /// True for an empty grid.
    pub fn is_empty(&self) -> bool {
        self.grid.is_empty()
    }

    /// Pore volume of cell `i` at zero pressure, mm^3 (0 for solid cells).
    pub fn pore_volume_mm3(&self, i: usize) -> f64 {
        if self.domain[i].is_some() {
            self.props[i].porosity * self.grid.voxel_volume_mm3()
        } else {
            0.0
        }
    }

    /// The cell containing point `p` (mm), if inside the grid.
    pub fn cell_at(&self, p_mm: [f64; 3]) -> Option<usize> {
        let v = self.grid.world_to_voxel(p_mm);
        let mut ijk = [0usize; 3];
        for a in 0..3 {
            let r = v[a].round();
            if !(r >= 0.0 && r < self.grid.dims[a] as f64) {
                return None;
            }
            ijk[a] = r as usize;
        }
        Some(self.grid.index(ijk[0], ijk[1], ijk[2]))
    }
}

/// Harmonic face coefficient of two half-cells: `A / (h_i / (2 k_i) + h_j / (2 k_j))`, the
/// standard two-point flux transmissibility (series resistances of the two half-cells). Zero if
/// either coefficient is zero.
pub fn harmonic_face(area_mm2: f64, h_i: f64, k_i: f64, h_j: f64, k_j: f64) -> f64 {
    if k_i <= 0.0 || k_j <= 0.0 {
        return 0.0;
    }
    area_mm2 / (h_i / (2.0 * k_i) + h_j / (2.0 * k_j))
}

/// Face coefficients of a grid: hydraulic conductance and diffusive transmissibility of the face
/// between cell `i` and its `+axis` neighbour, stored at `i` (zero where there is none).
#[derive(Debug, Clone, PartialEq)]
pub struct Faces {
    /// Conductance, mm^3 / (s pu), per axis.
    pub conductance: [Vec<f64>; 3],
    /// Diffusive transmissibility (harmonic phi * D), mm^3/s, per axis.
    pub transmissibility: [Vec<f64>; 3],
    /// Conductance to zero pressure per cell: the cell's own drain plus its open crop faces.
    pub sink: Vec<f64>,
}

impl Faces {
    /// Faces of `g`, with the faces listed in `opened` (cell, axis) passing between domains at
    /// full conductance (a puncture).
    pub fn new(g: &ContrastGrid, opened: &[(usize, usize)]) -> Faces {
        let n = g.len();
        let [nx, ny, nz] = g.grid.dims;
        let h = g.grid.spacing_mm;
        let area = [h[1] * h[2], h[0] * h[2], h[0] * h[1]];
        let strides = [1, nx, nx * ny];
        let mut conductance = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
        let mut transmissibility = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
        let mut sink = g.drain.clone();
        let mut open = std::collections::BTreeSet::new();
        open.extend(opened.iter().copied());
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let c = g.grid.index(i, j, k);
                    let Some(dc) = g.domain[c] else { continue };
                    let pc = &g.props[c];
                    let ijk = [i, j, k];
                    for a in 0..3 {
                        if g.open_at_crop[dc.index()] {
                            for on_face in [ijk[a] == 0, ijk[a] + 1 == g.grid.dims[a]] {
                                if on_face {
                                    // Half a cell to the fixed pressure on the crop face.
                                    sink[c] += 2.0 * pc.mobility[a] * area[a] / h[a];
                                }
                            }
                        }
                        if ijk[a] + 1 == g.grid.dims[a] {
                            continue;
                        }
                        let nb = c + strides[a];
                        let Some(dn) = g.domain[nb] else { continue };
                        let pn = &g.props[nb];
                        let m = if open.contains(&(c, a)) {
                            1.0
                        } else {
                            interdomain_multiplier(dc, dn)
                        };
                        if m == 0.0 {
                            continue;
                        }
                        conductance[a][c] =
                            m * harmonic_face(area[a], h[a], pc.mobility[a], h[a], pn.mobility[a]);
                        transmissibility[a][c] = m * harmonic_face(
                            area[a],
                            h[a],
                            pc.porosity * pc.diffusivity,
                            h[a],
                            pn.porosity * pn.diffusivity,
                        );
                    }
                }
            }
        }
        Faces {
            conductance,
            transmissibility,
            sink,
        }
    }
}
