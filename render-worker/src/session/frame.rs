//! Encoded frames: 8-bit grey JPEG behind a small fixed header.
//!
//! Binary websocket message layout (little endian), 40 bytes then the JPEG:
//!
//! | bytes  | field                                                  |
//! |--------|--------------------------------------------------------|
//! | 0..4   | magic `SIMF`                                           |
//! | 4      | header version (1)                                     |
//! | 5      | view code (`ViewId::code`; the hello lists every view) |
//! | 6      | flags: bit 0 set for a draft (a cheaper preview of the |
//! |        | same input; the full frame follows), other bits 0      |
//! | 7      | reserved (0)                                           |
//! | 8..16  | frame sequence (per session, increasing)               |
//! | 16..24 | last accepted input sequence the frame reflects        |
//! | 24..32 | simulation time of the image, ms                       |
//! | 32..34 | width, pixels                                          |
//! | 34..36 | height, pixels                                         |
//! | 36..40 | reserved (0)                                           |

use super::image::ViewImage as Image;

use super::image::ViewId;

/// Header length, bytes.
pub const HEADER_BYTES: usize = 40;
/// Magic bytes.
pub const MAGIC: &[u8; 4] = b"SIMF";
/// Flag bit (byte 6) of a draft frame.
pub const FLAG_DRAFT: u8 = 1;
/// Header version (byte 4).
pub const HEADER_VERSION: u8 = 1;
/// JPEG quality. Simulator choice: 85 keeps grey-level steps of 1 to 2 at 512 x 512 in about
/// 30 to 60 kB per frame.
pub const JPEG_QUALITY: u8 = 85;

/// Why a frame could not be encoded or parsed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// JPEG (and the header) hold at most 65,535 pixels per side.
    #[error("image of {width} x {height} pixels is too large for a JPEG frame")]
    TooLarge {
        /// Width, pixels.
        width: u32,
        /// Height, pixels.
        height: u32,
    },
    /// The JPEG encoder failed.
    #[error("JPEG encoding failed: {0}")]
    Jpeg(String),
    /// Not a version-1 frame.
    #[error("not a version-1 SIMF frame")]
    NotAFrame,
    /// A view code this build does not know.
    #[error("unknown view code {0}")]
    UnknownView(u8),
}

/// One frame ready to send.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EncodedFrame {
    /// Which view.
    pub view: ViewId,
    /// Frame sequence.
    pub frame_seq: u64,
    /// Last accepted input sequence reflected.
    pub input_seq: u64,
    /// Simulation time, ms.
    pub t_ms: u64,
    /// Width, pixels.
    pub width: u16,
    /// Height, pixels.
    pub height: u16,
    /// A draft (header flag [`FLAG_DRAFT`]): a cheaper preview of this input; the full frame
    /// of the same input follows unless newer input supersedes it.
    pub draft: bool,
    /// JPEG bytes.
    pub jpeg: Vec<u8>,
}

/// Grey JPEG of an image.
pub fn encode_jpeg(image: &Image) -> Result<Vec<u8>, FrameError> {
    let too_large = || FrameError::TooLarge {
        width: image.width,
        height: image.height,
    };
    let w = u16::try_from(image.width).map_err(|_| too_large())?;
    let h = u16::try_from(image.height).map_err(|_| too_large())?;
    let mut out = Vec::new();
    jpeg_encoder::Encoder::new(&mut out, JPEG_QUALITY)
        .encode(&image.pixels, w, h, jpeg_encoder::ColorType::Luma)
        .map_err(|e| FrameError::Jpeg(e.to_string()))?;
    Ok(out)
}

impl EncodedFrame {
    /// Encodes `image` with its sequence numbers.
    pub fn new(
        view: ViewId,
        frame_seq: u64,
        input_seq: u64,
        t_ms: u64,
        image: &Image,
    ) -> Result<EncodedFrame, FrameError> {
        Ok(EncodedFrame {
            view,
            frame_seq,
            input_seq,
            t_ms,
            width: image.width as u16,
            height: image.height as u16,
            draft: false,
            jpeg: encode_jpeg(image)?,
        })
    }

    /// The same frame marked as a draft or not.
    pub fn with_draft(self, draft: bool) -> EncodedFrame {
        EncodedFrame { draft, ..self }
    }

    /// The binary message: header then JPEG.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(HEADER_BYTES + self.jpeg.len());
        b.extend_from_slice(MAGIC);
        b.push(HEADER_VERSION);
        b.push(self.view.code());
        b.push(if self.draft { FLAG_DRAFT } else { 0 });
        b.push(0);
        b.extend_from_slice(&self.frame_seq.to_le_bytes());
        b.extend_from_slice(&self.input_seq.to_le_bytes());
        b.extend_from_slice(&self.t_ms.to_le_bytes());
        b.extend_from_slice(&self.width.to_le_bytes());
        b.extend_from_slice(&self.height.to_le_bytes());
        b.extend_from_slice(&[0; 4]);
        b.extend_from_slice(&self.jpeg);
        b
    }

    /// Parses a binary message.
    pub fn parse(b: &[u8]) -> Result<EncodedFrame, FrameError> {
        if b.len() < HEADER_BYTES || &b[0..4] != MAGIC || b[4] != HEADER_VERSION {
            return Err(FrameError::NotAFrame);
        }
        let u64_at = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap_or([0; 8]));
        let u16_at = |i: usize| u16::from_le_bytes([b[i], b[i + 1]]);
        Ok(EncodedFrame {
            view: ViewId::from_code(b[5]).ok_or(FrameError::UnknownView(b[5]))?,
            frame_seq: u64_at(8),
            input_seq: u64_at(16),
            t_ms: u64_at(24),
            width: u16_at(32),
            height: u16_at(34),
            draft: b[6] & FLAG_DRAFT != 0,
            jpeg: b[HEADER_BYTES..].to_vec(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trips_and_jpeg_is_a_jpeg() {
        let image = Image {
            width: 16,
            height: 8,
            pixels: (0..128).map(|i| (i * 2) as u8).collect(),
        };
        let f = EncodedFrame::new(ViewId::FLUOROSCOPY, 7, 42, 1234, &image).unwrap();
        assert_eq!(&f.jpeg[0..2], &[0xFF, 0xD8], "JPEG SOI marker");
        assert_eq!(
            &f.jpeg[f.jpeg.len() - 2..],
            &[0xFF, 0xD9],
            "JPEG EOI marker"
        );
        let back = EncodedFrame::parse(&f.to_bytes()).unwrap();
        assert_eq!(back, f);
        assert!(!back.draft);
        assert_eq!(
            f.to_bytes()[6],
            0,
            "a full frame's flags are 0, as before drafts"
        );
        let d = f.clone().with_draft(true);
        assert_eq!(d.to_bytes()[6], FLAG_DRAFT);
        assert_eq!(EncodedFrame::parse(&d.to_bytes()).unwrap(), d);
        assert!(EncodedFrame::parse(b"nope").is_err());
    }
}
