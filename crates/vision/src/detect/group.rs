//! Grouping raw window hits into faces: OpenCV's `groupRectangles` (partition by
//! similarity, average each class, keep classes with more than `min_neighbors` members,
//! drop classes nested in a stronger one), and non-maximum suppression to merge the
//! detections of several cascades.

use super::scan::Rect;

/// OpenCV's `SimilarRects`: every edge within eps · (mean of the smaller sides) / 2... i.e.
/// δ = eps · (min(w₁, w₂) + min(h₁, h₂)) / 2.
fn similar(a: &Rect, b: &Rect, eps: f64) -> bool {
    let delta = eps * f64::from(a.w.min(b.w) + a.h.min(b.h)) * 0.5;
    f64::from((a.x - b.x).abs()) <= delta
        && f64::from((a.y - b.y).abs()) <= delta
        && f64::from((a.x + a.w - b.x - b.w).abs()) <= delta
        && f64::from((a.y + a.h - b.y - b.h).abs()) <= delta
}

fn find(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}

/// A grouped face: the averaged rectangle, how many raw hits it merges, and the best stage
/// margin among them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Group {
    pub rect: Rect,
    pub neighbors: usize,
    pub margin: f32,
}

/// OpenCV's `groupRectangles(rects, min_neighbors, eps)`. With `min_neighbors == 0` every
/// hit is returned as its own group, as OpenCV does.
pub fn group_rectangles(hits: &[(Rect, f32)], min_neighbors: usize, eps: f64) -> Vec<Group> {
    if min_neighbors == 0 {
        return hits.iter().map(|&(rect, margin)| Group { rect, neighbors: 1, margin }).collect();
    }
    let n = hits.len();
    // Connected components of the similarity relation (order independent).
    let mut parent: Vec<usize> = (0..n).collect();
    for i in 0..n {
        for j in i + 1..n {
            if similar(&hits[i].0, &hits[j].0, eps) {
                let (a, b) = (find(&mut parent, i), find(&mut parent, j));
                if a != b {
                    parent[a.max(b)] = a.min(b);
                }
            }
        }
    }
    let mut class_of = vec![usize::MAX; n];
    let mut sums: Vec<([i64; 4], usize, f32)> = Vec::new();
    for i in 0..n {
        let r = find(&mut parent, i);
        if class_of[r] == usize::MAX {
            class_of[r] = sums.len();
            sums.push(([0; 4], 0, f32::NEG_INFINITY));
        }
        let c = &mut sums[class_of[r]];
        let h = &hits[i].0;
        c.0[0] += i64::from(h.x);
        c.0[1] += i64::from(h.y);
        c.0[2] += i64::from(h.w);
        c.0[3] += i64::from(h.h);
        c.1 += 1;
        c.2 = c.2.max(hits[i].1);
    }
    let groups: Vec<Group> = sums
        .iter()
        .map(|(s, k, m)| {
            // OpenCV: saturate_cast<int>(sum · (1/k)) with a float factor: round half to even.
            let f = 1.0f32 / *k as f32;
            let avg = |v: i64| (v as f32 * f).round_ties_even() as i32;
            Group { rect: Rect { x: avg(s[0]), y: avg(s[1]), w: avg(s[2]), h: avg(s[3]) }, neighbors: *k, margin: *m }
        })
        .collect();
    let mut out = Vec::new();
    for (i, g) in groups.iter().enumerate() {
        let n1 = g.neighbors;
        if n1 <= min_neighbors {
            continue;
        }
        let r1 = g.rect;
        let nested = groups.iter().enumerate().any(|(j, g2)| {
            let n2 = g2.neighbors;
            if j == i || n2 <= min_neighbors {
                return false;
            }
            let r2 = g2.rect;
            let dx = (f64::from(r2.w) * eps).round() as i32;
            let dy = (f64::from(r2.h) * eps).round() as i32;
            r1.x >= r2.x - dx
                && r1.y >= r2.y - dy
                && r1.x + r1.w <= r2.x + r2.w + dx
                && r1.y + r1.h <= r2.y + r2.h + dy
                && (n2 > n1.max(3) || n1 < 3)
        });
        if !nested {
            out.push(*g);
        }
    }
    out
}

/// Greedy non-maximum suppression: boxes sorted by score, a box dropped when it overlaps a
/// kept one by IoU > `iou` or lies mostly (> `contain` of its area) inside it.
pub fn nms<T>(mut items: Vec<T>, key: impl Fn(&T) -> (crate::face::FaceBox, f32), iou: f32, contain: f32) -> Vec<T> {
    items.sort_by(|a, b| key(b).1.total_cmp(&key(a).1));
    let mut kept: Vec<T> = Vec::new();
    for it in items {
        let (b, _) = key(&it);
        let clash = kept.iter().any(|k| {
            let (kb, _) = key(k);
            let iw = (b.x1.min(kb.x1) - b.x0.max(kb.x0)).max(0.0);
            let ih = (b.y1.min(kb.y1) - b.y0.max(kb.y0)).max(0.0);
            let inter = iw * ih;
            b.iou(&kb) > iou || inter > contain * b.area().min(kb.area())
        });
        if !clash {
            kept.push(it);
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    fn r(x: i32, y: i32, w: i32, h: i32) -> (Rect, f32) {
        (Rect { x, y, w, h }, 0.0)
    }

    #[test]
    fn similar_uses_opencvs_delta() {
        // δ = 0.2 · (20 + 20) / 2 = 4.
        let a = Rect { x: 0, y: 0, w: 20, h: 20 };
        assert!(similar(&a, &Rect { x: 4, y: 4, w: 20, h: 20 }, 0.2));
        assert!(!similar(&a, &Rect { x: 5, y: 0, w: 20, h: 20 }, 0.2));
        assert!(!similar(&a, &Rect { x: 0, y: 0, w: 25, h: 20 }, 0.2)); // right edge moves 5
    }

    #[test]
    fn groups_need_more_than_min_neighbors() {
        // Three similar hits and one stray.
        let hits = [r(10, 10, 20, 20), r(12, 10, 20, 20), r(11, 13, 21, 20), r(100, 100, 20, 20)];
        let g = group_rectangles(&hits, 2, 0.2);
        assert_eq!(g.len(), 1);
        assert_eq!(g[0].neighbors, 3);
        // Averages: x = 33/3 = 11, y = 33/3 = 11, w = 61/3 = 20.33 → 20, h = 20.
        assert_eq!(g[0].rect, Rect { x: 11, y: 11, w: 20, h: 20 });
        assert!(group_rectangles(&hits, 3, 0.2).is_empty());
        assert_eq!(group_rectangles(&hits, 0, 0.2).len(), 4);
    }

    #[test]
    fn chains_are_one_class() {
        // a~b and b~c but not a~c: partition joins them transitively.
        let hits = [r(0, 0, 20, 20), r(4, 0, 20, 20), r(8, 0, 20, 20)];
        let g = group_rectangles(&hits, 1, 0.2);
        assert_eq!(g.len(), 1);
        assert_eq!(g[0].neighbors, 3);
    }

    #[test]
    fn small_group_inside_a_strong_one_is_dropped() {
        let mut hits = vec![r(50, 50, 10, 10), r(51, 50, 10, 10)]; // weak, small
        for i in 0..5 {
            hits.push(r(40 + i % 2, 40, 40, 40)); // strong, large, containing it
        }
        let g = group_rectangles(&hits, 1, 0.2);
        assert_eq!(g.len(), 1);
        assert_eq!(g[0].neighbors, 5);
    }

    #[test]
    fn nms_keeps_the_best_of_overlapping_boxes() {
        use crate::face::FaceBox;
        let b = |x0: f32, s: f32| (FaceBox { x0, y0: 0.0, x1: x0 + 10.0, y1: 10.0 }, s);
        let kept = nms(vec![b(0.0, 1.0), b(1.0, 5.0), b(30.0, 2.0)], |t| *t, 0.3, 0.8);
        assert_eq!(kept.len(), 2);
        assert_eq!(kept[0].1, 5.0);
        assert_eq!(kept[1].1, 2.0);
    }
}
