//! Reader for dlib's binary serialisation (`dlib/serialize.h`), the subset a
//! `shape_predictor` file uses: variable-length integers, floats as (mantissa, exponent)
//! pairs (`dlib/float_details.h`), column matrices, `std::vector` and 2-vectors.
//!
//! Every length read from the file is checked against the bytes that remain before
//! anything is allocated, so a corrupt or hostile file costs at most its own size.

/// Why a byte stream is not a valid dlib serialisation of what was expected.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FormatError {
    #[error("unexpected end of data at byte {offset} while reading {what}")]
    Truncated { offset: usize, what: &'static str },
    #[error("bad integer control byte {byte:#04x} at byte {offset} while reading {what}")]
    BadIntHeader { offset: usize, byte: u8, what: &'static str },
    #[error("integer out of range at byte {offset} while reading {what}")]
    IntOutOfRange { offset: usize, what: &'static str },
    #[error("float at byte {offset} uses dlib's legacy text encoding, which this reader does not support")]
    LegacyFloat { offset: usize },
    #[error("{what} at byte {offset}: count {count} cannot fit in the {remaining} bytes left")]
    CountTooLarge { offset: usize, what: &'static str, count: u64, remaining: usize },
}

/// A cursor over the serialised bytes.
pub struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        Reader { data, pos: 0 }
    }

    pub fn position(&self) -> usize {
        self.pos
    }

    pub fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    /// dlib's integer encoding: a control byte whose low 4 bits give the number of
    /// little-endian magnitude bytes that follow (1..=8) and whose bit 7 is the sign.
    /// Returns (negative, magnitude).
    #[inline]
    fn raw_int(&mut self, max_bytes: usize, what: &'static str) -> Result<(bool, u64), FormatError> {
        let offset = self.pos;
        let Some(&ctrl) = self.data.get(self.pos) else {
            return Err(FormatError::Truncated { offset, what });
        };
        let negative = ctrl & 0x80 != 0;
        let size = (ctrl & 0x0F) as usize;
        // dlib refuses a zero size and sizes beyond the target type; like dlib, the
        // three reserved bits (0x70) are ignored here.
        if size == 0 || size > max_bytes {
            return Err(FormatError::BadIntHeader { offset, byte: ctrl, what });
        }
        let bytes = self.data.get(self.pos + 1..self.pos + 1 + size).ok_or(FormatError::Truncated { offset, what })?;
        let mut v = 0u64;
        for &b in bytes.iter().rev() {
            v = (v << 8) | b as u64;
        }
        self.pos += 1 + size;
        Ok((negative, v))
    }

    /// A signed integer of `bytes` bytes in C++ (`int` = 4, `long` = 8, `int16` = 2).
    pub fn signed(&mut self, bytes: usize, what: &'static str) -> Result<i64, FormatError> {
        let offset = self.pos;
        let (neg, mag) = self.raw_int(bytes, what)?;
        let limit: u64 = 1u64 << (bytes * 8 - 1);
        // Magnitudes that do not fit the C++ type would wrap in dlib; refuse them here.
        if neg {
            if mag > limit {
                return Err(FormatError::IntOutOfRange { offset, what });
            }
            Ok((mag as i128).wrapping_neg() as i64)
        } else {
            if mag >= limit {
                return Err(FormatError::IntOutOfRange { offset, what });
            }
            Ok(mag as i64)
        }
    }

    /// An unsigned integer (`unsigned long`, 8 bytes); a set sign bit is an error.
    pub fn unsigned(&mut self, what: &'static str) -> Result<u64, FormatError> {
        let offset = self.pos;
        let (neg, mag) = self.raw_int(8, what)?;
        if neg {
            return Err(FormatError::BadIntHeader { offset, byte: self.data[offset], what });
        }
        Ok(mag)
    }

    /// A float: `int64` mantissa and `int16` exponent, value = mantissa · 2^exponent,
    /// with exponents 32000 / 32001 / 32002 standing for +∞ / −∞ / NaN (and larger ones
    /// for NaN too, as in `float_details::convert_to_T`).
    #[inline]
    pub fn float(&mut self, what: &'static str) -> Result<f32, FormatError> {
        let offset = self.pos;
        match self.data.get(self.pos) {
            None => return Err(FormatError::Truncated { offset, what }),
            // dlib tells the binary format from its older text format by these bits.
            Some(&b) if b & 0x70 != 0 => return Err(FormatError::LegacyFloat { offset }),
            _ => {}
        }
        let mantissa = self.signed(8, what)?;
        let exponent = self.signed(2, what)?;
        Ok(float_from_parts(mantissa, exponent as i16))
    }

    /// A count of elements (an `unsigned long`) that each take at least `min_bytes` bytes
    /// in what follows: refused when it cannot fit in the remaining data.
    pub fn count(&mut self, min_bytes: usize, what: &'static str) -> Result<usize, FormatError> {
        let offset = self.pos;
        let n = self.unsigned(what)?;
        self.check_fits(offset, n, min_bytes, what)
    }

    fn check_fits(&self, offset: usize, n: u64, min_bytes: usize, what: &'static str) -> Result<usize, FormatError> {
        let remaining = self.remaining();
        if n.saturating_mul(min_bytes.max(1) as u64) > remaining as u64 {
            return Err(FormatError::CountTooLarge { offset, what, count: n, remaining });
        }
        Ok(n as usize)
    }

    /// A `matrix<float,0,1>` (a column vector): `-nr`, `-nc` (or `nr`, `nc` in the older
    /// layout), then the elements row by row. Returns the elements; the column count must
    /// be 1 (0 is accepted for an empty matrix).
    pub fn float_column(&mut self, what: &'static str) -> Result<Vec<f32>, FormatError> {
        let offset = self.pos;
        let mut nr = self.signed(8, what)?;
        let mut nc = self.signed(8, what)?;
        if nr < 0 || nc < 0 {
            nr = nr.checked_neg().ok_or(FormatError::IntOutOfRange { offset, what })?;
            nc = nc.checked_neg().ok_or(FormatError::IntOutOfRange { offset, what })?;
        }
        if nr < 0 || nc < 0 || (nc != 1 && !(nc == 0 || nr == 0)) {
            return Err(FormatError::IntOutOfRange { offset, what });
        }
        let n = (nr as u64).saturating_mul(nc as u64);
        // A float takes at least 4 bytes (two integers of at least 2 bytes each).
        let n = self.check_fits(offset, n, 4, what)?;
        let mut v = Vec::with_capacity(n);
        for _ in 0..n {
            v.push(self.float(what)?);
        }
        Ok(v)
    }
}

/// `float_details` → `float`: `ldexpf((float)mantissa, exponent)`.
#[inline]
pub fn float_from_parts(mantissa: i64, exponent: i16) -> f32 {
    const IS_INF: i16 = 32000;
    const IS_NINF: i16 = 32001;
    if exponent < IS_INF {
        // (float)mantissa rounds once; scaling by a power of two in f64 is exact while in
        // f64's range, and the final cast rounds once more only where the result is
        // subnormal or out of f32's range (where ldexpf also rounds / overflows).
        let m = mantissa as f32 as f64;
        let e = exponent as i32;
        let half = e / 2;
        (m * (half as f64).exp2() * ((e - half) as f64).exp2()) as f32
    } else if exponent == IS_INF {
        f32::INFINITY
    } else if exponent == IS_NINF {
        f32::NEG_INFINITY
    } else {
        f32::NAN
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integers_follow_dlibs_encoding() {
        // 1 → [0x01, 0x01]; -136 → [0x81, 0x88]; 0 → [0x01, 0x00]; 0x1234 → [0x02, 0x34, 0x12]
        let bytes = [0x01, 0x01, 0x81, 0x88, 0x01, 0x00, 0x02, 0x34, 0x12];
        let mut r = Reader::new(&bytes);
        assert_eq!(r.signed(4, "a").unwrap(), 1);
        assert_eq!(r.signed(8, "b").unwrap(), -136);
        assert_eq!(r.unsigned("c").unwrap(), 0);
        assert_eq!(r.unsigned("d").unwrap(), 0x1234);
        assert!(matches!(r.unsigned("e"), Err(FormatError::Truncated { offset: 9, .. })));
    }

    #[test]
    fn integer_errors() {
        // size 0, size beyond the type, sign on an unsigned, truncation
        assert!(matches!(Reader::new(&[0x00]).unsigned("x"), Err(FormatError::BadIntHeader { .. })));
        assert!(matches!(Reader::new(&[0x03, 1, 2, 3]).signed(2, "x"), Err(FormatError::BadIntHeader { .. })));
        assert!(matches!(Reader::new(&[0x81, 1]).unsigned("x"), Err(FormatError::BadIntHeader { .. })));
        assert!(matches!(Reader::new(&[0x02, 1]).unsigned("x"), Err(FormatError::Truncated { .. })));
        // 0x8000 does not fit a positive int16; -0x8000 does.
        assert!(matches!(Reader::new(&[0x02, 0x00, 0x80]).signed(2, "x"), Err(FormatError::IntOutOfRange { .. })));
        assert_eq!(Reader::new(&[0x82, 0x00, 0x80]).signed(2, "x").unwrap(), -32768);
    }

    #[test]
    fn floats_are_mantissa_times_power_of_two() {
        // The first float of the 68-point model: mantissa 0xf1384d (3 bytes), exponent -29.
        let bytes = [0x03, 0x4d, 0x38, 0xf1, 0x81, 0x1d];
        let v = Reader::new(&bytes).float("f").unwrap();
        assert_eq!(v, 0xf1384d as f32 / (1u64 << 29) as f32);
        assert_eq!(float_from_parts(3, -1), 1.5);
        assert_eq!(float_from_parts(-5, 2), -20.0);
        assert_eq!(float_from_parts(1, 32000), f32::INFINITY);
        assert_eq!(float_from_parts(1, 32001), f32::NEG_INFINITY);
        assert!(float_from_parts(1, 32002).is_nan());
        // 2^-140 is a subnormal f32 (exact); 2^200 overflows to infinity; 2^-200 to 0.
        assert_eq!(float_from_parts(1, -140), f32::from_bits(1 << 9));
        assert_eq!(float_from_parts(1, 200), f32::INFINITY);
        assert_eq!(float_from_parts(1, -200), 0.0);
        // The smallest exponent with a large mantissa still lands in range.
        assert_eq!(float_from_parts(1 << 40, -160), 2f32.powi(-120));
        // Text-encoded floats (ASCII digits have bits 0x70 set) are refused clearly.
        assert!(matches!(Reader::new(b"1.5 ").float("f"), Err(FormatError::LegacyFloat { .. })));
    }

    #[test]
    fn counts_are_bounded_by_the_remaining_bytes() {
        // A vector claiming 2^32 elements in a 10-byte buffer is refused before allocating.
        let bytes = [0x06, 0, 0, 0, 0, 1, 0, 0, 0, 0];
        let err = Reader::new(&bytes).count(1, "v").unwrap_err();
        assert!(matches!(err, FormatError::CountTooLarge { count, .. } if count == 1 << 32));
        // A matrix header claiming a huge size likewise.
        let bytes = [0x84, 0xff, 0xff, 0xff, 0x7f, 0x81, 0x01];
        assert!(matches!(Reader::new(&bytes).float_column("m"), Err(FormatError::CountTooLarge { .. })));
    }

    #[test]
    fn column_matrices_both_layouts() {
        // new layout: -2, -1, then 0.5, -3
        let new = [0x81, 0x02, 0x81, 0x01, 0x01, 0x01, 0x81, 0x01, 0x81, 0x03, 0x01, 0x00];
        assert_eq!(Reader::new(&new).float_column("m").unwrap(), vec![0.5, -3.0]);
        // old layout: 2, 1
        let old = [0x01, 0x02, 0x01, 0x01, 0x01, 0x01, 0x81, 0x01, 0x81, 0x03, 0x01, 0x00];
        assert_eq!(Reader::new(&old).float_column("m").unwrap(), vec![0.5, -3.0]);
        // two columns is not a column vector
        let bad = [0x81, 0x02, 0x81, 0x02];
        assert!(Reader::new(&bad).float_column("m").is_err());
    }
}
