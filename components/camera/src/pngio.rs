//! PNG files of RGBD frames: 8-bit RGB colour and 16-bit grey depth (counts of the stream's
//! depth unit, 0 = no depth), the format RealSense tools and TUM RGB-D use. Every error
//! names the file.

use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::Path;

use crate::CameraError;

fn image_err(path: &Path, problem: impl Into<String>) -> CameraError {
    CameraError::Image {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

fn encode(
    path: &Path,
    w: u32,
    h: u32,
    color: png::ColorType,
    depth: png::BitDepth,
    data: &[u8],
) -> Result<(), CameraError> {
    let file = File::create(path).map_err(|cause| CameraError::Write {
        path: path.to_path_buf(),
        cause,
    })?;
    let mut enc = png::Encoder::new(BufWriter::new(file), w, h);
    enc.set_color(color);
    enc.set_depth(depth);
    enc.set_compression(png::Compression::Fast);
    let png_err = |e: png::EncodingError| match e {
        png::EncodingError::IoError(source) => CameraError::Write {
            path: path.to_path_buf(),
            cause: source,
        },
        other => image_err(path, format!("cannot encode PNG: {other}")),
    };
    let mut writer = enc.write_header().map_err(png_err)?;
    writer.write_image_data(data).map_err(png_err)?;
    writer.finish().map_err(png_err)
}

/// Writes an RGB8 image (`w·h·3` bytes).
pub fn write_rgb_png(path: &Path, w: u32, h: u32, rgb: &[u8]) -> Result<(), CameraError> {
    if rgb.len() != w as usize * h as usize * 3 {
        return Err(image_err(
            path,
            format!("{} bytes is not a {w}x{h} RGB8 image", rgb.len()),
        ));
    }
    encode(path, w, h, png::ColorType::Rgb, png::BitDepth::Eight, rgb)
}

/// Writes a 16-bit greyscale depth image. `scratch` is reused for the big-endian samples.
pub fn write_depth_png(path: &Path, w: u32, h: u32, depth: &[u16], scratch: &mut Vec<u8>) -> Result<(), CameraError> {
    if depth.len() != w as usize * h as usize {
        return Err(image_err(
            path,
            format!("{} samples is not a {w}x{h} depth image", depth.len()),
        ));
    }
    scratch.clear();
    scratch.extend(depth.iter().flat_map(|d| d.to_be_bytes()));
    encode(path, w, h, png::ColorType::Grayscale, png::BitDepth::Sixteen, scratch)
}

/// Opens a PNG and checks its size before anything is decoded (a corrupt header cannot
/// make us allocate an absurd frame).
fn open_png(path: &Path, w: u32, h: u32) -> Result<png::Reader<BufReader<File>>, CameraError> {
    let file = File::open(path).map_err(|cause| CameraError::Read {
        path: path.to_path_buf(),
        cause,
    })?;
    let mut dec = png::Decoder::new(BufReader::new(file));
    let hdr = dec
        .read_header_info()
        .map_err(|e| image_err(path, format!("not a readable PNG: {e}")))?;
    if hdr.width != w || hdr.height != h {
        return Err(image_err(
            path,
            format!("is {}x{}, the recording says {w}x{h}", hdr.width, hdr.height),
        ));
    }
    dec.read_info()
        .map_err(|e| image_err(path, format!("not a readable PNG: {e}")))
}

/// Reads an 8-bit RGB (or RGBA, alpha dropped) PNG of exactly `w`×`h` into `rgb`.
/// `scratch` is reused for the decoded rows.
pub fn read_rgb_png(path: &Path, w: u32, h: u32, rgb: &mut [u8], scratch: &mut Vec<u8>) -> Result<(), CameraError> {
    let px = w as usize * h as usize;
    if rgb.len() != px * 3 {
        return Err(image_err(
            path,
            format!("output buffer of {} bytes is not {w}x{h} RGB8", rgb.len()),
        ));
    }
    let mut reader = open_png(path, w, h)?;
    let (ct, bd) = reader.output_color_type();
    let channels = match (ct, bd) {
        (png::ColorType::Rgb, png::BitDepth::Eight) => 3,
        (png::ColorType::Rgba, png::BitDepth::Eight) => 4,
        _ => {
            return Err(image_err(
                path,
                format!("colour must be 8-bit RGB or RGBA, found {ct:?} {bd:?}"),
            ))
        }
    };
    if channels == 3 {
        reader
            .next_frame(rgb)
            .map_err(|e| image_err(path, format!("corrupt image data: {e}")))?;
    } else {
        scratch.resize(px * 4, 0);
        reader
            .next_frame(scratch)
            .map_err(|e| image_err(path, format!("corrupt image data: {e}")))?;
        for (o, i) in rgb.chunks_exact_mut(3).zip(scratch.chunks_exact(4)) {
            o.copy_from_slice(&i[..3]);
        }
    }
    Ok(())
}

/// Reads a 16-bit greyscale PNG of exactly `w`×`h` into `depth`.
pub fn read_depth_png(
    path: &Path,
    w: u32,
    h: u32,
    depth: &mut [u16],
    scratch: &mut Vec<u8>,
) -> Result<(), CameraError> {
    let px = w as usize * h as usize;
    if depth.len() != px {
        return Err(image_err(
            path,
            format!("output buffer of {} samples is not {w}x{h}", depth.len()),
        ));
    }
    let mut reader = open_png(path, w, h)?;
    let (ct, bd) = reader.output_color_type();
    if (ct, bd) != (png::ColorType::Grayscale, png::BitDepth::Sixteen) {
        return Err(image_err(
            path,
            format!("depth must be 16-bit greyscale, found {ct:?} {bd:?}"),
        ));
    }
    scratch.resize(px * 2, 0);
    reader
        .next_frame(scratch)
        .map_err(|e| image_err(path, format!("corrupt image data: {e}")))?;
    for (d, b) in depth.iter_mut().zip(scratch.chunks_exact(2)) {
        *d = u16::from_be_bytes([b[0], b[1]]);
    }
    Ok(())
}

/// Turbo colour map (Mikhailov 2019, polynomial fit), `x` in [0, 1].
pub fn turbo(x: f64) -> [u8; 3] {
    let x = x.clamp(0.0, 1.0);
    let r =
        0.13572138 + x * (4.61539260 + x * (-42.66032258 + x * (132.13108234 + x * (-152.94239396 + x * 59.28637943))));
    let g = 0.09140261 + x * (2.19418839 + x * (4.84296658 + x * (-14.18503333 + x * (4.27729857 + x * 2.82956604))));
    let b =
        0.10667330 + x * (12.64194608 + x * (-60.58204836 + x * (110.36276771 + x * (-89.90310912 + x * 27.34824973))));
    let q = |c: f64| (c.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    [q(r), q(g), q(b)]
}

/// A false-colour view of a depth image for people: near = red, far = blue (turbo map
/// between the 0.1st and 99.9th percentile of valid depths), no depth = black.
pub fn depth_preview(depth: &[u16]) -> Vec<u8> {
    let mut valid: Vec<u16> = depth.iter().copied().filter(|&d| d > 0).collect();
    let mut out = vec![0u8; depth.len() * 3];
    if valid.is_empty() {
        return out;
    }
    valid.sort_unstable();
    let lo = valid[valid.len() / 1000] as f64;
    let hi = valid[valid.len() - 1 - valid.len() / 1000] as f64;
    let span = (hi - lo).max(1.0);
    for (o, &d) in out.chunks_exact_mut(3).zip(depth) {
        if d > 0 {
            o.copy_from_slice(&turbo(1.0 - (d as f64 - lo) / span));
        }
    }
    out
}
