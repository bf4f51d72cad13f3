//! JPEG decoding through libjpeg-turbo (TurboJPEG API of the system library), so that the
//! pixels are the ones OpenCV's `imread` — and hence dlib's tools and its reference
//! landmarks — see: accurate integer IDCT (ISLOW), fancy (triangular) chroma upsampling,
//! libjpeg's YCbCr → RGB tables. See docs/decisions/0501-jpeg-decoder.md.
//!
//! The C library reports errors through `setjmp`/`longjmp` inside TurboJPEG itself; on the
//! Rust side every call is a plain return code, so nothing unwinds across the boundary.
//! Warnings (corrupt entropy data, a premature end of file) are not fatal, as in OpenCV:
//! the image decoded so far is returned (libjpeg fills what it could not decode in grey).
//! (TurboJPEG 2.1 reports an error that follows a warning in the same file as a warning: such
//! a file also yields its decoded part, never uninitialised memory — the buffer is zeroed.)

use std::ffi::{CStr, c_int, c_ulong};

use image::RgbImage;
use image::metadata::Orientation;
use turbojpeg_sys as tj;

use super::{DecodeError, DecodeLimits};

/// An initialised TurboJPEG decompressor, destroyed on drop. One per decode: a handle
/// holds per-image state and is not shared between threads.
struct Decompressor(tj::tjhandle);

impl Decompressor {
    fn new() -> Result<Self, DecodeError> {
        // SAFETY: no arguments; a null return is handled.
        let handle = unsafe { tj::tjInitDecompress() };
        if handle.is_null() {
            return Err(DecodeError::AllocationLimit {
                format: "JPEG".into(),
                reason: "libjpeg-turbo could not allocate a decompressor".into(),
            });
        }
        Ok(Self(handle))
    }

    /// Whether the last failed call only raised a warning (the output is still usable).
    fn last_was_warning(&self) -> bool {
        // SAFETY: the handle is valid for self's lifetime.
        unsafe { tj::tjGetErrorCode(self.0) == tj::TJERR_TJERR_WARNING as c_int }
    }

    fn last_error(&self) -> DecodeError {
        // SAFETY: the handle is valid; TurboJPEG returns a NUL-terminated string it owns
        // (never null for a valid handle), copied out before the next call.
        let msg = unsafe {
            let p = tj::tjGetErrorStr2(self.0);
            if p.is_null() {
                "unknown libjpeg-turbo error".into()
            } else {
                CStr::from_ptr(p).to_string_lossy().into_owned()
            }
        };
        // TurboJPEG prefixes its own messages with the function name: not useful to a user.
        let reason = match msg.split_once("(): ") {
            Some((_, rest)) => rest.to_string(),
            None => msg,
        };
        DecodeError::Corrupt { format: "JPEG".into(), reason }
    }
}

impl Drop for Decompressor {
    fn drop(&mut self) {
        // SAFETY: created by tjInitDecompress, destroyed exactly once.
        unsafe {
            tj::tjDestroy(self.0);
        }
    }
}

/// Decodes JPEG bytes (already checked against `limits.max_encoded_bytes`) into RGB,
/// the EXIF orientation applied.
pub(super) fn decode(bytes: &[u8], limits: &DecodeLimits) -> Result<RgbImage, DecodeError> {
    let len = c_ulong::try_from(bytes.len())
        .map_err(|_| DecodeError::EncodedTooLarge { bytes: bytes.len(), limit: limits.max_encoded_bytes })?;
    let d = Decompressor::new()?;
    let (mut width, mut height, mut subsamp, mut colorspace) = (0 as c_int, 0 as c_int, 0 as c_int, 0 as c_int);
    // SAFETY: `bytes` outlives the call and `len` is its length; the out-pointers are valid.
    let rc = unsafe {
        tj::tjDecompressHeader3(d.0, bytes.as_ptr(), len, &mut width, &mut height, &mut subsamp, &mut colorspace)
    };
    // A warning while reading the header (e.g. data ending inside it) is fatal only when no
    // image size came out of it.
    if rc != 0 && (!d.last_was_warning() || width <= 0 || height <= 0) {
        return Err(d.last_error());
    }
    // libjpeg limits dimensions to 65500, so these are positive and fit in u32.
    let (w, h) = (u32::try_from(width).unwrap_or(0), u32::try_from(height).unwrap_or(0));
    if w == 0 || h == 0 {
        return Err(DecodeError::ZeroSize { width: w, height: h });
    }
    let pixels = u64::from(w) * u64::from(h);
    if pixels > limits.max_pixels {
        return Err(DecodeError::TooManyPixels { width: w, height: h, pixels, limit: limits.max_pixels });
    }

    // CMYK and YCCK (Adobe) JPEGs: libjpeg converts YCCK → CMYK but not CMYK → RGB; the
    // conversion below is the one the `image` crate applies (Adobe's inverted CMYK).
    let cmyk = colorspace == tj::TJCS_TJCS_CMYK as c_int || colorspace == tj::TJCS_TJCS_YCCK as c_int;
    let (format, channels) = if cmyk { (tj::TJPF_TJPF_CMYK, 4) } else { (tj::TJPF_TJPF_RGB, 3) };
    let size = usize::try_from(pixels * channels).map_err(|_| too_much_memory(pixels))?;
    let mut buf = Vec::new();
    buf.try_reserve_exact(size).map_err(|_| too_much_memory(pixels))?;
    buf.resize(size, 0u8);
    // Default flags = OpenCV's settings: ISLOW IDCT, fancy upsampling, top-down rows. The
    // scan limit refuses progressive files with more than 500 scans (a CPU-time bomb: each
    // scan re-walks the whole coefficient buffer); no real encoder writes more than ~10.
    let flags = tj::TJFLAG_LIMITSCANS as c_int;
    // SAFETY: `buf` holds exactly width × height × channels bytes, the size TurboJPEG
    // writes for this pixel format and pitch; `bytes` is valid for `len` bytes.
    let rc = unsafe {
        tj::tjDecompress2(
            d.0,
            bytes.as_ptr(),
            len,
            buf.as_mut_ptr(),
            width,
            width * channels as c_int,
            height,
            format as c_int,
            flags,
        )
    };
    if rc != 0 && !d.last_was_warning() {
        return Err(d.last_error());
    }
    let rgb = if cmyk { cmyk_to_rgb(&buf) } else { buf };
    let rgb = RgbImage::from_raw(w, h, rgb).ok_or_else(|| too_much_memory(pixels))?; // sized above: never fails
    let mut image = image::DynamicImage::ImageRgb8(rgb);
    image.apply_orientation(exif_orientation(bytes).unwrap_or(Orientation::NoTransforms));
    Ok(image.into_rgb8())
}

fn too_much_memory(pixels: u64) -> DecodeError {
    DecodeError::AllocationLimit { format: "JPEG".into(), reason: format!("no memory for {pixels} pixels") }
}

/// Adobe CMYK as libjpeg returns it (stored inverted: 255 = no ink) → RGB, each channel
/// times K / 255, rounded.
fn cmyk_to_rgb(cmyk: &[u8]) -> Vec<u8> {
    let mul = |a: u8, k: u8| {
        let t = u32::from(a) * u32::from(k) + 128;
        (((t >> 8) + t) >> 8) as u8
    };
    cmyk.chunks_exact(4).flat_map(|p| [mul(p[0], p[3]), mul(p[1], p[3]), mul(p[2], p[3])]).collect()
}

/// The EXIF orientation of a JPEG: the first APP1 segment holding "Exif\0\0" before the
/// first scan. Walks the marker segments by their lengths, never past the end of `bytes`;
/// anything malformed means "no orientation" (the photo stays as stored).
fn exif_orientation(bytes: &[u8]) -> Option<Orientation> {
    let mut pos = 2; // after SOI
    loop {
        // Markers may be preceded by fill bytes 0xFF.
        if *bytes.get(pos)? != 0xFF {
            return None;
        }
        while *bytes.get(pos)? == 0xFF {
            pos += 1;
        }
        let marker = *bytes.get(pos)?;
        pos += 1;
        match marker {
            0xDA | 0xD9 => return None,     // start of scan / end of image: no EXIF before the pixels
            0x01 | 0xD0..=0xD7 => continue, // standalone markers, no length
            _ => {}
        }
        let len = usize::from(u16::from_be_bytes([*bytes.get(pos)?, *bytes.get(pos + 1)?]));
        let segment = bytes.get(pos + 2..pos.checked_add(len)?)?;
        if marker == 0xE1
            && let Some(tiff) = segment.strip_prefix(b"Exif\0\0")
        {
            return Orientation::from_exif_chunk(tiff);
        }
        pos += len.max(2);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decode::decode;

    /// Encodes `pixels` (in `pf` layout) with libjpeg-turbo's encoder at quality 100.
    fn tj_compress(pixels: &[u8], w: i32, h: i32, pf: tj::TJPF, subsamp: tj::TJSAMP, flags: u32) -> Vec<u8> {
        // SAFETY: test helper; `pixels` holds w × h pixels of `pf`, TurboJPEG allocates the
        // output, copied out and freed with tjFree.
        unsafe {
            let h_ = tj::tjInitCompress();
            assert!(!h_.is_null());
            let (mut out, mut size) = (std::ptr::null_mut(), 0);
            let rc = tj::tjCompress2(
                h_,
                pixels.as_ptr(),
                w,
                0,
                h,
                pf,
                &mut out,
                &mut size,
                subsamp as c_int,
                100,
                flags as c_int,
            );
            assert_eq!(rc, 0);
            let v = std::slice::from_raw_parts(out, size as usize).to_vec();
            tj::tjFree(out);
            tj::tjDestroy(h_);
            v
        }
    }

    fn gradient(w: u32, h: u32, channels: u32) -> Vec<u8> {
        (0..w * h * channels)
            .map(|i| {
                let (p, c) = (i / channels, i % channels);
                ((p % w) * 4 + (p / w) * 2 + c * 20) as u8
            })
            .collect()
    }

    fn max_diff(a: &[u8], b: &[u8]) -> u8 {
        assert_eq!(a.len(), b.len());
        a.iter().zip(b).map(|(x, y)| x.abs_diff(*y)).max().unwrap_or(0)
    }

    #[test]
    fn baseline_and_progressive_give_the_same_pixels() {
        // Progressive coding rearranges the same quantised coefficients: identical output.
        let src = gradient(37, 23, 3);
        let base = tj_compress(&src, 37, 23, tj::TJPF_TJPF_RGB, tj::TJSAMP_TJSAMP_420, 0);
        let prog = tj_compress(&src, 37, 23, tj::TJPF_TJPF_RGB, tj::TJSAMP_TJSAMP_420, tj::TJFLAG_PROGRESSIVE);
        assert_ne!(base, prog);
        let (a, b) = (decode(&base).unwrap(), decode(&prog).unwrap());
        assert_eq!(a.dimensions(), (37, 23));
        assert_eq!(a, b);
        assert!(max_diff(a.as_raw(), &src) <= 6, "{}", max_diff(a.as_raw(), &src));
    }

    #[test]
    fn grey_jpeg_is_replicated() {
        let src = gradient(16, 9, 1);
        let out = decode(&tj_compress(&src, 16, 9, tj::TJPF_TJPF_GRAY, tj::TJSAMP_TJSAMP_GRAY, 0)).unwrap();
        for (p, g) in out.pixels().zip(&src) {
            assert_eq!(p.0[0], p.0[1]);
            assert_eq!(p.0[1], p.0[2]);
            assert!(p.0[0].abs_diff(*g) <= 2, "{} vs {g}", p.0[0]);
        }
    }

    #[test]
    fn cmyk_jpeg_becomes_rgb() {
        // TurboJPEG writes CMYK input as an Adobe YCCK JPEG: the YCCK → CMYK → RGB path.
        let src = gradient(16, 16, 4);
        let out = decode(&tj_compress(&src, 16, 16, tj::TJPF_TJPF_CMYK, tj::TJSAMP_TJSAMP_444, 0)).unwrap();
        let expect: Vec<u8> = src
            .chunks_exact(4)
            .flat_map(|p| (0..3).map(move |c| (f64::from(p[c]) * f64::from(p[3]) / 255.0).round() as u8))
            .collect();
        assert!(max_diff(out.as_raw(), &expect) <= 4, "{}", max_diff(out.as_raw(), &expect));
    }

    /// The last scan (SOS … before EOI) of a progressive JPEG repeated `n` more times.
    fn with_repeated_last_scan(jpeg: &[u8], n: usize) -> Vec<u8> {
        let sos = jpeg.windows(2).rposition(|w| w == [0xFF, 0xDA]).unwrap();
        let eoi = jpeg.len() - 2;
        assert_eq!(&jpeg[eoi..], &[0xFF, 0xD9]);
        let mut out = jpeg[..eoi].to_vec();
        for _ in 0..n {
            out.extend_from_slice(&jpeg[sos..eoi]);
        }
        out.extend_from_slice(&jpeg[eoi..]);
        out
    }

    #[test]
    fn progressive_scan_bomb_is_refused() {
        let prog =
            tj_compress(&gradient(8, 8, 3), 8, 8, tj::TJPF_TJPF_RGB, tj::TJSAMP_TJSAMP_444, tj::TJFLAG_PROGRESSIVE);
        // A few extra scans: a bogus progression is only a warning, the image comes out.
        assert!(decode(&with_repeated_last_scan(&prog, 3)).is_ok());
        match decode(&with_repeated_last_scan(&prog, 600)) {
            Err(DecodeError::Corrupt { reason, .. }) => {
                assert!(reason.contains("500 scans"), "{reason}")
            }
            other => panic!("expected a scan-limit error, got {other:?}"),
        }
    }

    /// A baseline JPEG with its SOF0 fields patched: sample precision, height, width.
    fn with_sof(jpeg: &[u8], precision: u8, w: u16, h: u16) -> Vec<u8> {
        let mut out = jpeg.to_vec();
        let sof = out.windows(2).position(|m| m == [0xFF, 0xC0]).unwrap();
        out[sof + 4] = precision;
        out[sof + 5..sof + 7].copy_from_slice(&h.to_be_bytes());
        out[sof + 7..sof + 9].copy_from_slice(&w.to_be_bytes());
        out
    }

    #[test]
    fn size_is_checked_from_the_header_and_odd_precision_is_an_error() {
        let jpeg = tj_compress(&gradient(8, 8, 3), 8, 8, tj::TJPF_TJPF_RGB, tj::TJSAMP_TJSAMP_444, 0);
        // 60000 × 60000 claimed by an 8×8 file: refused before any pixel buffer exists.
        match decode(&with_sof(&jpeg, 8, 60000, 60000)) {
            Err(DecodeError::TooManyPixels { width: 60000, height: 60000, .. }) => {}
            other => panic!("expected TooManyPixels, got {other:?}"),
        }
        let limits = DecodeLimits { max_encoded_bytes: 1 << 20, max_pixels: 63 };
        assert!(matches!(super::decode(&jpeg, &limits), Err(DecodeError::TooManyPixels { pixels: 64, .. })));
        // Zero height in SOF: libjpeg refuses it ("Empty JPEG image").
        assert!(matches!(
            decode(&with_sof(&jpeg, 8, 8, 0)),
            Err(DecodeError::Corrupt { .. }) | Err(DecodeError::ZeroSize { .. })
        ));
        // 12-bit samples: not supported by this libjpeg build — a clear error, not a panic.
        match decode(&with_sof(&jpeg, 12, 8, 8)) {
            Err(DecodeError::Corrupt { reason, .. }) => {
                assert!(reason.contains("precision"), "{reason}")
            }
            other => panic!("expected an unsupported-precision error, got {other:?}"),
        }
    }

    #[test]
    fn corrupt_entropy_data_is_a_warning_not_an_error() {
        // As in OpenCV: damaged scan data still yields an image (what libjpeg could decode).
        let src = gradient(64, 48, 3);
        let mut jpeg = tj_compress(&src, 64, 48, tj::TJPF_TJPF_RGB, tj::TJSAMP_TJSAMP_420, 0);
        let n = jpeg.len();
        for b in &mut jpeg[n - 60..n - 10] {
            *b = 0xFF; // markers where entropy data should be
        }
        assert_eq!(decode(&jpeg).unwrap().dimensions(), (64, 48));
    }

    #[test]
    fn cmyk_conversion_is_the_rounded_product() {
        // Brute force against the exact rounded product for every (a, k).
        for a in 0..=255u8 {
            for k in 0..=255u8 {
                let expect = (f64::from(a) * f64::from(k) / 255.0).round() as u8;
                assert_eq!(cmyk_to_rgb(&[a, a, a, k]), vec![expect; 3], "a {a} k {k}");
            }
        }
    }

    #[test]
    fn exif_walk_survives_malformed_segments() {
        assert_eq!(exif_orientation(&[0xFF, 0xD8]), None);
        assert_eq!(exif_orientation(&[0xFF, 0xD8, 0xFF, 0xE1, 0xFF, 0xFF, 0x00]), None); // length past end
        assert_eq!(exif_orientation(&[0xFF, 0xD8, 0xFF, 0xE1, 0x00]), None); // cut inside length
        assert_eq!(exif_orientation(&[0xFF, 0xD8, 0xFF, 0xE0, 0x00, 0x00, 0xFF, 0xD9]), None); // length 0
        assert_eq!(exif_orientation(&[0xFF, 0xD8, 0x12, 0x34]), None); // not a marker
        for n in 0..64 {
            let bytes: Vec<u8> = (0..n).map(|i| [0xFF, 0xE1, 0x00, 0x03][i % 4]).collect();
            let _ = exif_orientation(&bytes); // never panics, always terminates
        }
    }
}
