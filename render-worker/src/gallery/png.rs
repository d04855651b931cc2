//! A minimal PNG writer for 8-bit greyscale images (PNG 1.2: signature, IHDR, one zlib IDAT with
//! filter type 0 on every row, IEND; chunk CRC-32 over type and data).

use std::io::Write;

use flate2::Compression;
use flate2::write::ZlibEncoder;

/// The eight bytes every PNG file starts with.
const SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1a, b'\n'];

/// Encodes `pixels` (row-major, `width * height` grey levels) as a PNG file.
pub fn encode_grey(width: u32, height: u32, pixels: &[u8]) -> std::io::Result<Vec<u8>> {
    let (w, h) = (width as usize, height as usize);
    if width == 0 || height == 0 || pixels.len() != w * h {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!(
                "a {width} x {height} image needs {} pixels, got {}",
                w * h,
                pixels.len()
            ),
        ));
    }
    let mut out = SIGNATURE.to_vec();
    let mut ihdr = Vec::with_capacity(13);
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    // Bit depth 8, colour type 0 (greyscale), deflate, adaptive filtering, no interlace.
    ihdr.extend_from_slice(&[8, 0, 0, 0, 0]);
    chunk(&mut out, b"IHDR", &ihdr);
    let mut z = ZlibEncoder::new(Vec::new(), Compression::default());
    for row in pixels.chunks_exact(w) {
        z.write_all(&[0])?;
        z.write_all(row)?;
    }
    chunk(&mut out, b"IDAT", &z.finish()?);
    chunk(&mut out, b"IEND", &[]);
    Ok(out)
}

fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let mut crc = crc32fast::Hasher::new();
    crc.update(kind);
    crc.update(data);
    out.extend_from_slice(&crc.finalize().to_be_bytes());
}

/// Reads back a file written by [`encode_grey`] (tests and the gallery's own checks): width,
/// height and pixels; `None` for anything else.
pub fn decode_grey(bytes: &[u8]) -> Option<(u32, u32, Vec<u8>)> {
    use std::io::Read;
    let mut rest = bytes.strip_prefix(&SIGNATURE[..])?;
    let (mut width, mut height, mut idat) = (0u32, 0u32, Vec::new());
    while rest.len() >= 12 {
        let len = u32::from_be_bytes(rest[..4].try_into().ok()?) as usize;
        let kind: [u8; 4] = rest[4..8].try_into().ok()?;
        let data = rest.get(8..8 + len)?;
        let crc = u32::from_be_bytes(rest.get(8 + len..12 + len)?.try_into().ok()?);
        let mut h = crc32fast::Hasher::new();
        h.update(&kind);
        h.update(data);
        if h.finalize() != crc {
            return None;
        }
        match &kind {
            b"IHDR" => {
                width = u32::from_be_bytes(data.get(..4)?.try_into().ok()?);
                height = u32::from_be_bytes(data.get(4..8)?.try_into().ok()?);
                if data.get(8..13)? != [8, 0, 0, 0, 0] {
                    return None;
                }
            }
            b"IDAT" => idat.extend_from_slice(data),
            b"IEND" => break,
            _ => {}
        }
        rest = &rest[12 + len..];
    }
    let mut raw = Vec::new();
    flate2::read::ZlibDecoder::new(&idat[..])
        .read_to_end(&mut raw)
        .ok()?;
    let w = width as usize;
    let mut pixels = Vec::with_capacity(w * height as usize);
    for row in raw.chunks_exact(w + 1) {
        if row[0] != 0 {
            return None;
        }
        pixels.extend_from_slice(&row[1..]);
    }
    (pixels.len() == w * height as usize && w > 0).then_some((width, height, pixels))
}
