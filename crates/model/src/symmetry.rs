//! Left/right symmetry maps: each vertex's nearest vertex after mirroring x → −x, found with
//! a uniform grid (exact nearest neighbour, not approximate).

/// Result of mirroring a mesh onto itself.
#[derive(Clone, Debug)]
pub struct MirrorMap {
    /// For each vertex, the vertex nearest to its mirror image.
    pub map: Vec<u32>,
    /// Distance between each vertex's mirror image and its match (same units as input).
    pub distance: Vec<f32>,
}

/// Nearest-vertex mirror map of `points` (x → −x). `candidates_of(i)` restricts the search
/// for vertex `i` to vertices `j` with `group[j] == group_match(group[i])`, so that e.g. a left
/// eyeball maps onto the right eyeball even where another surface is closer.
pub fn mirror_map(points: &[[f32; 3]], group: &[u8], group_match: impl Fn(u8) -> u8) -> MirrorMap {
    let grid = Grid::new(points, group);
    let mut map = Vec::with_capacity(points.len());
    let mut distance = Vec::with_capacity(points.len());
    for (i, p) in points.iter().enumerate() {
        let q = [-p[0], p[1], p[2]];
        let (j, d) = grid.nearest(q, group_match(group[i])).unwrap_or((i as u32, 0.0));
        map.push(j);
        distance.push(d);
    }
    MirrorMap { map, distance }
}

struct Grid<'a> {
    points: &'a [[f32; 3]],
    group: &'a [u8],
    lo: [f32; 3],
    cell: f32,
    dims: [usize; 3],
    start: Vec<u32>,
    items: Vec<u32>,
}

impl<'a> Grid<'a> {
    fn new(points: &'a [[f32; 3]], group: &'a [u8]) -> Self {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in points {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        // About two points per cell on a surface-like cloud.
        let extent = (0..3).map(|a| (hi[a] - lo[a]).max(1e-6)).fold(0.0f32, f32::max);
        let cell = (extent / (points.len() as f32 / 2.0).sqrt().max(1.0)).max(1e-6);
        let dims = [0, 1, 2].map(|a| (((hi[a] - lo[a]) / cell) as usize + 1).min(1024));
        let mut counts = vec![0u32; dims[0] * dims[1] * dims[2] + 1];
        let cell_of = |p: &[f32; 3]| -> usize {
            let c = [0, 1, 2].map(|a| (((p[a] - lo[a]) / cell) as usize).min(dims[a] - 1));
            (c[2] * dims[1] + c[1]) * dims[0] + c[0]
        };
        for p in points {
            counts[cell_of(p) + 1] += 1;
        }
        for i in 1..counts.len() {
            counts[i] += counts[i - 1];
        }
        let mut fill = counts.clone();
        let mut items = vec![0u32; points.len()];
        for (i, p) in points.iter().enumerate() {
            let c = cell_of(p);
            items[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        Self { points, group, lo, cell, dims, start: counts, items }
    }

    fn nearest(&self, q: [f32; 3], want: u8) -> Option<(u32, f32)> {
        let c = [0, 1, 2].map(|a| ((q[a] - self.lo[a]) / self.cell).floor() as i64);
        // Far enough to cover the whole grid from q, even when q lies outside it.
        let max_r = (0..3).map(|a| self.dims[a] as i64 + c[a].abs() + 1).max().unwrap_or(1);
        let mut best: Option<(u32, f32)> = None;
        for r in 0..=max_r {
            // Every point outside the cube of radius r cells is farther than (r)·cell from q.
            if let Some((_, d)) = best
                && d <= (r as f32 - 1.0).max(0.0) * self.cell
            {
                break;
            }
            for z in c[2] - r..=c[2] + r {
                for y in c[1] - r..=c[1] + r {
                    for x in c[0] - r..=c[0] + r {
                        let shell = (x - c[0]).abs() == r || (y - c[1]).abs() == r || (z - c[2]).abs() == r;
                        if !shell {
                            continue;
                        }
                        if x < 0 || y < 0 || z < 0 {
                            continue;
                        }
                        let (x, y, z) = (x as usize, y as usize, z as usize);
                        if x >= self.dims[0] || y >= self.dims[1] || z >= self.dims[2] {
                            continue;
                        }
                        let cell = (z * self.dims[1] + y) * self.dims[0] + x;
                        for &j in &self.items[self.start[cell] as usize..self.start[cell + 1] as usize] {
                            if self.group[j as usize] != want {
                                continue;
                            }
                            let p = self.points[j as usize];
                            let d = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
                            if best.is_none_or(|(_, bd)| d < bd) {
                                best = Some((j, d));
                            }
                        }
                    }
                }
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute-force oracle on a random cloud with groups.
    #[test]
    fn matches_brute_force() {
        let mut s = 12345u64;
        let mut rnd = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 33) as f32 / (1u64 << 31) as f32) * 2.0 - 1.0
        };
        let pts: Vec<[f32; 3]> = (0..2000).map(|_| [rnd() * 50.0, rnd() * 80.0, rnd() * 10.0]).collect();
        let group: Vec<u8> = (0..2000).map(|i| (i % 3) as u8).collect();
        let swap = |g: u8| {
            if g == 1 {
                2
            } else if g == 2 {
                1
            } else {
                g
            }
        };
        let m = mirror_map(&pts, &group, swap);
        for (i, p) in pts.iter().enumerate() {
            let q = [-p[0], p[1], p[2]];
            let mut best = (0usize, f32::INFINITY);
            for (j, r) in pts.iter().enumerate() {
                if group[j] != swap(group[i]) {
                    continue;
                }
                let d = ((r[0] - q[0]).powi(2) + (r[1] - q[1]).powi(2) + (r[2] - q[2]).powi(2)).sqrt();
                if d < best.1 {
                    best = (j, d);
                }
            }
            assert!((m.distance[i] - best.1).abs() < 1e-5, "vertex {i}");
        }
    }
}
