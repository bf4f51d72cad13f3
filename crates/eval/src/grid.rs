//! Nearest-neighbour queries over a fixed point set: a uniform grid of buckets, searched in
//! growing shells until no closer point can exist.

use glam::DVec3;
use std::collections::HashMap;

pub struct Grid<'a> {
    points: &'a [DVec3],
    cell: f64,
    cells: HashMap<[i64; 3], Vec<u32>>,
}

impl<'a> Grid<'a> {
    /// `cell`: bucket side (a few times the point spacing).
    pub fn new(points: &'a [DVec3], cell: f64) -> Self {
        let mut cells: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for (i, p) in points.iter().enumerate() {
            if p.is_finite() {
                cells.entry(Self::key(*p, cell)).or_default().push(i as u32);
            }
        }
        Grid { points, cell, cells }
    }

    fn key(p: DVec3, cell: f64) -> [i64; 3] {
        [(p.x / cell).floor() as i64, (p.y / cell).floor() as i64, (p.z / cell).floor() as i64]
    }

    /// Index and squared distance of the point nearest to `q` (`None` for an empty set).
    pub fn nearest(&self, q: DVec3) -> Option<(usize, f64)> {
        if self.cells.is_empty() || !q.is_finite() {
            return None;
        }
        let k = Self::key(q, self.cell);
        let mut best: Option<(usize, f64)> = None;
        // Shell r covers every point within r·cell of q; stop once the best is that close.
        for r in 0i64..1_000 {
            for dx in -r..=r {
                for dy in -r..=r {
                    for dz in -r..=r {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != r {
                            continue;
                        }
                        if let Some(ids) = self.cells.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                            for &i in ids {
                                let d = self.points[i as usize].distance_squared(q);
                                if best.is_none_or(|b| d < b.1) {
                                    best = Some((i as usize, d));
                                }
                            }
                        }
                    }
                }
            }
            if let Some(b) = best
                && b.1.sqrt() <= r as f64 * self.cell
            {
                return best;
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn agrees_with_brute_force() {
        let pts: Vec<DVec3> = (0..500)
            .map(|i| {
                let t = i as f64;
                DVec3::new((t * 0.37).sin() * 50.0, (t * 0.11).cos() * 40.0, (t * 0.053).sin() * 30.0)
            })
            .collect();
        let g = Grid::new(&pts, 4.0);
        for j in 0..200 {
            let t = j as f64 * 1.3;
            let q = DVec3::new(t.cos() * 70.0, (t * 0.7).sin() * 60.0, (t * 0.2).cos() * 45.0);
            let want = pts.iter().map(|p| p.distance_squared(q)).fold(f64::INFINITY, f64::min);
            assert!((g.nearest(q).unwrap().1 - want).abs() < 1e-9);
        }
        assert!(Grid::new(&[], 1.0).nearest(DVec3::ZERO).is_none());
    }
}
