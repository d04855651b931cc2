//! The solids of the phantom and the list they are pushed onto, in painting order.

use crate::anatomy::phantom::sdf::Sdf;
use crate::material::MaterialClass;

/// One solid of the phantom, in painting order.
#[derive(Debug, Clone)]
pub struct PhantomPart {
    /// Stable structure name (used for mesh names and masks).
    pub name: String,
    /// Tissue class of the structure.
    pub material: MaterialClass,
    /// The solid.
    pub sdf: Sdf,
    /// Whether the structure's mesh bounds its whole solid, with later structures nested inside it
    /// (true for the body envelope layers that contain everything), rather than only the part the
    /// painting order leaves to it. Labels and CT follow the painting order either way.
    pub nested: bool,
}

/// The parts list under construction, in painting order (both phantoms build with it).
#[derive(Default)]
pub(crate) struct Parts(pub(crate) Vec<PhantomPart>);

impl Parts {
    pub(crate) fn push(&mut self, name: &str, material: MaterialClass, sdf: Sdf) {
        // The two envelope solids that contain everything are meshed whole (nested): their
        // exclusive parts would be a thin shell (skin) and a surface wrapped round every organ
        // (deep soft tissue), both slow to mesh and of no use to a renderer that nests.
        let nested = name == "skin" || name == "deep_soft_tissue";
        self.0.push(PhantomPart {
            name: name.to_string(),
            material,
            // Children that cannot change the value at a point are skipped (same values).
            sdf: sdf.prepared(),
            nested,
        });
    }

    /// Pushes a bone as its cortical solid `{name}_cortical`, then its cancellous inset
    /// `{name}_cancellous` (`cortex_mm` thinner), both clipped to `under_skin` first so the
    /// cortex covers the cut as well.
    pub(crate) fn push_bone(&mut self, name: &str, bone: Sdf, under_skin: &Sdf, cortex_mm: f64) {
        let bone = Sdf::Intersect(vec![bone, under_skin.clone()]);
        self.push(
            &format!("{name}_cortical"),
            MaterialClass::CorticalBone,
            bone.clone(),
        );
        self.push(
            &format!("{name}_cancellous"),
            MaterialClass::Cancellous,
            bone.offset(-cortex_mm),
        );
    }
}
