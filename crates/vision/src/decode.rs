//! Decoding photos with limits: JPEG, PNG and WebP bytes → an 8-bit RGB image, the EXIF
//! orientation applied.
//!
//! JPEG goes through libjpeg-turbo (`decode/jpeg.rs`), for the same pixels as OpenCV and dlib (the
//! landmark model was trained and is checked on them); PNG and WebP through the `image`
//! crate.
//!
//! Untrusted bytes are checked in this order, so that nothing large is allocated from a header
//! value: the encoded size against [`DecodeLimits::max_encoded_bytes`]; the format from the
//! magic bytes; the width × height read from the header against
//! [`DecodeLimits::max_pixels`] (a decompression bomb — a tiny file claiming a huge image —
//! is refused here, before any pixel buffer exists); only then the pixels are decoded (for
//! PNG and WebP with `image`'s own allocation limit set as a second fence).
//!
//! Every pixel layout the decoders produce (8/16-bit, grey, grey + alpha, RGB, RGBA) becomes
//! `RgbImage`: 16-bit samples are scaled to 8 bits, grey is replicated, alpha is dropped
//! (the colour channels are kept as stored, not composited over a background).

use std::io::Cursor;

use image::{DynamicImage, ImageDecoder, ImageError, ImageFormat, ImageReader, RgbImage};

mod jpeg;

/// Limits applied to every decode. The defaults suit photos sent to a service.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DecodeLimits {
    /// Largest accepted encoded input, in bytes. Default 50 MiB.
    pub max_encoded_bytes: usize,
    /// Largest accepted width × height, read from the header before decoding.
    /// Default 50 megapixels (e.g. 8660 × 5773).
    pub max_pixels: u64,
}

impl DecodeLimits {
    pub const DEFAULT_MAX_ENCODED_BYTES: usize = 50 * 1024 * 1024;
    pub const DEFAULT_MAX_PIXELS: u64 = 50_000_000;
}

impl Default for DecodeLimits {
    fn default() -> Self {
        Self { max_encoded_bytes: Self::DEFAULT_MAX_ENCODED_BYTES, max_pixels: Self::DEFAULT_MAX_PIXELS }
    }
}

/// Why bytes could not be turned into an image.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    #[error("empty input: no image bytes")]
    Empty,
    #[error("encoded image too large: {bytes} bytes, the limit is {limit} bytes")]
    EncodedTooLarge { bytes: usize, limit: usize },
    #[error("unknown image format: the bytes are not JPEG, PNG or WebP")]
    UnknownFormat,
    #[error("unsupported image format {format}: only JPEG, PNG and WebP are accepted")]
    UnsupportedFormat { format: String },
    #[error("image too large: {width}×{height} = {pixels} pixels, the limit is {limit} pixels")]
    TooManyPixels { width: u32, height: u32, pixels: u64, limit: u64 },
    #[error("image has zero size ({width}×{height})")]
    ZeroSize { width: u32, height: u32 },
    #[error("corrupt or truncated {format} image: {reason}")]
    Corrupt { format: String, reason: String },
    #[error("decoding the {format} image needs more memory than allowed: {reason}")]
    AllocationLimit { format: String, reason: String },
}

/// Decodes with the default [`DecodeLimits`].
pub fn decode(bytes: &[u8]) -> Result<RgbImage, DecodeError> {
    decode_with_limits(bytes, &DecodeLimits::default())
}

/// Decodes JPEG, PNG or WebP bytes into RGB, EXIF orientation applied, within `limits`.
pub fn decode_with_limits(bytes: &[u8], limits: &DecodeLimits) -> Result<RgbImage, DecodeError> {
    if bytes.is_empty() {
        return Err(DecodeError::Empty);
    }
    if bytes.len() > limits.max_encoded_bytes {
        return Err(DecodeError::EncodedTooLarge { bytes: bytes.len(), limit: limits.max_encoded_bytes });
    }
    let format = image::guess_format(bytes).map_err(|_| DecodeError::UnknownFormat)?;
    let name = format_name(format);
    if !matches!(format, ImageFormat::Jpeg | ImageFormat::Png | ImageFormat::WebP) {
        return Err(DecodeError::UnsupportedFormat { format: name });
    }
    if format == ImageFormat::Jpeg {
        return jpeg::decode(bytes, limits);
    }

    let mut reader = ImageReader::with_format(Cursor::new(bytes), format);
    let mut image_limits = image::Limits::default();
    // The output buffer of the largest accepted image at 16 bits × 4 channels, plus the
    // decoders' working memory: a fence behind the header check below.
    image_limits.max_alloc = Some(limits.max_pixels.saturating_mul(8).saturating_add(64 << 20));
    reader.limits(image_limits);
    let mut decoder = reader.into_decoder().map_err(|e| map_error(e, &name))?;

    let (width, height) = decoder.dimensions();
    if width == 0 || height == 0 {
        return Err(DecodeError::ZeroSize { width, height });
    }
    let pixels = u64::from(width) * u64::from(height);
    if pixels > limits.max_pixels {
        return Err(DecodeError::TooManyPixels { width, height, pixels, limit: limits.max_pixels });
    }
    // A malformed EXIF block is not worth refusing the photo for: keep it upright as stored.
    let orientation = decoder.orientation().unwrap_or(image::metadata::Orientation::NoTransforms);
    let mut image = DynamicImage::from_decoder(decoder).map_err(|e| map_error(e, &name))?;
    image.apply_orientation(orientation);
    Ok(match image {
        DynamicImage::ImageRgb8(rgb) => rgb,
        other => other.to_rgb8(),
    })
}

fn format_name(format: ImageFormat) -> String {
    match format {
        ImageFormat::Jpeg => "JPEG".into(),
        ImageFormat::Png => "PNG".into(),
        ImageFormat::WebP => "WebP".into(),
        other => format!("{other:?}"),
    }
}

fn map_error(e: ImageError, format: &str) -> DecodeError {
    let format = format.to_string();
    match e {
        ImageError::Limits(l) => DecodeError::AllocationLimit { format, reason: l.to_string() },
        ImageError::Unsupported(u) => DecodeError::Corrupt { format, reason: format!("unsupported feature: {u}") },
        ImageError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            DecodeError::Corrupt { format, reason: "unexpected end of data (truncated)".into() }
        }
        other => DecodeError::Corrupt { format, reason: other.to_string() },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{ImageBuffer, ImageEncoder, Luma, LumaA, Rgb, Rgba};

    fn png_bytes<P: image::PixelWithColorType>(img: &ImageBuffer<P, Vec<P::Subpixel>>) -> Vec<u8>
    where
        [P::Subpixel]: image::EncodableLayout,
    {
        let mut out = Vec::new();
        image::codecs::png::PngEncoder::new(&mut out)
            .write_image(
                image::EncodableLayout::as_bytes(img.as_raw().as_slice()),
                img.width(),
                img.height(),
                P::COLOR_TYPE,
            )
            .unwrap();
        out
    }

    fn jpeg_bytes(img: &RgbImage) -> Vec<u8> {
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95)
            .write_image(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgb8)
            .unwrap();
        out
    }

    /// A 4-colour test card: quadrants red, green / blue, white (TL, TR / BL, BR).
    const QUAD: [[u8; 3]; 4] = [[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255]];
    fn quadrants(w: u32, h: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| {
            let q = (if y < h / 2 { 0 } else { 2 }) + (if x < w / 2 { 0 } else { 1 });
            Rgb(QUAD[q])
        })
    }
    /// Which test-card quadrant colour each quadrant of `img` shows (nearest colour).
    fn read_quadrants(img: &RgbImage) -> [usize; 4] {
        let (w, h) = img.dimensions();
        let probe = |x: u32, y: u32| {
            let p = img.get_pixel(x, y).0;
            (0..4)
                .min_by_key(|&q| (0..3).map(|c| (i32::from(p[c]) - i32::from(QUAD[q][c])).pow(2)).sum::<i32>())
                .unwrap()
        };
        [probe(w / 4, h / 4), probe(3 * w / 4, h / 4), probe(w / 4, 3 * h / 4), probe(3 * w / 4, 3 * h / 4)]
    }

    /// Inserts an APP1 EXIF segment (big-endian TIFF, one IFD entry: Orientation) after SOI.
    fn with_exif_orientation(jpeg: &[u8], orientation: u16) -> Vec<u8> {
        assert_eq!(&jpeg[..2], &[0xFF, 0xD8]);
        let mut tiff = Vec::new();
        tiff.extend_from_slice(b"MM\x00\x2A"); // big-endian TIFF magic
        tiff.extend_from_slice(&8u32.to_be_bytes()); // offset of IFD0
        tiff.extend_from_slice(&1u16.to_be_bytes()); // one entry
        tiff.extend_from_slice(&0x0112u16.to_be_bytes()); // tag: Orientation
        tiff.extend_from_slice(&3u16.to_be_bytes()); // type SHORT
        tiff.extend_from_slice(&1u32.to_be_bytes()); // count
        tiff.extend_from_slice(&orientation.to_be_bytes());
        tiff.extend_from_slice(&[0, 0]); // value padding to 4 bytes
        tiff.extend_from_slice(&0u32.to_be_bytes()); // no next IFD
        let mut payload = b"Exif\x00\x00".to_vec();
        payload.extend_from_slice(&tiff);
        let mut out = jpeg[..2].to_vec();
        out.extend_from_slice(&[0xFF, 0xE1]);
        out.extend_from_slice(&((payload.len() + 2) as u16).to_be_bytes());
        out.extend_from_slice(&payload);
        out.extend_from_slice(&jpeg[2..]);
        out
    }

    #[test]
    fn png_rgb8_round_trips_exactly() {
        let img = RgbImage::from_fn(7, 5, |x, y| Rgb([x as u8 * 30, y as u8 * 40, 77]));
        assert_eq!(decode(&png_bytes(&img)).unwrap(), img);
    }

    #[test]
    fn png_16bit_is_scaled_to_8bit() {
        let img: ImageBuffer<Rgb<u16>, Vec<u16>> =
            ImageBuffer::from_fn(4, 3, |x, y| Rgb([x as u16 * 20000, 65535, y as u16 * 257 * 100]));
        let out = decode(&png_bytes(&img)).unwrap();
        for (x, y, p) in out.enumerate_pixels() {
            let src = img.get_pixel(x, y).0;
            for c in 0..3 {
                let expect = (f64::from(src[c]) / 257.0).round() as i32;
                assert!((i32::from(p.0[c]) - expect).abs() <= 1, "{x},{y} c{c}");
            }
        }
    }

    #[test]
    fn grey_grey_alpha_and_rgba_become_rgb() {
        let grey: ImageBuffer<Luma<u8>, Vec<u8>> = ImageBuffer::from_fn(3, 2, |x, y| Luma([(x * 50 + y * 7) as u8]));
        let out = decode(&png_bytes(&grey)).unwrap();
        for (x, y, p) in out.enumerate_pixels() {
            let g = grey.get_pixel(x, y).0[0];
            assert_eq!(p.0, [g, g, g]);
        }
        let ga: ImageBuffer<LumaA<u8>, Vec<u8>> = ImageBuffer::from_fn(3, 2, |x, _| LumaA([x as u8 * 60, 0]));
        let out = decode(&png_bytes(&ga)).unwrap();
        assert_eq!(out.get_pixel(2, 1).0, [120, 120, 120]); // alpha dropped, not composited
        let grey16: ImageBuffer<Luma<u16>, Vec<u16>> = ImageBuffer::from_fn(2, 2, |_, _| Luma([257 * 200]));
        assert_eq!(decode(&png_bytes(&grey16)).unwrap().get_pixel(1, 1).0, [200; 3]);
        let rgba: ImageBuffer<Rgba<u8>, Vec<u8>> = ImageBuffer::from_fn(2, 2, |x, y| Rgba([10, x as u8, y as u8, 3]));
        let out = decode(&png_bytes(&rgba)).unwrap();
        assert_eq!(out.get_pixel(1, 1).0, [10, 1, 1]);
    }

    #[test]
    fn jpeg_decodes_close_to_source() {
        let img = quadrants(32, 16);
        let out = decode(&jpeg_bytes(&img)).unwrap();
        assert_eq!(out.dimensions(), (32, 16));
        assert_eq!(read_quadrants(&out), [0, 1, 2, 3]);
    }

    #[test]
    fn webp_lossless_round_trips() {
        let img = RgbImage::from_fn(9, 4, |x, y| Rgb([x as u8 * 25, y as u8 * 60, 3]));
        let mut out = Vec::new();
        image::codecs::webp::WebPEncoder::new_lossless(&mut out)
            .write_image(img.as_raw(), 9, 4, image::ExtendedColorType::Rgb8)
            .unwrap();
        assert_eq!(decode(&out).unwrap(), img);
    }

    #[test]
    fn exif_orientations_are_applied() {
        // Displayed quadrants (TL, TR, BL, BR) for EXIF orientation 1..=8, as indices into
        // the stored card's quadrants, and whether width and height swap.
        let expected: [([usize; 4], bool); 8] = [
            ([0, 1, 2, 3], false), // 1 normal
            ([1, 0, 3, 2], false), // 2 mirrored horizontally
            ([3, 2, 1, 0], false), // 3 rotated 180°
            ([2, 3, 0, 1], false), // 4 mirrored vertically
            ([0, 2, 1, 3], true),  // 5 transposed
            ([2, 0, 3, 1], true),  // 6 rotated 90° clockwise
            ([3, 1, 2, 0], true),  // 7 transversed
            ([1, 3, 0, 2], true),  // 8 rotated 90° counter-clockwise
        ];
        let jpeg = jpeg_bytes(&quadrants(32, 16));
        for (i, (quads, swap)) in expected.iter().enumerate() {
            let out = decode(&with_exif_orientation(&jpeg, i as u16 + 1)).unwrap();
            let dims = if *swap { (16, 32) } else { (32, 16) };
            assert_eq!(out.dimensions(), dims, "orientation {}", i + 1);
            assert_eq!(read_quadrants(&out), *quads, "orientation {}", i + 1);
        }
    }

    #[test]
    fn one_pixel_image() {
        let img = RgbImage::from_pixel(1, 1, Rgb([1, 2, 3]));
        assert_eq!(decode(&png_bytes(&img)).unwrap(), img);
    }

    /// A PNG signature and a valid IHDR claiming `w`×`h` RGB8, then an empty IDAT and IEND.
    fn png_header_only(w: u32, h: u32) -> Vec<u8> {
        let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
        let mut chunk = |kind: &[u8], data: &[u8]| {
            out.extend_from_slice(&(data.len() as u32).to_be_bytes());
            let mut body = kind.to_vec();
            body.extend_from_slice(data);
            out.extend_from_slice(&body);
            out.extend_from_slice(&crc32fast::hash(&body).to_be_bytes());
        };
        let mut ihdr = Vec::new();
        ihdr.extend_from_slice(&w.to_be_bytes());
        ihdr.extend_from_slice(&h.to_be_bytes());
        ihdr.extend_from_slice(&[8, 2, 0, 0, 0]); // 8-bit RGB, deflate, adaptive, no interlace
        chunk(b"IHDR", &ihdr);
        chunk(b"IDAT", &[0x78, 0x9C, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]);
        chunk(b"IEND", &[]);
        out
    }

    #[test]
    fn decompression_bomb_is_refused_from_the_header() {
        let bytes = png_header_only(30000, 30000);
        assert!(bytes.len() < 100);
        match decode(&bytes) {
            Err(DecodeError::TooManyPixels { width: 30000, height: 30000, pixels: 900_000_000, limit }) => {
                assert_eq!(limit, DecodeLimits::DEFAULT_MAX_PIXELS)
            }
            other => panic!("expected TooManyPixels, got {other:?}"),
        }
        let msg = decode(&bytes).unwrap_err().to_string();
        assert!(msg.contains("900000000") && msg.contains("50000000"), "{msg}");
    }

    #[test]
    fn small_limits_are_enforced() {
        let img = RgbImage::new(10, 10);
        let png = png_bytes(&img);
        let limits = DecodeLimits { max_encoded_bytes: 10, max_pixels: 1000 };
        assert!(matches!(decode_with_limits(&png, &limits), Err(DecodeError::EncodedTooLarge { limit: 10, .. })));
        let limits = DecodeLimits { max_encoded_bytes: 1 << 20, max_pixels: 99 };
        assert!(matches!(decode_with_limits(&png, &limits), Err(DecodeError::TooManyPixels { pixels: 100, .. })));
        let limits = DecodeLimits { max_encoded_bytes: 1 << 20, max_pixels: 100 };
        assert!(decode_with_limits(&png, &limits).is_ok());
    }

    #[test]
    fn zero_size_is_refused() {
        // PNG forbids zero dimensions in IHDR; the decoder may reject it itself, either way it
        // must be an error, never an empty image.
        for (w, h) in [(0, 10), (10, 0)] {
            match decode(&png_header_only(w, h)) {
                Err(DecodeError::ZeroSize { .. }) | Err(DecodeError::Corrupt { .. }) => {}
                other => panic!("expected a zero-size error, got {other:?}"),
            }
        }
    }

    #[test]
    fn empty_garbage_unknown_and_unsupported() {
        assert!(matches!(decode(&[]), Err(DecodeError::Empty)));
        assert!(matches!(decode(b"hello, this is not an image"), Err(DecodeError::UnknownFormat)));
        assert!(matches!(decode(b"GIF89a\x01\x00\x01\x00"), Err(DecodeError::UnsupportedFormat { .. })));
        assert!(matches!(decode(b"BM\x00\x00\x00\x00"), Err(DecodeError::UnsupportedFormat { .. })));
        // Right magic, garbage after it.
        let mut bad = b"\x89PNG\r\n\x1a\n".to_vec();
        bad.extend_from_slice(&[0xAB; 64]);
        assert!(matches!(decode(&bad), Err(DecodeError::Corrupt { .. })));
        let mut bad = vec![0xFF, 0xD8, 0xFF];
        bad.extend_from_slice(&[0x11; 64]);
        assert!(matches!(decode(&bad), Err(DecodeError::Corrupt { .. })));
    }

    #[test]
    fn truncated_files_are_errors() {
        let img = RgbImage::from_fn(64, 48, |x, y| Rgb([(x * 3) as u8, (y * 5) as u8, (x ^ y) as u8]));
        let png = png_bytes(&img);
        let jpeg = jpeg_bytes(&img);
        let mut webp = Vec::new();
        image::codecs::webp::WebPEncoder::new_lossless(&mut webp)
            .write_image(img.as_raw(), 64, 48, image::ExtendedColorType::Rgb8)
            .unwrap();
        for (name, bytes) in [("png", &png), ("webp", &webp)] {
            for cut in [bytes.len() / 3, bytes.len() / 2, bytes.len() - 13] {
                let r = decode(&bytes[..cut]);
                assert!(matches!(r, Err(DecodeError::Corrupt { .. })), "{name} cut at {cut}: {r:?}");
            }
        }
        // A JPEG cut inside its headers cannot decode. (Cut inside the entropy-coded data,
        // JPEG decoders conventionally return the partial image; that is not an error.)
        let r = decode(&jpeg[..40]);
        assert!(matches!(r, Err(DecodeError::Corrupt { .. })), "{r:?}");
        for cut in 1..jpeg.len() {
            let _ = decode(&jpeg[..cut]); // never panics
        }
    }
}
