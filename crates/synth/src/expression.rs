//! Random, plausible, sparse blendshape expressions (ARKit naming, weights in [0, 1]).
//!
//! An expression is a few *actions* — groups of blendshapes that move together in real
//! faces (a smile pulls the lip corners and raises the cheeks, surprise raises the brows and
//! widens the eyes) — each with one intensity and a little left/right asymmetry. Mutually
//! exclusive actions (jaw left vs right, look up vs down …) are never combined. Names a
//! model does not have are skipped, so any blendshape model with ARKit names works; a PCA
//! expression model gets small N(0, 0.5) draws instead (see [`random_expression`]).

use crate::rng::Rng;

/// An action: `(blendshape, relative weight)` pairs; `_L`/`_R` partners get asymmetry.
struct Action {
    name: &'static str,
    /// Actions of the same non-empty group exclude each other.
    group: &'static str,
    shapes: &'static [(&'static str, f32)],
    /// Upper bound of the intensity (some shapes look broken at full weight when combined).
    max: f32,
}

const ACTIONS: &[Action] = &[
    Action {
        name: "smile",
        group: "mouth",
        max: 1.0,
        shapes: &[
            ("mouthSmile_L", 1.0),
            ("mouthSmile_R", 1.0),
            ("cheekSquint_L", 0.6),
            ("cheekSquint_R", 0.6),
            ("eyeSquint_L", 0.3),
            ("eyeSquint_R", 0.3),
        ],
    },
    Action {
        name: "frown",
        group: "mouth",
        max: 0.9,
        shapes: &[("mouthFrown_L", 1.0), ("mouthFrown_R", 1.0), ("browDown_L", 0.5), ("browDown_R", 0.5)],
    },
    Action { name: "pucker", group: "mouth", max: 0.9, shapes: &[("mouthPucker", 1.0)] },
    Action { name: "funnel", group: "mouth", max: 0.8, shapes: &[("mouthFunnel", 1.0)] },
    Action { name: "press", group: "mouth", max: 0.8, shapes: &[("mouthPress_L", 1.0), ("mouthPress_R", 1.0)] },
    Action { name: "stretch", group: "mouth", max: 0.8, shapes: &[("mouthStretch_L", 1.0), ("mouthStretch_R", 1.0)] },
    Action { name: "dimple", group: "mouth", max: 0.8, shapes: &[("mouthDimple_L", 1.0), ("mouthDimple_R", 1.0)] },
    Action { name: "mouth_left", group: "mouth_side", max: 0.7, shapes: &[("mouthLeft", 1.0)] },
    Action { name: "mouth_right", group: "mouth_side", max: 0.7, shapes: &[("mouthRight", 1.0)] },
    Action { name: "lip_roll", group: "lips", max: 0.7, shapes: &[("mouthRollLower", 1.0), ("mouthRollUpper", 1.0)] },
    Action { name: "shrug", group: "lips", max: 0.8, shapes: &[("mouthShrugLower", 1.0), ("mouthShrugUpper", 0.6)] },
    Action {
        name: "upper_lip_up",
        group: "lips",
        max: 0.7,
        shapes: &[("mouthUpperUp_L", 1.0), ("mouthUpperUp_R", 1.0)],
    },
    Action {
        name: "open",
        group: "jaw",
        max: 1.0,
        shapes: &[("jawOpen", 1.0), ("mouthLowerDown_L", 0.3), ("mouthLowerDown_R", 0.3)],
    },
    Action { name: "talk", group: "jaw", max: 0.5, shapes: &[("jawOpen", 1.0)] },
    Action { name: "jaw_forward", group: "jaw_side", max: 0.6, shapes: &[("jawForward", 1.0)] },
    Action { name: "jaw_left", group: "jaw_side", max: 0.6, shapes: &[("jawLeft", 1.0)] },
    Action { name: "jaw_right", group: "jaw_side", max: 0.6, shapes: &[("jawRight", 1.0)] },
    Action {
        name: "surprise",
        group: "brows",
        max: 1.0,
        shapes: &[
            ("browInnerUp_L", 1.0),
            ("browInnerUp_R", 1.0),
            ("browOuterUp_L", 0.8),
            ("browOuterUp_R", 0.8),
            ("eyeWide_L", 0.6),
            ("eyeWide_R", 0.6),
        ],
    },
    Action { name: "worry", group: "brows", max: 0.9, shapes: &[("browInnerUp_L", 1.0), ("browInnerUp_R", 1.0)] },
    Action {
        name: "brow_down",
        group: "brows",
        max: 0.9,
        shapes: &[("browDown_L", 1.0), ("browDown_R", 1.0), ("eyeSquint_L", 0.3), ("eyeSquint_R", 0.3)],
    },
    Action { name: "sneer", group: "nose", max: 0.8, shapes: &[("noseSneer_L", 1.0), ("noseSneer_R", 1.0)] },
    Action { name: "cheek_puff", group: "cheeks", max: 0.8, shapes: &[("cheekPuff_L", 1.0), ("cheekPuff_R", 1.0)] },
    Action { name: "blink", group: "lids", max: 1.0, shapes: &[("eyeBlink_L", 1.0), ("eyeBlink_R", 1.0)] },
    Action { name: "squint", group: "lids", max: 0.8, shapes: &[("eyeSquint_L", 1.0), ("eyeSquint_R", 1.0)] },
    Action { name: "wink_left", group: "lids", max: 1.0, shapes: &[("eyeBlink_L", 1.0)] },
    Action { name: "look_up", group: "gaze_v", max: 0.8, shapes: &[("eyeLookUp_L", 1.0), ("eyeLookUp_R", 1.0)] },
    Action { name: "look_down", group: "gaze_v", max: 0.8, shapes: &[("eyeLookDown_L", 1.0), ("eyeLookDown_R", 1.0)] },
    Action { name: "look_left", group: "gaze_h", max: 0.8, shapes: &[("eyeLookOut_L", 1.0), ("eyeLookIn_R", 1.0)] },
    Action { name: "look_right", group: "gaze_h", max: 0.8, shapes: &[("eyeLookOut_R", 1.0), ("eyeLookIn_L", 1.0)] },
];

/// Draws one expression for a model's expression names.
///
/// Blendshape models (`blendshape == true`): with probability 0.15 neutral, otherwise 1–4
/// actions from distinct groups, intensity U(0.15, max), each shape within ±0.15 of it
/// (asymmetry), summed and clamped to [0, 1]. Returns the weights and the action names.
/// PCA models: N(0, 0.5) per mode clamped to ±2 (no names).
pub fn random_expression(names: &[String], blendshape: bool, rng: &mut Rng) -> (Vec<f32>, Vec<&'static str>) {
    let mut w = vec![0.0f32; names.len()];
    if !blendshape {
        for x in &mut w {
            *x = rng.normal_clamped(0.5, 2.0) as f32;
        }
        return (w, Vec::new());
    }
    let mut used = Vec::new();
    if rng.chance(0.15) {
        return (w, used);
    }
    let count = 1 + rng.below(4) as usize;
    let mut groups: Vec<&str> = Vec::new();
    for _ in 0..count * 3 {
        if used.len() == count {
            break;
        }
        let a = &ACTIONS[rng.below(ACTIONS.len() as u64) as usize];
        if groups.contains(&a.group) {
            continue;
        }
        groups.push(a.group);
        used.push(a.name);
        let intensity = rng.range(0.15, a.max as f64) as f32;
        for &(shape, rel) in a.shapes {
            let jitter = rng.range(-0.15, 0.15) as f32;
            if let Some(k) = names.iter().position(|n| n == shape) {
                w[k] = (w[k] + rel * (intensity + jitter).max(0.0)).clamp(0.0, 1.0);
            }
        }
    }
    (w, used)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arkit() -> Vec<String> {
        let mut v: Vec<String> = ACTIONS.iter().flat_map(|a| a.shapes.iter().map(|s| s.0.to_string())).collect();
        v.sort();
        v.dedup();
        v
    }

    #[test]
    fn every_action_names_real_arkit_shapes() {
        // The 53 ICT names (upstream vertex_indices.json).
        let ict = "browDown_L browDown_R browInnerUp_L browInnerUp_R browOuterUp_L browOuterUp_R cheekPuff_L cheekPuff_R cheekSquint_L cheekSquint_R eyeBlink_L eyeBlink_R eyeLookDown_L eyeLookDown_R eyeLookIn_L eyeLookIn_R eyeLookOut_L eyeLookOut_R eyeLookUp_L eyeLookUp_R eyeSquint_L eyeSquint_R eyeWide_L eyeWide_R jawForward jawLeft jawOpen jawRight mouthClose mouthDimple_L mouthDimple_R mouthFrown_L mouthFrown_R mouthFunnel mouthLeft mouthLowerDown_L mouthLowerDown_R mouthPress_L mouthPress_R mouthPucker mouthRight mouthRollLower mouthRollUpper mouthShrugLower mouthShrugUpper mouthSmile_L mouthSmile_R mouthStretch_L mouthStretch_R mouthUpperUp_L mouthUpperUp_R noseSneer_L noseSneer_R";
        let ict: Vec<&str> = ict.split(' ').collect();
        assert_eq!(ict.len(), 53);
        for n in arkit() {
            assert!(ict.contains(&n.as_str()), "{n}");
        }
    }

    #[test]
    fn expressions_are_sparse_in_range_and_exclusive() {
        let names = arkit();
        let k = |n: &str| names.iter().position(|x| x == n).unwrap();
        let mut rng = Rng::new(5);
        let mut neutral = 0;
        for _ in 0..2000 {
            let (w, used) = random_expression(&names, true, &mut rng);
            assert!(w.iter().all(|&x| (0.0..=1.0).contains(&x)));
            let nonzero = w.iter().filter(|&&x| x > 0.0).count();
            assert!(nonzero <= 16, "{nonzero}");
            if used.is_empty() {
                neutral += 1;
            }
            assert!(!(w[k("jawLeft")] > 0.0 && w[k("jawRight")] > 0.0));
            assert!(!(w[k("eyeLookUp_L")] > 0.0 && w[k("eyeLookDown_L")] > 0.0));
        }
        assert!((200..400).contains(&neutral), "{neutral}");
    }
}
