//! Body habitus of the lumbar phantom: slim, average and obese bodies around the same spine.
//!
//! A habitus changes only the soft-tissue envelope: the subcutaneous fat under the skin (all
//! round), and the abdomen's size in front and to the sides (visceral fat, in the deep soft
//! tissue). The posterior skin moves back by the change of subcutaneous fat, so the distance
//! from the skin to every spinal target grows with it; the spine, its landmarks and every
//! deeper structure stay where they are.
//!
//! Figures (simulator choices, set so the skin-to-epidural-space depth at L3-L4 follows the
//! trend with body-mass index that C. P. Clinkscales et al. measured, "An observational study of
//! the relationship between lumbar epidural space depth and body mass index in Michigan
//! parturients", Int. J. Obstet. Anesth. 16 (2007) 323-327: about 4-5 cm at a normal BMI and
//! over 7 cm in the obese):
//! | habitus | subcutaneous fat | abdomen (half width x half depth) | anterior wall moved |
//! |---|---:|---:|---:|
//! | slim | 8 mm | 150 x 104 mm | -20 mm |
//! | average | 15 mm | 165 x 117 mm | 0 |
//! | obese | 40 mm | 210 x 165 mm | +70 mm |

use serde::{Deserialize, Serialize};

use super::PhantomParams;
use super::model::BODY_CENTRE_Y_MM;

/// A body habitus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Habitus {
    /// Thin: little subcutaneous and visceral fat.
    Slim,
    /// The default phantom.
    Average,
    /// Obese: thick subcutaneous fat, a large abdomen.
    Obese,
}

/// One habitus's envelope.
struct Envelope {
    subcutaneous_fat_mm: f64,
    half_width_mm: f64,
    /// Posterior skin moved back (positive: further from the spine), mm.
    posterior_mm: f64,
    /// Anterior abdominal wall moved forward, mm.
    anterior_mm: f64,
}

impl Habitus {
    /// All three, slim first.
    pub const ALL: [Habitus; 3] = [Habitus::Slim, Habitus::Average, Habitus::Obese];

    /// The name station files and region names use.
    pub fn name(self) -> &'static str {
        match self {
            Habitus::Slim => "slim",
            Habitus::Average => "average",
            Habitus::Obese => "obese",
        }
    }

    /// The habitus named `name`.
    pub fn parse(name: &str) -> Option<Habitus> {
        Self::ALL.into_iter().find(|h| h.name() == name)
    }

    fn envelope(self) -> Envelope {
        match self {
            Habitus::Slim => Envelope {
                subcutaneous_fat_mm: 8.0,
                half_width_mm: 150.0,
                posterior_mm: -7.0,
                anterior_mm: -20.0,
            },
            Habitus::Average => Envelope {
                subcutaneous_fat_mm: 15.0,
                half_width_mm: 165.0,
                posterior_mm: 0.0,
                anterior_mm: 0.0,
            },
            Habitus::Obese => Envelope {
                subcutaneous_fat_mm: 40.0,
                half_width_mm: 210.0,
                posterior_mm: 25.0,
                anterior_mm: 70.0,
            },
        }
    }

    /// `params` (the average body's) with this habitus's envelope, the grid's extent grown or
    /// shrunk with it (the average grid's margins in front and behind, 6 mm of air beyond the
    /// hips at the sides). The average habitus returns `params` unchanged.
    pub fn apply(self, params: &PhantomParams) -> PhantomParams {
        let mut p = params.clone();
        if self == Habitus::Average {
            return p;
        }
        let avg = Habitus::Average.envelope();
        let e = self.envelope();
        let a = &mut p.anatomy;
        a.subcutaneous_fat_mm = e.subcutaneous_fat_mm;
        a.body_half_width_mm = e.half_width_mm;
        a.body_half_depth_mm += 0.5 * (e.posterior_mm + e.anterior_mm);
        a.body_centre_y_mm = BODY_CENTRE_Y_MM + 0.5 * (e.anterior_mm - e.posterior_mm);
        // The hips are 12 mm wider than the waist; 6 mm of air beyond.
        let half_x = e.half_width_mm + 12.0 + 6.0;
        p.extent_min_mm[0] = -half_x;
        p.extent_max_mm[0] = half_x;
        p.extent_min_mm[1] += avg.posterior_mm - e.posterior_mm;
        p.extent_max_mm[1] += e.anterior_mm - avg.anterior_mm;
        p
    }

    /// The region name of the lumbar phantom with this habitus: the phantom's own name for the
    /// average body, `lumbar-phantom-slim` and `lumbar-phantom-obese` for the others.
    pub fn region_name(self) -> String {
        match self {
            Habitus::Average => super::REGION_NAME.to_string(),
            other => format!("{}-{}", super::REGION_NAME, other.name()),
        }
    }

    /// The habitus whose region is named `name` (`None` for a name that is not a lumbar
    /// phantom's).
    pub fn of_region(name: &str) -> Option<Habitus> {
        Self::ALL.into_iter().find(|h| h.region_name() == name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn habitus_moves_the_posterior_skin_by_the_fat_and_keeps_the_average_as_it_was() {
        let base = PhantomParams::with_voxel_mm(2.0);
        assert_eq!(Habitus::Average.apply(&base), base);
        // The average body's cache key is the one it had before habitus existed: the envelope
        // centre is left out of the serialized parameters at its default.
        let json = serde_json::to_string(&base.anatomy).expect("serializes");
        assert!(!json.contains("body_centre_y_mm"), "{json}");
        let posterior =
            |p: &PhantomParams| p.anatomy.body_centre_y_mm - p.anatomy.body_half_depth_mm;
        let anterior =
            |p: &PhantomParams| p.anatomy.body_centre_y_mm + p.anatomy.body_half_depth_mm;
        let (slim, obese) = (Habitus::Slim.apply(&base), Habitus::Obese.apply(&base));
        assert!((posterior(&slim) - posterior(&base) - 7.0).abs() < 1e-9);
        assert!((posterior(&base) - posterior(&obese) - 25.0).abs() < 1e-9);
        assert!((anterior(&obese) - anterior(&base) - 70.0).abs() < 1e-9);
        // The fat's inner surface (where the muscles and spine begin) stays behind the spine
        // where it was.
        for p in [&slim, &obese] {
            let inner = posterior(p) + p.anatomy.skin_mm + p.anatomy.subcutaneous_fat_mm;
            let base_inner =
                posterior(&base) + base.anatomy.skin_mm + base.anatomy.subcutaneous_fat_mm;
            assert!((inner - base_inner).abs() < 1e-9);
            // The grid keeps the average body's 4 mm of air behind and in front of the body.
            assert!(
                p.extent_min_mm[1] <= posterior(p) - 4.0 + 1e-9,
                "{:?}",
                p.extent_min_mm
            );
            assert!(
                p.extent_max_mm[1] >= anterior(p) + 4.0,
                "{:?}",
                p.extent_max_mm
            );
        }
        for h in Habitus::ALL {
            assert_eq!(Habitus::parse(h.name()), Some(h));
            assert_eq!(Habitus::of_region(&h.region_name()), Some(h));
        }
        assert_eq!(Habitus::of_region("lumbar-ct"), None);
    }
}
