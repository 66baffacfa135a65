//! Distance from each bone to each vertex, measured inside the mesh's volume.
//!
//! A bone's distance field is a multi-source Dijkstra over the solid cells (26
//! neighbours, steps of 1, √2 and √3 cells), seeded at the cells the bone passes through
//! with their exact distance to the segment. Paths never leave the solid, so a vertex of
//! the left leg is far from the right leg's bones however close the legs are in space,
//! as long as the grid separates them.
//!
//! Distances are integers in tenths of a cell (steps of 10, 14 and 17: 1, √2 and √3 to
//! within 2 %), which allows a bucket queue instead of a heap: each settled cell costs its
//! 26 neighbour checks and nothing more, which is what makes 50 fields over a 20k-vertex
//! mesh take tens of milliseconds.

use super::voxel::Grid;
use crate::rig::metrics::Segment;
use glam::Vec3;

/// Distance units per cell.
const UNITS: f32 = 10.0;
/// A cell is on a bone when its centre is within half a cell diagonal of the segment.
const ON_BONE: f32 = 0.87;
/// Bucket ring size: must exceed the largest step (17) plus the spread of seed distances.
const RING: usize = 32;
/// Not reached from the seeds.
pub const UNREACHED: u32 = u32::MAX;

/// The solid cells of the mesh and how they connect.
pub struct Volume {
    pub grid: Grid,
    /// Private: the walk indexes without bounds checks on the strength of it (see `new`).
    solid: Vec<bool>,
    /// Indices of the solid cells.
    pub cells: Vec<u32>,
    /// 26-connected piece of solid each cell belongs to (u32::MAX outside).
    pub blob: Vec<u32>,
    steps: Vec<(isize, u32)>,
}

impl Volume {
    /// `solid` holds one entry per grid cell. Cells on the grid's outer layer are taken as
    /// outside whatever it says (voxelization pads the mesh, so it never marks one): every
    /// solid cell's 26 neighbours are then in the grid, which the walk relies on.
    pub fn new(grid: Grid, mut solid: Vec<bool>) -> Volume {
        assert_eq!(
            solid.len(),
            grid.dims.iter().product::<usize>(),
            "one solid flag per grid cell"
        );
        clear_border(&grid, &mut solid);
        let cells: Vec<u32> = (0..solid.len())
            .filter(|&i| solid[i])
            .map(|i| i as u32)
            .collect();
        let steps: Vec<(isize, u32)> = grid
            .neighbour_offsets()
            .into_iter()
            .map(|(o, len)| (o, (len * UNITS).round() as u32))
            .collect();
        let mut blob = vec![u32::MAX; solid.len()];
        let mut next = 0;
        let mut stack = Vec::new();
        for &c in &cells {
            if blob[c as usize] != u32::MAX {
                continue;
            }
            blob[c as usize] = next;
            stack.push(c as usize);
            while let Some(i) = stack.pop() {
                for &(o, _) in &steps {
                    let j = (i as isize + o) as usize;
                    if solid[j] && blob[j] == u32::MAX {
                        blob[j] = next;
                        stack.push(j);
                    }
                }
            }
            next += 1;
        }
        Volume {
            grid,
            solid,
            cells,
            blob,
            steps,
        }
    }

    /// Grid cells (solid or not) the segment passes through, with each centre's distance
    /// to the segment in mesh units.
    pub fn cells_on(&self, seg: &Segment, stamp: &mut Stamp) -> Vec<(u32, f32)> {
        let g = &self.grid;
        // Only the part near the grid is walked, so the steps are bounded by the grid's
        // size whatever the bone's length (a file's joint transform can put a joint 1e30
        // units away, and the step count would then exceed any integer: a hang).
        let Some((seg, steps)) = walk(g, seg) else {
            return Vec::new();
        };
        stamp.next();
        let mut out = Vec::new();
        for s in 0..=steps {
            let p = seg.a.lerp(seg.b, s as f32 / steps as f32);
            let c = g.cell_of(p);
            for dz in 0..3 {
                for dy in 0..3 {
                    for dx in 0..3 {
                        let (Some(x), Some(y), Some(z)) = (
                            (c[0] + dx).checked_sub(1).filter(|&v| v < g.dims[0]),
                            (c[1] + dy).checked_sub(1).filter(|&v| v < g.dims[1]),
                            (c[2] + dz).checked_sub(1).filter(|&v| v < g.dims[2]),
                        ) else {
                            continue;
                        };
                        let i = g.index([x, y, z]);
                        if !stamp.first_visit(i) {
                            continue;
                        }
                        let d = seg.distance(g.center([x, y, z]));
                        if d <= ON_BONE * g.cell {
                            out.push((i as u32, d));
                        }
                    }
                }
            }
        }
        out
    }

    /// Where a bone's field starts: its solid cells, or, for a bone wholly outside the
    /// volume, the solid cells nearest to it (each with its own distance to the bone).
    pub fn seeds(&self, seg: &Segment, on_bone: &[(u32, f32)]) -> Vec<(u32, u32)> {
        let to_units = |d: f32| (d / self.grid.cell * UNITS).round() as u32;
        let inside: Vec<(u32, u32)> = on_bone
            .iter()
            .filter(|(c, _)| self.solid[*c as usize])
            .map(|&(c, d)| (c, to_units(d)))
            .collect();
        if !inside.is_empty() {
            return inside;
        }
        let dist: Vec<(u32, f32)> = self
            .cells
            .iter()
            .map(|&c| {
                (
                    c,
                    seg.distance(self.grid.center(self.grid.coords(c as usize))),
                )
            })
            .collect();
        let Some(best) = dist.iter().map(|x| x.1).min_by(f32::total_cmp) else {
            return Vec::new();
        };
        // Only cells within half a cell of the nearest, so the seeds' spread stays well
        // inside the bucket ring.
        dist.into_iter()
            .filter(|&(_, d)| d <= best + 0.5 * self.grid.cell)
            .map(|(c, d)| (c, to_units(d)))
            .collect()
    }

    /// Fills `dist` (one entry per grid cell) with the geodesic distance from `seeds`,
    /// in tenths of a cell; solid cells that are not reached stay [`UNREACHED`], and cells
    /// outside the solid hold 0, which no path can improve on, so the walk needs no
    /// separate look at `solid` per neighbour. Pass the same `dist` and `ring` to every
    /// call: only the cells the last field set are reset.
    ///
    /// With `bounds = Some((nearest, joins))`, the field stops wherever `nearest.k`
    /// fields that joined `nearest` are strictly nearer (see [`Nearest`]): those cells,
    /// and the cells past them, keep a larger value or stay unreached, and each cell's k
    /// nearest are exact all the same. With `joins`, this field's values join them.
    pub fn field(
        &self,
        seeds: &[(u32, u32)],
        dist: &mut Vec<u32>,
        ring: &mut Ring,
        bounds: Option<(&mut Nearest, bool)>,
    ) {
        // Until k fields have joined there is no bound: those walk unbounded and join in
        // one pass over the solid cells afterwards (cheaper than inserting as they settle).
        match bounds {
            Some((n, joins)) if n.joined == n.k => self.walk(seeds, dist, ring, Some((n, joins))),
            early => {
                self.walk(seeds, dist, ring, None);
                if let Some((n, true)) = early {
                    n.fill(self, dist);
                }
            }
        }
    }

    fn walk(
        &self,
        seeds: &[(u32, u32)],
        dist: &mut Vec<u32>,
        ring: &mut Ring,
        mut bounds: Option<(&mut Nearest, bool)>,
    ) {
        if dist.len() == self.solid.len() {
            for &c in &ring.touched {
                dist[c as usize] = UNREACHED;
            }
        } else {
            dist.clear();
            dist.extend(self.solid.iter().map(|&s| if s { UNREACHED } else { 0 }));
        }
        ring.clear();
        let Some(start) = seeds.iter().map(|s| s.1).min() else {
            return;
        };
        for &(c, d) in seeds {
            if d < dist[c as usize] {
                dist[c as usize] = d;
                ring.push(d, c);
            }
        }
        let mut cur = start;
        while ring.pending > 0 {
            while let Some(c) = ring.pop(cur) {
                let c = c as usize;
                if dist[c] != cur {
                    // Settled earlier at a shorter distance.
                    continue;
                }
                if let Some((k, joins)) = bounds.as_mut() {
                    // Checked where a cell settles, not at each of its 26 neighbours: a
                    // cell past the bound keeps its value but goes no further.
                    if cur > k.kth[c] {
                        continue;
                    }
                    if *joins {
                        k.insert(c, cur);
                    }
                }
                // Only solid cells are ever pushed (the others hold 0, which no path
                // improves on), and the grid's empty border keeps every neighbour of a
                // solid cell inside the grid: no index below needs a bounds check.
                debug_assert!(self.solid[c]);
                for &(o, w) in &self.steps {
                    let n = c.wrapping_add_signed(o);
                    let nd = cur + w;
                    // SAFETY: n is a neighbour of the solid cell c, so within the grid
                    // (see above), and `dist` has one entry per grid cell.
                    let d = unsafe { dist.get_unchecked_mut(n) };
                    if nd < *d {
                        *d = nd;
                        ring.push(nd, n as u32);
                    }
                }
            }
            cur += 1;
        }
    }

    /// Whether each grid cell is solid.
    pub fn solid(&self) -> &[bool] {
        &self.solid
    }

    /// Converts a field value to mesh units.
    pub fn to_mesh(&self, units: u32) -> f32 {
        units as f32 / UNITS * self.grid.cell
    }
}

/// Marks the grid's outer layer of cells not solid.
fn clear_border(grid: &Grid, solid: &mut [bool]) {
    let [nx, ny, nz] = grid.dims;
    for z in 0..nz {
        for y in 0..ny {
            if z == 0 || y == 0 || z + 1 == nz || y + 1 == ny {
                solid[grid.index([0, y, z])..=grid.index([nx - 1, y, z])].fill(false);
            } else {
                solid[grid.index([0, y, z])] = false;
                solid[grid.index([nx - 1, y, z])] = false;
            }
        }
    }
}

/// Each solid cell's `k` smallest field values over the fields that joined it.
///
/// A field that reaches a cell farther than k others would stay farther than those k past
/// that cell too (each of them is at most that much nearer there, and paths go on the same
/// way), so it cannot be among the k nearest anywhere it would go from there: the
/// k-nearest-site variant of Dijkstra. For skinning this leaves each bone's walk to the
/// region where it is among the k nearest, instead of the whole volume, and changes none
/// of the k nearest.
pub struct Nearest {
    k: usize,
    /// Per grid cell, the k-th smallest value ([`UNREACHED`] until k fields reached it).
    /// Laid out like a field, so the walk reads it where it reads the field.
    kth: Vec<u32>,
    /// Grid cell → index among the solid cells, for `best`.
    rank: Vec<u32>,
    /// `k` values per solid cell, in no order.
    best: Vec<u32>,
    /// Fields joined so far.
    joined: usize,
}

impl Nearest {
    pub fn new(volume: &Volume, k: usize) -> Nearest {
        let k = k.max(1);
        let mut rank = vec![u32::MAX; volume.solid.len()];
        for (r, &c) in volume.cells.iter().enumerate() {
            rank[c as usize] = r as u32;
        }
        Nearest {
            k,
            kth: vec![UNREACHED; volume.solid.len()],
            rank,
            best: vec![UNREACHED; volume.cells.len() * k],
            joined: 0,
        }
    }

    /// One of the first k fields joins: its values fill a slot of every cell.
    fn fill(&mut self, volume: &Volume, dist: &[u32]) {
        let (k, j) = (self.k, self.joined);
        for (r, &c) in volume.cells.iter().enumerate() {
            self.best[r * k + j] = dist[c as usize];
        }
        self.joined += 1;
        if self.joined == k {
            for (r, &c) in volume.cells.iter().enumerate() {
                self.kth[c as usize] = self.best[r * k..(r + 1) * k]
                    .iter()
                    .copied()
                    .max()
                    .unwrap_or(UNREACHED);
            }
        }
    }

    /// Adds a settled value (once k fields have joined). The k values are kept unsorted:
    /// replacing the largest and finding the new largest is a few compares, where keeping
    /// them sorted cost a memmove per settled cell (as much as the rest of the walk).
    fn insert(&mut self, cell: usize, d: u32) {
        if d >= self.kth[cell] {
            return;
        }
        let at = self.rank[cell] as usize * self.k;
        let list = &mut self.best[at..at + self.k];
        let top = (0..self.k).fold(0, |t, i| if list[i] > list[t] { i } else { t });
        list[top] = d;
        self.kth[cell] = list.iter().copied().max().unwrap_or(UNREACHED);
    }
}

/// The part of `seg` that [`Volume::cells_on`] walks, and in how many steps (two per
/// cell).
fn walk(g: &Grid, seg: &Segment) -> Option<(Segment, usize)> {
    let seg = clip_to_grid(g, seg)?;
    let len = seg.a.distance(seg.b);
    // The clipped part lies in the grown box, so its length is finite and at most the
    // box's diagonal; the cap only guards against rounding.
    let cap = 2 * (g.dims.iter().sum::<usize>() + 6);
    let steps = ((len / (g.cell * 0.5)).ceil().max(1.0) as usize).min(cap);
    Some((seg, steps))
}

/// The part of `seg` within the grid's box grown by one cell (a step's 3×3×3
/// neighbourhood reaches that far out), or `None` when the segment misses it or is not
/// finite. A segment wholly inside is returned as it is, to the bit. Every cell within
/// [`ON_BONE`] cells of the segment has its nearest point on the part kept, so the cells
/// found and their distances are those of the whole segment, as far as `f32` can place a
/// segment far longer than the grid (one of 1e30 units cannot be placed to a cell).
fn clip_to_grid(g: &Grid, seg: &Segment) -> Option<Segment> {
    let d = seg.b - seg.a;
    if !(seg.a.is_finite() && seg.b.is_finite() && d.is_finite()) {
        return None;
    }
    let lo = g.origin - Vec3::splat(g.cell);
    let hi = g.origin + Vec3::from(g.dims.map(|n| n as f32)) * g.cell + Vec3::splat(g.cell);
    let (mut t0, mut t1) = (0.0f32, 1.0f32);
    for k in 0..3 {
        if d[k] == 0.0 {
            if seg.a[k] < lo[k] || seg.a[k] > hi[k] {
                return None;
            }
            continue;
        }
        let (u, v) = ((lo[k] - seg.a[k]) / d[k], (hi[k] - seg.a[k]) / d[k]);
        t0 = t0.max(u.min(v));
        t1 = t1.min(u.max(v));
    }
    if t0 > t1 {
        return None;
    }
    Some(Segment {
        a: if t0 > 0.0 { seg.a + d * t0 } else { seg.a },
        b: if t1 < 1.0 { seg.a + d * t1 } else { seg.b },
    })
}

/// Marks cells visited during one walk without clearing a whole array each time.
pub struct Stamp {
    marks: Vec<u32>,
    now: u32,
}

impl Stamp {
    pub fn new(len: usize) -> Stamp {
        Stamp {
            marks: vec![0; len],
            now: 0,
        }
    }

    fn next(&mut self) {
        self.now += 1;
    }

    fn first_visit(&mut self, i: usize) -> bool {
        let seen = self.marks[i] == self.now;
        self.marks[i] = self.now;
        !seen
    }
}

/// Dial's bucket queue over a ring of distances `cur .. cur + RING`.
#[derive(Default)]
pub struct Ring {
    buckets: Vec<Vec<u32>>,
    pending: usize,
    /// Cells the last field set, so the next one resets only those.
    touched: Vec<u32>,
}

impl Ring {
    fn clear(&mut self) {
        self.buckets.resize_with(RING, Vec::new);
        self.buckets.iter_mut().for_each(Vec::clear);
        self.pending = 0;
        self.touched.clear();
    }

    fn push(&mut self, d: u32, c: u32) {
        self.buckets[d as usize % RING].push(c);
        self.pending += 1;
        self.touched.push(c);
    }

    fn pop(&mut self, d: u32) -> Option<u32> {
        let c = self.buckets[d as usize % RING].pop()?;
        self.pending -= 1;
        Some(c)
    }
}

/// The up to 8 cells whose centres surround each vertex (the trilinear stencil), each
/// with the vertex's distance to its centre. A vertex's distance to a bone is the least
/// over its solid stencil cells of field + offset, which removes most of the grid's
/// staircase from the weights.
pub struct Stencils {
    pub start: Vec<u32>,
    pub cells: Vec<(u32, f32)>,
}

impl Stencils {
    pub fn new(volume: &Volume, positions: &[Vec3]) -> Stencils {
        let g = &volume.grid;
        let mut start = Vec::with_capacity(positions.len() + 1);
        let mut cells = Vec::with_capacity(positions.len() * 8);
        start.push(0);
        for &p in positions {
            let first = cells.len();
            let base = g.cell_of(p - Vec3::splat(g.cell * 0.5));
            for k in 0..8 {
                let c = [
                    (base[0] + (k & 1)).min(g.dims[0] - 1),
                    (base[1] + ((k >> 1) & 1)).min(g.dims[1] - 1),
                    (base[2] + ((k >> 2) & 1)).min(g.dims[2] - 1),
                ];
                let i = g.index(c);
                // Clamping at the grid's edge can repeat a cell.
                let repeated = cells[first..].iter().any(|x: &(u32, f32)| x.0 == i as u32);
                if volume.solid[i] && !repeated {
                    cells.push((i as u32, p.distance(g.center(c))));
                }
            }
            start.push(cells.len() as u32);
        }
        Stencils { start, cells }
    }

    pub fn of(&self, v: usize) -> &[(u32, f32)] {
        &self.cells[self.start[v] as usize..self.start[v + 1] as usize]
    }

    /// The vertex's distance to the field's seeds in mesh units, or None if unreached.
    pub fn distance(&self, volume: &Volume, v: usize, dist: &[u32]) -> Option<f32> {
        self.of(v)
            .iter()
            .filter(|(c, _)| dist[*c as usize] != UNREACHED)
            .map(|&(c, off)| volume.to_mesh(dist[c as usize]) + off)
            .min_by(f32::total_cmp)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The unbounded field from one cell.
    fn field_from(v: &Volume, at: [usize; 3]) -> Vec<u32> {
        let (mut dist, mut ring) = (Vec::new(), Ring::default());
        v.field(&[(v.grid.index(at) as u32, 0)], &mut dist, &mut ring, None);
        dist
    }

    fn slab(dims: [usize; 3]) -> Volume {
        let grid = Grid {
            origin: Vec3::ZERO,
            cell: 1.0,
            dims,
        };
        let mut solid = vec![false; dims.iter().product()];
        for z in 2..dims[2] - 2 {
            for y in 2..dims[1] - 2 {
                for x in 2..dims[0] - 2 {
                    solid[grid.index([x, y, z])] = true;
                }
            }
        }
        Volume::new(grid, solid)
    }

    #[test]
    fn field_follows_chamfer_steps() {
        let v = slab([12, 12, 12]);
        let dist = field_from(&v, [2, 2, 2]);
        assert_eq!(dist[v.grid.index([5, 2, 2])], 30);
        assert_eq!(dist[v.grid.index([5, 5, 2])], 42);
        assert_eq!(dist[v.grid.index([5, 5, 5])], 51);
        assert_eq!(dist[v.grid.index([0, 0, 0])], 0, "outside the solid");
    }

    #[test]
    fn a_bone_far_longer_than_the_grid_is_walked_only_where_it_crosses() {
        let v = slab([12, 12, 12]);
        let y = Vec3::new(0.0, 6.5, 6.5);
        let cells = |a: Vec3, b: Vec3| {
            let mut stamp = Stamp::new(v.solid.len());
            let mut c = v.cells_on(&Segment { a, b }, &mut stamp);
            c.sort_by_key(|&(i, _)| i);
            c
        };
        // 10^4 units each way: the same cells as the bone clipped by hand.
        let long = cells(y + Vec3::X * -1e4, y + Vec3::X * 1e4);
        let inside = cells(y + Vec3::X * -1.0, y + Vec3::X * 13.0);
        assert_eq!(long.len(), inside.len());
        assert!(!long.is_empty());
        for ((i, d), (j, e)) in long.iter().zip(&inside) {
            assert_eq!(i, j);
            assert!((d - e).abs() < 1e-2, "{d} {e}");
        }
        // A joint 1e30 units away (a hostile transform): the steps once overflowed to
        // usize::MAX, a hang; now they are bounded by the grid.
        let huge = Segment {
            a: y + Vec3::X * -1e30,
            b: y + Vec3::X * 1e30,
        };
        let (_, steps) = walk(&v.grid, &huge).expect("crosses the grid");
        assert!(steps <= 2 * (36 + 6), "{steps} steps");
        cells(huge.a, huge.b);
        assert!(
            cells(y + Vec3::Y * 1e30, y + Vec3::Y * 2e30).is_empty(),
            "misses"
        );
        assert!(cells(Vec3::splat(f32::NAN), y).is_empty(), "not finite");
        let inner = (y + Vec3::X * 3.0, y + Vec3::X * 5.0);
        let clipped = clip_to_grid(
            &v.grid,
            &Segment {
                a: inner.0,
                b: inner.1,
            },
        )
        .unwrap();
        assert_eq!(
            (clipped.a, clipped.b),
            inner,
            "inside: unchanged to the bit"
        );
    }

    #[test]
    fn the_grid_border_is_never_solid() {
        // Solid everywhere, the outer layer included: the walk, whose neighbour indices are
        // unchecked, must never step off the grid.
        let dims = [5, 4, 6];
        let grid = Grid {
            origin: Vec3::ZERO,
            cell: 1.0,
            dims,
        };
        let v = Volume::new(grid, vec![true; dims.iter().product()]);
        let interior = 3 * 2 * 4;
        assert_eq!(v.cells.len(), interior);
        assert!(!v.solid[v.grid.index([0, 1, 1])] && !v.solid[v.grid.index([4, 3, 5])]);
        let dist = field_from(&v, [1, 1, 1]);
        assert!(v.cells.iter().all(|&c| dist[c as usize] != UNREACHED));
        assert_eq!(dist[v.grid.index([3, 2, 4])], 17 + 14 + 10);
    }

    #[test]
    fn paths_go_around_a_wall() {
        // A U shape: two arms joined at the bottom; the straight line between the arm
        // tops crosses empty space.
        let mut v = slab([14, 14, 5]);
        for y in 4..12 {
            for x in 6..8 {
                let i = v.grid.index([x, y, 2]);
                v.solid[i] = false;
            }
        }
        let v = Volume::new(v.grid.clone(), v.solid);
        let dist = field_from(&v, [3, 11, 2]);
        let across = v.to_mesh(dist[v.grid.index([10, 11, 2])]);
        assert!(across > 14.0, "went around the wall: {across}");
    }

    #[test]
    fn pruned_fields_keep_each_cells_k_nearest() {
        // A slab with a wall, so some paths bend, and 12 small seed sets spread over it.
        let mut v = slab([20, 16, 9]);
        for y in 2..12 {
            for z in 2..7 {
                let i = v.grid.index([9, y, z]);
                v.solid[i] = false;
            }
        }
        let v = Volume::new(v.grid.clone(), v.solid);
        let mut rng = 0x2545_f491_u64;
        let mut next = |n: usize| {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (rng >> 33) as usize % n
        };
        let sets: Vec<Vec<(u32, u32)>> = (0..12)
            .map(|_| {
                (0..1 + next(3))
                    .map(|_| (v.cells[next(v.cells.len())], next(8) as u32))
                    .collect()
            })
            .collect();
        let k = 3;
        let (mut dist, mut ring) = (Vec::new(), Ring::default());
        let mut full: Vec<Vec<u32>> = vec![Vec::new(); v.solid.len()];
        let mut pruned: Vec<Vec<u32>> = vec![Vec::new(); v.solid.len()];
        let mut nearest = Nearest::new(&v, k);
        let mut skipped = 0;
        for seeds in &sets {
            v.field(seeds, &mut dist, &mut ring, None);
            for &c in &v.cells {
                full[c as usize].push(dist[c as usize]);
            }
            v.field(seeds, &mut dist, &mut ring, Some((&mut nearest, true)));
            for &c in &v.cells {
                pruned[c as usize].push(dist[c as usize]);
                skipped += usize::from(dist[c as usize] == UNREACHED);
            }
        }
        assert!(
            skipped > v.cells.len(),
            "pruning left out only {skipped} cells"
        );
        for &c in &v.cells {
            let (f, p) = (&full[c as usize], &pruned[c as usize]);
            let mut fs = f.clone();
            fs.sort_unstable();
            let kth = fs[k - 1];
            for (b, (&x, &y)) in f.iter().zip(p).enumerate() {
                // Every field among the k nearest is exact; the others are never nearer.
                if x <= kth {
                    assert_eq!(x, y, "cell {c}, field {b}");
                } else {
                    assert!(y >= x && (y > kth || y == UNREACHED), "cell {c}, field {b}");
                }
            }
        }
    }
}
