//! Solid voxelization: which cells of a regular grid lie on or inside the mesh.
//!
//! Surface cells are those a triangle overlaps (an exact triangle–box test, so the
//! surface has no gaps a 6-connected fill could slip through). Everything a flood fill
//! from the grid border reaches without crossing the surface is outside; the rest is
//! inside. An open mesh lets the fill in, which leaves just its shell: distances then
//! run along the surface instead of through the volume, which degrades gracefully.

use glam::Vec3;

/// Empty cells kept around the mesh, so the border is always outside and every solid
/// cell's 26 neighbours are in the grid.
const PAD: usize = 2;

/// A regular grid of cubes of side `cell`, the first one's corner at `origin`.
#[derive(Clone, Debug)]
pub struct Grid {
    pub origin: Vec3,
    pub cell: f32,
    pub dims: [usize; 3],
}

impl Grid {
    /// A grid over the box `lo`–`hi` with `resolution` cells along its longest side.
    pub fn around(lo: Vec3, hi: Vec3, resolution: usize) -> Grid {
        let extent = (hi - lo).max_element().max(1e-6);
        let cell = extent / resolution.max(1) as f32;
        let dims = ((hi - lo) / cell)
            .to_array()
            .map(|n| n.ceil().max(1.0) as usize + 2 * PAD);
        Grid {
            origin: lo - Vec3::splat(PAD as f32 * cell),
            cell,
            dims,
        }
    }

    pub fn index(&self, c: [usize; 3]) -> usize {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }

    pub fn coords(&self, i: usize) -> [usize; 3] {
        let (nx, ny) = (self.dims[0], self.dims[1]);
        [i % nx, (i / nx) % ny, i / (nx * ny)]
    }

    pub fn center(&self, c: [usize; 3]) -> Vec3 {
        self.origin + (Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32) + 0.5) * self.cell
    }

    /// The cell holding `p`, clamped into the grid.
    pub fn cell_of(&self, p: Vec3) -> [usize; 3] {
        let k = ((p - self.origin) / self.cell).floor();
        let clamp = |v: f32, n: usize| (v.max(0.0) as usize).min(n - 1);
        [
            clamp(k.x, self.dims[0]),
            clamp(k.y, self.dims[1]),
            clamp(k.z, self.dims[2]),
        ]
    }

    /// Index offsets of the 26 neighbours, with their step lengths in cells.
    pub fn neighbour_offsets(&self) -> Vec<(isize, f32)> {
        let (sx, sy) = (1isize, self.dims[0] as isize);
        let sz = sy * self.dims[1] as isize;
        let mut out = Vec::with_capacity(26);
        for dz in -1isize..=1 {
            for dy in -1isize..=1 {
                for dx in -1isize..=1 {
                    let n = dx.abs() + dy.abs() + dz.abs();
                    if n > 0 {
                        out.push((dx * sx + dy * sy + dz * sz, (n as f32).sqrt()));
                    }
                }
            }
        }
        out
    }
}

/// A box of cells `lo .. lo + dims` inside a [`Grid`].
#[derive(Clone, Copy, Debug)]
pub struct Region {
    pub lo: [usize; 3],
    pub dims: [usize; 3],
}

impl Region {
    pub fn whole(grid: &Grid) -> Region {
        Region {
            lo: [0; 3],
            dims: grid.dims,
        }
    }

    /// The cells overlapping `lo`–`hi`, grown by `margin` cells and clipped to the grid.
    pub fn around(grid: &Grid, lo: Vec3, hi: Vec3, margin: usize) -> Region {
        let a = grid.cell_of(lo);
        let b = grid.cell_of(hi);
        let mut r = Region {
            lo: [0; 3],
            dims: [0; 3],
        };
        for k in 0..3 {
            let l = a[k].saturating_sub(margin);
            let h = (b[k] + margin).min(grid.dims[k] - 1);
            r.lo[k] = l;
            r.dims[k] = h - l + 1;
        }
        r
    }

    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// Index within the region of a grid cell, or None when the cell is outside it.
    pub fn local(&self, c: [usize; 3]) -> Option<usize> {
        let mut l = [0; 3];
        for k in 0..3 {
            l[k] = c[k].checked_sub(self.lo[k]).filter(|&v| v < self.dims[k])?;
        }
        Some(l[0] + self.dims[0] * (l[1] + self.dims[1] * l[2]))
    }
}

/// The cells of `region` that the triangles `tris` overlap, one flag per region cell.
/// Every cell a triangle overlaps is inside the box of its corners' cells, so a region
/// holding that box sees all of the triangle's cells.
pub fn surface(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    tris: impl IntoIterator<Item = usize>,
    grid: &Grid,
    region: &Region,
) -> Vec<bool> {
    let mut surface = vec![false; region.len()];
    let half = Vec3::splat(grid.cell * 0.5);
    for t in tris {
        let [a, b, c] = triangles[t].map(|i| positions[i as usize]);
        let lo = grid.cell_of(a.min(b).min(c));
        let hi = grid.cell_of(a.max(b).max(c));
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    let Some(l) = region.local([x, y, z]) else {
                        continue;
                    };
                    if !surface[l] && triangle_box_overlap(grid.center([x, y, z]), half, a, b, c) {
                        surface[l] = true;
                    }
                }
            }
        }
    }
    surface
}

/// Sets the flags of `grid_flags` (one per cell of `grid`) that are set in `surface` (one
/// per cell of `region`, a box inside `grid`).
pub fn merge_into(grid_flags: &mut [bool], grid: &Grid, region: &Region, surface: &[bool]) {
    let [nx, ny, nz] = region.dims;
    for z in 0..nz {
        for y in 0..ny {
            let row = (z * ny + y) * nx;
            let at = grid.index([region.lo[0], region.lo[1] + y, region.lo[2] + z]);
            for (g, &s) in grid_flags[at..at + nx]
                .iter_mut()
                .zip(&surface[row..row + nx])
            {
                *g |= s;
            }
        }
    }
}

/// Solid cells of `region` given its surface cells: everything a 6-connected fill from
/// the region's border reaches without crossing the surface is outside.
pub fn fill(surface: &[bool], region: &Region) -> Vec<bool> {
    let [nx, ny, nz] = region.dims;
    // Border cells that are not surface are outside to begin with. Only interior cells
    // are ever pushed, so a popped cell's six neighbours are all in the region and the
    // fill's loop needs no coordinates or bounds checks; a border neighbour is already
    // outside or surface and is never pushed.
    let mut outside = vec![false; region.len()];
    let mut stack: Vec<usize> = Vec::new();
    let (sy, sz) = (nx, nx * ny);
    // Region dimensions are at least 1, so `n - 1` does not wrap.
    let interior = |x: usize, y: usize, z: usize| {
        (1..nx - 1).contains(&x) && (1..ny - 1).contains(&y) && (1..nz - 1).contains(&z)
    };
    for z in 0..nz {
        for y in 0..ny {
            let face = z == 0 || y == 0 || z + 1 == nz || y + 1 == ny;
            let mut mark = |x: usize| {
                let i = x + sy * y + sz * z;
                if surface[i] || outside[i] {
                    return;
                }
                outside[i] = true;
                let near = [
                    (x.wrapping_sub(1), y, z),
                    (x + 1, y, z),
                    (x, y.wrapping_sub(1), z),
                    (x, y + 1, z),
                    (x, y, z.wrapping_sub(1)),
                    (x, y, z + 1),
                ];
                // A wrapped coordinate is huge, so `interior` rejects it too.
                for (x, y, z) in near.into_iter().filter(|&(x, y, z)| interior(x, y, z)) {
                    let j = x + sy * y + sz * z;
                    if !surface[j] && !outside[j] {
                        outside[j] = true;
                        stack.push(j);
                    }
                }
            };
            if face {
                (0..nx).for_each(&mut mark);
            } else {
                mark(0);
                mark(nx - 1);
            }
        }
    }
    while let Some(i) = stack.pop() {
        for j in [i - 1, i + 1, i - sy, i + sy, i - sz, i + sz] {
            if !surface[j] && !outside[j] {
                outside[j] = true;
                stack.push(j);
            }
        }
    }
    outside.iter().map(|o| !o).collect()
}

/// Akenine-Möller's separating-axis test of a triangle against an axis-aligned box.
/// The box is grown by a hair so triangles lying exactly on a cell face count for both
/// cells, which keeps the surface watertight.
fn triangle_box_overlap(center: Vec3, half: Vec3, a: Vec3, b: Vec3, c: Vec3) -> bool {
    let h = half * (1.0 + 1e-4);
    let v = [a - center, b - center, c - center];
    let e = [v[1] - v[0], v[2] - v[1], v[0] - v[2]];
    // The box's face normals.
    for k in 0..3 {
        let (lo, hi) = min_max(v.iter().map(|p| p[k]));
        if lo > h[k] || hi < -h[k] {
            return false;
        }
    }
    // The triangle's plane.
    let n = e[0].cross(e[1]);
    let r = h.dot(n.abs());
    if n.dot(v[0]).abs() > r {
        return false;
    }
    // Cross products of edges with the box axes.
    for edge in e {
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            let ax = axis.cross(edge);
            if ax.length_squared() < 1e-30 {
                continue;
            }
            let (lo, hi) = min_max(v.iter().map(|p| p.dot(ax)));
            let r = h.dot(ax.abs());
            if lo > r || hi < -r {
                return false;
            }
        }
    }
    true
}

fn min_max(xs: impl Iterator<Item = f32>) -> (f32, f32) {
    xs.fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), x| {
        (lo.min(x), hi.max(x))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fill the plain way: every cell's six neighbours with bounds checks, from every
    /// non-surface border cell.
    fn reference_fill(surface: &[bool], [nx, ny, nz]: [usize; 3]) -> Vec<bool> {
        let mut outside = vec![false; surface.len()];
        let idx = |x: usize, y: usize, z: usize| x + nx * (y + ny * z);
        let mut stack = Vec::new();
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let border =
                        x == 0 || y == 0 || z == 0 || x + 1 == nx || y + 1 == ny || z + 1 == nz;
                    if border && !surface[idx(x, y, z)] {
                        outside[idx(x, y, z)] = true;
                        stack.push([x, y, z]);
                    }
                }
            }
        }
        while let Some(c) = stack.pop() {
            for k in 0..3 {
                for up in [false, true] {
                    let mut n = c;
                    if up {
                        n[k] += 1;
                    } else if n[k] > 0 {
                        n[k] -= 1;
                    } else {
                        continue;
                    }
                    if n[0] < nx && n[1] < ny && n[2] < nz {
                        let i = idx(n[0], n[1], n[2]);
                        if !surface[i] && !outside[i] {
                            outside[i] = true;
                            stack.push(n);
                        }
                    }
                }
            }
        }
        outside.iter().map(|o| !o).collect()
    }

    #[test]
    fn fill_matches_the_plain_fill_on_random_walls() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let mut enclosed = 0;
        for round in 0..400 {
            let dims = [0, 1, 2].map(|_| 1 + (next() % 9) as usize);
            let density = [10, 30, 50, 70][round % 4];
            let region = Region { lo: [0; 3], dims };
            let surface: Vec<bool> = (0..region.len()).map(|_| next() % 100 < density).collect();
            let got = fill(&surface, &region);
            assert_eq!(got, reference_fill(&surface, dims), "dims {dims:?}");
            enclosed += got
                .iter()
                .zip(&surface)
                .filter(|(s, w)| **s && !**w)
                .count();
        }
        assert!(enclosed > 0, "some rounds must enclose empty cells");
    }

    #[test]
    fn parts_surfaces_merged_are_the_whole_surface() {
        // Two overlapping boxes and a far one, each its own part.
        let mut p = Vec::new();
        let mut t = Vec::new();
        for (lo, hi) in [
            (Vec3::ZERO, Vec3::ONE),
            (Vec3::splat(0.5), Vec3::new(1.7, 1.2, 1.4)),
            (Vec3::new(3.0, 0.2, 0.1), Vec3::new(3.3, 0.9, 0.4)),
        ] {
            let (bp, bt) = cube(lo, hi);
            let base = p.len() as u32;
            p.extend(bp);
            t.extend(bt.into_iter().map(|tri: [u32; 3]| tri.map(|i| i + base)));
        }
        let grid = Grid::around(Vec3::ZERO, Vec3::new(3.3, 1.2, 1.4), 24);
        let whole = Region::whole(&grid);
        let expect = surface(&p, &t, 0..t.len(), &grid, &whole);
        let mut merged = vec![false; whole.len()];
        for part in [0..12, 12..24, 24..36] {
            let (lo, hi) = part.clone().flat_map(|i| t[i]).fold(
                (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
                |(a, b), i| (a.min(p[i as usize]), b.max(p[i as usize])),
            );
            let region = Region::around(&grid, lo, hi, 2);
            let s = surface(&p, &t, part, &grid, &region);
            merge_into(&mut merged, &grid, &region, &s);
        }
        assert!(expect.iter().filter(|&&s| s).count() > 100);
        assert_eq!(merged, expect);
    }

    /// A closed axis-aligned box mesh, 12 triangles.
    pub(crate) fn cube(lo: Vec3, hi: Vec3) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let p: Vec<Vec3> = (0..8)
            .map(|i| {
                Vec3::new(
                    if i & 1 == 0 { lo.x } else { hi.x },
                    if i & 2 == 0 { lo.y } else { hi.y },
                    if i & 4 == 0 { lo.z } else { hi.z },
                )
            })
            .collect();
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let t = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        (p, t)
    }

    #[test]
    fn a_closed_box_is_filled_and_an_open_one_is_a_shell() {
        let (p, t) = cube(Vec3::ZERO, Vec3::ONE);
        let grid = Grid::around(Vec3::ZERO, Vec3::ONE, 10);
        let region = Region::whole(&grid);
        let s = fill(&surface(&p, &t, 0..t.len(), &grid, &region), &region);
        let mid = grid.index(grid.cell_of(Vec3::splat(0.5)));
        assert!(s[mid], "the middle of a closed box is solid");
        assert!(!s[0], "the corner of the grid is outside");
        // Without the top face, the fill gets in and only the walls stay solid.
        let open: Vec<usize> = (0..t.len()).filter(|&i| !(i == 6 || i == 7)).collect();
        let s = fill(&surface(&p, &t, open, &grid, &region), &region);
        assert!(!s[mid]);
        let wall = grid.index(grid.cell_of(Vec3::new(0.0, 0.5, 0.5)));
        assert!(s[wall]);
    }

    #[test]
    fn box_test_matches_obvious_cases() {
        let h = Vec3::splat(0.5);
        let (a, b, c) = (
            Vec3::new(-2.0, 0.0, -2.0),
            Vec3::new(2.0, 0.0, -2.0),
            Vec3::new(0.0, 0.0, 2.0),
        );
        assert!(triangle_box_overlap(Vec3::ZERO, h, a, b, c));
        assert!(!triangle_box_overlap(Vec3::new(0.0, 0.7, 0.0), h, a, b, c));
        assert!(!triangle_box_overlap(Vec3::new(3.0, 0.0, 1.9), h, a, b, c));
    }
}
