//! The cervical phantom's parts list under construction, in painting order.

use crate::anatomy::phantom::model::PhantomPart;
use crate::anatomy::phantom::sdf::Sdf;
use crate::material::MaterialClass;

/// The parts list under construction, in painting order.
#[derive(Default)]
pub(super) struct Parts(pub(super) Vec<PhantomPart>);

impl Parts {
    pub(super) fn push(&mut self, name: &str, material: MaterialClass, sdf: Sdf) {
        // The envelope layers that contain everything are meshed whole, as in the lumbar phantom.
        let nested = name == "skin" || name == "deep_soft_tissue";
        self.0.push(PhantomPart {
            name: name.to_string(),
            material,
            sdf,
            nested,
        });
    }
}
