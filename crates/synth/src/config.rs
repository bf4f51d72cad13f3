//! What a synthetic run varies, and within which ranges.

use crate::SynthError;

/// Resolution bucket of a square crop side `s` (DESIGN §3); `None` below 32 px. The
/// router's own definition ([`facerecon_vision::crop::Bucket`]), as a JSON-friendly index.
pub fn bucket_of(side: f32) -> Option<u8> {
    facerecon_vision::crop::Bucket::from_side(side).index().map(|b| b as u8)
}

/// Ranges of a synthetic run. `Default` is the project's training/test distribution.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SynthConfig {
    /// Buckets to draw crop sizes from, each equally likely.
    pub buckets: Vec<u8>,
    /// Largest crop side drawn for bucket 0, pixels.
    pub max_crop_side: f32,
    /// Fixed image size `(width, height)`; `None` draws a size per sample.
    pub image_size: Option<(u32, u32)>,
    /// Largest image side when sizes are drawn.
    pub max_image_side: u32,
    /// Yaw ~ U(−max, max), degrees.
    pub yaw_max_deg: f32,
    /// Pitch ~ N(0, sd) clamped to ±max, degrees.
    pub pitch_sd_deg: f32,
    pub pitch_max_deg: f32,
    /// Roll ~ N(0, sd) clamped to ±max, degrees.
    pub roll_sd_deg: f32,
    pub roll_max_deg: f32,
    /// `Some(s)`: render each face as the front end's crop of it, `s`×`s` pixels (the crop
    /// camera of DESIGN §4, the landmarks' crop square filling the image), so that the ground
    /// truth is in the crop camera's frame — the encoder's training data. `buckets`,
    /// `image_size` and the size ranges are then unused; lower resolutions are made from
    /// these by bicubic down/up-sampling (DESIGN §7).
    #[serde(default)]
    pub crop_frame: Option<u32>,
    /// `Some(y)`: every face at yaw `y` degrees instead of a drawn one (a pose sweep). Every
    /// other draw is unchanged, so sample `i` is the same face, lit and placed the same, at
    /// each yaw.
    #[serde(default)]
    pub yaw_deg: Option<f32>,
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            buckets: vec![0, 1, 2, 3],
            max_crop_side: 400.0,
            image_size: None,
            max_image_side: 1024,
            yaw_max_deg: 90.0,
            pitch_sd_deg: 12.0,
            pitch_max_deg: 35.0,
            roll_sd_deg: 8.0,
            roll_max_deg: 30.0,
            crop_frame: None,
            yaw_deg: None,
        }
    }
}

impl SynthConfig {
    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |m: String| Err(SynthError::Config(m));
        if self.buckets.is_empty() || self.buckets.iter().any(|&b| b > 3) {
            return bad(format!("buckets {:?}: need one or more of 0, 1, 2, 3", self.buckets));
        }
        if !(self.max_crop_side >= 232.0 && self.max_crop_side <= 4096.0) {
            return bad(format!("max crop side {} outside [232, 4096]", self.max_crop_side));
        }
        if let Some((w, h)) = self.image_size
            && !((48..=8192).contains(&w) && (48..=8192).contains(&h))
        {
            return bad(format!("image size {w}×{h}: each side must be in 48..=8192"));
        }
        if let Some(s) = self.crop_frame
            && !(32..=1024).contains(&s)
        {
            return bad(format!("crop frame {s} px outside 32..=1024"));
        }
        if let Some(y) = self.yaw_deg
            && !(y.abs() <= 90.0)
        {
            return bad(format!("yaw {y}° outside [−90, 90]"));
        }
        if !(64..=8192).contains(&self.max_image_side) {
            return bad(format!("max image side {} outside 64..=8192", self.max_image_side));
        }
        let angles = [
            ("yaw max", self.yaw_max_deg, 180.0),
            ("pitch sd", self.pitch_sd_deg, 90.0),
            ("pitch max", self.pitch_max_deg, 90.0),
            ("roll sd", self.roll_sd_deg, 180.0),
            ("roll max", self.roll_max_deg, 180.0),
        ];
        for (name, v, max) in angles {
            if !(v >= 0.0 && v <= max) {
                return bad(format!("{name} {v}° outside [0, {max}]"));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_follow_the_design() {
        assert_eq!(bucket_of(500.0), Some(0));
        assert_eq!(bucket_of(224.0), Some(0));
        assert_eq!(bucket_of(223.9), Some(1));
        assert_eq!(bucket_of(128.0), Some(1));
        assert_eq!(bucket_of(127.0), Some(2));
        assert_eq!(bucket_of(64.0), Some(2));
        assert_eq!(bucket_of(63.5), Some(3));
        assert_eq!(bucket_of(32.0), Some(3));
        assert_eq!(bucket_of(31.9), None);
    }

    #[test]
    fn bad_configs_are_refused() {
        assert!(SynthConfig::default().validate().is_ok());
        let c = SynthConfig { buckets: vec![4], ..Default::default() };
        assert!(c.validate().unwrap_err().to_string().contains("buckets"));
        let c = SynthConfig { image_size: Some((10, 500)), ..Default::default() };
        assert!(c.validate().is_err());
        let c = SynthConfig { yaw_max_deg: f32::NAN, ..Default::default() };
        assert!(c.validate().is_err());
    }
}
