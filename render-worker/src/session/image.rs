//! What a modality hands to the session for display: a view name and an 8-bit grey image. The
//! session, the frame encoder and the protocol know only these types, never a modality's own.

use serde::{Deserialize, Serialize};

/// A rendered view of a session (one per modality display).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewId {
    /// The C-arm image.
    Fluoroscopy,
    /// The ultrasound B-mode image.
    Ultrasound,
    /// The external view of the body for placing the ultrasound probe (skin, probe, needle
    /// outside the skin, C-arm direction).
    Placement,
}

impl ViewId {
    /// Wire code in the binary frame header.
    pub fn code(self) -> u8 {
        match self {
            ViewId::Fluoroscopy => 0,
            ViewId::Ultrasound => 1,
            ViewId::Placement => 2,
        }
    }

    /// Inverse of [`ViewId::code`].
    pub fn from_code(code: u8) -> Option<ViewId> {
        match code {
            0 => Some(ViewId::Fluoroscopy),
            1 => Some(ViewId::Ultrasound),
            2 => Some(ViewId::Placement),
            _ => None,
        }
    }
}

/// An 8-bit grey image, row-major from the top-left pixel: what every view displays.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ViewImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Grey levels, `width * height`, row-major from the top-left pixel.
    pub pixels: Vec<u8>,
}

impl From<sim_core::fluoro::Image> for ViewImage {
    fn from(i: sim_core::fluoro::Image) -> ViewImage {
        ViewImage {
            width: i.width,
            height: i.height,
            pixels: i.pixels,
        }
    }
}
