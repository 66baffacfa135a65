//! A library of rigged meshes to borrow skeletons from: the mesh most like the one being
//! rigged (by the shape of its surface with each axis of the bounding box stretched to
//! the same length, so that a stocky and a slender build of one character still match,
//! plus a smaller term for the box's proportions) lends its skeleton, which is then moved
//! onto the new mesh by the displacement between the two surfaces. An artist rigging a
//! character that resembles one already rigged starts from that rig; so does this.
//!
//! The library is a file (`rigserve library` writes it from any folder of rigged files
//! with a manifest: compact binary, [`codec`], or JSON when the name ends in `.json`); it
//! holds, per entry, surface samples and the skeleton in box coordinates, never the mesh
//! itself. The one the service uses by default is committed as `models/library.bin`, so
//! a clone rigs as the figures in the model card were measured.

mod codec;

use super::lanes;
use crate::mesh::{sample_surface, Mesh};
use crate::rig::Skeleton;
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Surface samples kept per library entry and drawn from the query.
pub const SHAPE_POINTS: usize = 512;
/// Widths of the Gaussians (box coordinates, each axis in [-1, 1]) over which surface
/// displacements are averaged, coarse to fine. Chosen leave-one-out on the `train` split
/// of ../shared/rigs (CD-J2J 0.0757 without a warp, 0.0702 with one scale of 0.12,
/// 0.0675 with 0.5, 0.3, 0.2; with the later proportion term and joints pulled inside,
/// 0.0617 with those three and 0.0611–0.0612 with any of four coarser starts tried,
/// `rigserve eval --retrieval --split train`; MODEL_CARD.md, "Warp widths").
const WARP_SCALES: [f32; 4] = [0.6, 0.4, 0.3, 0.2];
/// Weight of the mean |log ratio| of the boxes' proportions in the shape distance: box
/// coordinates hide whether a mesh is tall or long. Chosen leave-one-out on `train`
/// (CD-J2J 0.0675 at 0, 0.0642 at 0.05, 0.0626 at 0.2, 0.0638 at 0.5).
const PROPORTION_WEIGHT: f32 = 0.2;
/// Samples of the first, coarse comparison against every entry, and how many of the
/// nearest are then compared on all samples. On the `train` split leave-one-out the
/// entry chosen is the one the full comparison of every entry chooses for all 140 files.
const COARSE_POINTS: usize = 128;
pub const RERANKED: usize = 12;
/// Written into the file; a file of another version is refused.
pub const LIBRARY_VERSION: u32 = 1;

/// A skeleton and the surface it was rigged on, both in box coordinates.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Entry {
    pub name: String,
    pub category: String,
    /// The bounding box's sides over its longest.
    proportions: Vec3,
    points: Vec<Vec3>,
    skeleton: Skeleton,
}

/// Box coordinates: the bounding box mapped to [-1, 1] along every axis.
#[derive(Clone, Copy, Debug)]
pub struct BoxFrame {
    lo: Vec3,
    size: Vec3,
}

impl BoxFrame {
    pub fn of(mesh: &Mesh) -> BoxFrame {
        let (lo, hi) = mesh.bounds();
        BoxFrame::from_bounds(lo, hi)
    }
    pub fn from_bounds(lo: Vec3, hi: Vec3) -> BoxFrame {
        BoxFrame {
            lo,
            size: (hi - lo).max(Vec3::splat((hi - lo).max_element() * 1e-3 + 1e-12)),
        }
    }
    pub fn proportions(&self) -> Vec3 {
        self.size / self.size.max_element()
    }
    pub fn apply(&self, p: Vec3) -> Vec3 {
        (p - self.lo) / self.size * 2.0 - Vec3::ONE
    }
    pub fn invert(&self, q: Vec3) -> Vec3 {
        self.lo + (q + Vec3::ONE) * 0.5 * self.size
    }
}

pub fn shape_points(mesh: &Mesh, seed: u64) -> Vec<Vec3> {
    let frame = BoxFrame::of(mesh);
    sample_surface(mesh, SHAPE_POINTS, seed)
        .points
        .into_iter()
        .map(|p| frame.apply(p))
        .collect()
}

/// Surface samples already drawn (`x y z nx ny nz` rows) as independent draws of
/// [`SHAPE_POINTS`] each, in `frame`'s box coordinates, for [`Entry::fit_mean`]; fewer
/// samples than one draw are one draw.
pub fn draws_of_samples(rows: &[[f32; 6]], frame: &BoxFrame) -> Vec<Vec<Vec3>> {
    if rows.len() < SHAPE_POINTS {
        return vec![shape_of_samples(rows, frame)];
    }
    rows.chunks_exact(SHAPE_POINTS)
        .map(|c| shape_of_samples(c, frame))
        .collect()
}

/// The first [`SHAPE_POINTS`] of surface samples already drawn (`x y z nx ny nz` rows;
/// independent draws, so any prefix is itself a sample), in `frame`'s box coordinates.
pub fn shape_of_samples(rows: &[[f32; 6]], frame: &BoxFrame) -> Vec<Vec3> {
    rows.iter()
        .take(SHAPE_POINTS)
        .map(|r| frame.apply(Vec3::new(r[0], r[1], r[2])))
        .collect()
}

impl Entry {
    /// `skeleton` in the frame of `mesh`.
    pub fn new(name: &str, category: &str, mesh: &Mesh, skeleton: &Skeleton) -> Entry {
        let frame = BoxFrame::of(mesh);
        let mut s = skeleton.clone();
        s.map_points(|p| frame.apply(p));
        Entry {
            name: name.to_string(),
            category: category.to_string(),
            proportions: frame.proportions(),
            points: shape_points(mesh, 7),
            skeleton: s,
        }
    }

    pub fn bones(&self) -> usize {
        self.skeleton.len()
    }

    /// Symmetric chamfer distance between this entry's surface and `points` (both in box
    /// coordinates), plus how far apart the boxes' proportions are.
    pub fn distance(&self, points: &[Vec3], proportions: Vec3) -> f32 {
        self.distance_on(usize::MAX, points, proportions)
    }

    /// [`Entry::distance`] on this entry's first `n` samples.
    fn distance_on(&self, n: usize, points: &[Vec3], proportions: Vec3) -> f32 {
        let own = &self.points[..self.points.len().min(n)];
        let ln = |v: Vec3| Vec3::new(v.x.max(1e-3).ln(), v.y.max(1e-3).ln(), v.z.max(1e-3).ln());
        (directed(own, points) + directed(points, own)) * 0.5
            + PROPORTION_WEIGHT * (ln(self.proportions) - ln(proportions)).abs().element_sum() / 3.0
    }

    /// The skeleton moved onto the mesh whose box-coordinate samples are `points`
    /// (returned in box coordinates); `warp` false only stretches it onto the box.
    ///
    /// The warp is a coarse-to-fine non-rigid registration: at each scale the entry's
    /// surface samples and the mesh's are paired with their nearest neighbours both
    /// ways, the pairs' displacements are averaged under a Gaussian around every point
    /// to move, and both the entry's samples and its joints follow that field, so the
    /// next, narrower scale starts from surfaces already closer.
    pub fn fit(&self, points: &[Vec3], warp: bool) -> Skeleton {
        let mut s = self.skeleton.clone();
        if !warp || points.is_empty() {
            return s;
        }
        let mut src = self.points.clone();
        for sigma in WARP_SCALES {
            // Pairs: each entry sample with its nearest mesh sample, then each mesh sample
            // with its nearest entry sample; a pair is where it starts and how it moves.
            let mut keys = Vec::with_capacity(src.len() + points.len());
            let mut moves = Vec::with_capacity(src.len() + points.len());
            for (&p, q) in src.iter().zip(lanes::nearest_index(&src, points)) {
                keys.push(p);
                moves.push(q.map_or(Vec3::ZERO, |q| points[q] - p));
            }
            for (&q, p) in points.iter().zip(lanes::nearest_index(points, &src)) {
                let p = p.map_or(q, |p| src[p]);
                keys.push(p);
                moves.push(q - p);
            }
            let inv = 1.0 / (2.0 * sigma * sigma);
            let field = |at: &[Vec3]| lanes::gaussian_mean(at, &keys, &moves, inv);
            let ends: Vec<Vec3> = s.bones.iter().flat_map(|b| [b.head, b.tail]).collect();
            for (b, d) in s.bones.iter_mut().zip(field(&ends).chunks_exact(2)) {
                b.head += d[0];
                b.tail += d[1];
            }
            // The samples only guide the next, narrower scale.
            if sigma != WARP_SCALES[WARP_SCALES.len() - 1] {
                let d = field(&src);
                src.iter_mut().zip(d).for_each(|(p, d)| *p += d);
            }
        }
        s
    }

    /// [`Entry::fit`] against each of several independent surface draws of the same mesh,
    /// joint by joint averaged (one entry, one bone tree). The warp pairs the nearest
    /// neighbours of one random draw, so a borrowed rig moved by 0.005–0.01 CD-B2B between
    /// seeds on the same file; the mean of the model's four draws of 512 carries less of
    /// that noise. Rule written first (MODEL_CARD.md, "The library rig fitted four times"):
    /// `train` leave-one-out, full system, seeds 0–4, CD-J2J / B2B 0.0487 / 0.0411 ->
    /// 0.0481 / 0.0405; 300 held-out synthetic rigs, seeds 0–2, 0.0605 / 0.0499 -> 0.0595 /
    /// 0.0489. The warp's pairing and Gaussian averaging run eight points at a time
    /// ([`lanes::nearest_index`], [`lanes::gaussian_mean`]), so the four fits cost what one
    /// did before (the Dragon end to end, best of 4: 84 ms with one fit, 121 ms with four
    /// before the lanes, 88 ms after).
    pub fn fit_mean<D: AsRef<[Vec3]>>(&self, draws: &[D]) -> Skeleton {
        let fits: Vec<Skeleton> = draws.iter().map(|d| self.fit(d.as_ref(), true)).collect();
        let Some(first) = fits.first() else {
            return self.skeleton.clone();
        };
        let mut mean = first.clone();
        let n = fits.len() as f32;
        for (i, b) in mean.bones.iter_mut().enumerate() {
            b.head = fits.iter().map(|f| f.bones[i].head).sum::<Vec3>() / n;
            b.tail = fits.iter().map(|f| f.bones[i].tail).sum::<Vec3>() / n;
        }
        mean
    }
}

fn directed(a: &[Vec3], b: &[Vec3]) -> f32 {
    if a.is_empty() || b.is_empty() {
        return f32::INFINITY;
    }
    lanes::nearest2(a, b)
        .into_iter()
        .map(f32::sqrt)
        .sum::<f32>()
        / a.len() as f32
}

#[derive(Debug, thiserror::Error)]
pub enum LibraryError {
    #[error("skeleton library {0}: {1}")]
    Read(PathBuf, std::io::Error),
    #[error("skeleton library {0} is not a library file: {1}")]
    Parse(PathBuf, String),
    #[error("skeleton library {0} is version {1}, this build reads version {LIBRARY_VERSION}")]
    Version(PathBuf, u32),
    #[error("skeleton library {0}: entry {1} is unusable ({2})")]
    Entry(PathBuf, String, String),
}

impl LibraryError {
    pub fn code(&self) -> &'static str {
        match self {
            LibraryError::Read(..) => "library_unreadable",
            LibraryError::Parse(..) => "library_malformed",
            LibraryError::Version(..) => "library_version",
            LibraryError::Entry(..) => "library_entry_invalid",
        }
    }
}

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Library {
    pub version: u32,
    pub entries: Vec<Entry>,
}

/// The library a models folder may hold (`library.bin` in it).
pub fn default_path(models: &Path) -> PathBuf {
    models.join("library.bin")
}

impl Library {
    pub fn new(entries: Vec<Entry>) -> Library {
        Library {
            version: LIBRARY_VERSION,
            entries,
        }
    }

    /// Reads and checks a library file: every entry needs surface samples and a valid
    /// skeleton with finite coordinates, or the file is refused.
    pub fn load(path: &Path) -> Result<Library, LibraryError> {
        let bytes = std::fs::read(path).map_err(|e| LibraryError::Read(path.into(), e))?;
        let parse = |e: String| LibraryError::Parse(path.into(), e);
        let lib: Library = if bytes.starts_with(codec::MAGIC) {
            codec::decode(&bytes).map_err(|e| parse(e.to_string()))?
        } else {
            serde_json::from_slice(&bytes).map_err(|e| parse(e.to_string()))?
        };
        if lib.version != LIBRARY_VERSION {
            return Err(LibraryError::Version(path.into(), lib.version));
        }
        for e in &lib.entries {
            let bad = |why: String| LibraryError::Entry(path.into(), e.name.clone(), why);
            if e.points.is_empty() || !e.points.iter().all(|p| p.is_finite()) {
                return Err(bad("no finite surface samples".into()));
            }
            if !(e.proportions.is_finite() && e.proportions.min_element() > 0.0) {
                return Err(bad("proportions are not positive".into()));
            }
            e.skeleton
                .validate(usize::MAX)
                .map_err(|err| bad(err.to_string()))?;
            if !e
                .skeleton
                .bones
                .iter()
                .all(|b| b.head.is_finite() && b.tail.is_finite())
            {
                return Err(bad("a joint is not finite".into()));
            }
        }
        Ok(lib)
    }

    /// Writes the compact form, or JSON when `path` ends in `.json`.
    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        let bytes = if path.extension().is_some_and(|e| e == "json") {
            serde_json::to_vec(self).map_err(std::io::Error::other)?
        } else {
            codec::encode(self)
        };
        std::fs::write(path, bytes)
    }

    /// Without the entries named in `names` (to score a split the library must not see).
    pub fn without(&self, names: &std::collections::HashSet<String>) -> Library {
        Library::new(
            self.entries
                .iter()
                .filter(|e| !names.contains(&e.name))
                .cloned()
                .collect(),
        )
    }

    /// The [`RERANKED`] entries nearest to `points`, by increasing distance; only those
    /// of `category` when it is given and the library has any.
    ///
    /// The distance is quadratic in the samples, so every entry is first compared on a
    /// prefix of [`COARSE_POINTS`] (the samples are independent draws, so a prefix is a
    /// sample too) and only the nearest are measured on all of them.
    pub fn ranked(
        &self,
        points: &[Vec3],
        proportions: Vec3,
        category: Option<&str>,
    ) -> Vec<(usize, f32)> {
        let same = |e: &Entry| category.is_none_or(|c| e.category == c);
        let any_same = self.entries.iter().any(same);
        let coarse = &points[..points.len().min(COARSE_POINTS)];
        let mut r: Vec<(usize, f32)> = self
            .entries
            .iter()
            .enumerate()
            .filter(|(_, e)| !any_same || same(e))
            .map(|(i, e)| (i, e.distance_on(COARSE_POINTS, coarse, proportions)))
            .collect();
        r.sort_by(|a, b| a.1.total_cmp(&b.1));
        r.truncate(RERANKED);
        for (i, d) in &mut r {
            *d = self.entries[*i].distance(points, proportions);
        }
        r.sort_by(|a, b| a.1.total_cmp(&b.1));
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::Bone;

    fn boxed(lo: Vec3, hi: Vec3) -> Mesh {
        crate::mesh::box_mesh(lo, hi)
    }

    /// Two boxes: a body and a second block standing out along +x at the top (an "arm").
    fn body_with_arm(arm: f32) -> Mesh {
        let mut m = boxed(Vec3::new(-0.2, 0.0, -0.2), Vec3::new(0.2, 2.0, 0.2));
        let a = boxed(Vec3::new(0.2, 1.6, -0.1), Vec3::new(0.2 + arm, 1.8, 0.1));
        let base = m.positions.len() as u32;
        m.positions.extend(a.positions);
        m.triangles
            .extend(a.triangles.iter().map(|t| t.map(|i| i + base)));
        m
    }

    fn skeleton(arm: f32) -> Skeleton {
        let mut s = Skeleton {
            bones: vec![
                Bone::new("hips", None, Vec3::new(0.0, 0.2, 0.0), Vec3::ZERO),
                Bone::new("chest", Some(0), Vec3::new(0.0, 1.7, 0.0), Vec3::ZERO),
                Bone::new("hand", Some(1), Vec3::new(0.2 + arm, 1.7, 0.0), Vec3::ZERO),
            ],
            ..Skeleton::default()
        };
        s.infer_tails();
        s
    }

    fn library() -> Library {
        Library::new(vec![
            Entry::new("armed", "humanoid", &body_with_arm(0.8), &skeleton(0.8)),
            Entry::new(
                "cube",
                "robot_prop",
                &boxed(Vec3::ZERO, Vec3::ONE),
                &skeleton(0.0),
            ),
            Entry::new(
                "slab",
                "humanoid",
                &boxed(Vec3::ZERO, Vec3::new(3.0, 0.2, 1.0)),
                &skeleton(0.0),
            ),
        ])
    }

    #[test]
    fn the_most_similar_shape_ranks_first_and_categories_filter() {
        let lib = library();
        // The same character with a shorter arm, scaled and moved: still nearest to "armed".
        let mut query = body_with_arm(0.5);
        query
            .positions
            .iter_mut()
            .for_each(|p| *p = *p * 3.0 + Vec3::X * 10.0);
        let frame = BoxFrame::of(&query);
        let pts = shape_points(&query, 1);
        let r = lib.ranked(&pts, frame.proportions(), None);
        assert_eq!(lib.entries[r[0].0].name, "armed", "{r:?}");
        assert!(r.windows(2).all(|w| w[0].1 <= w[1].1));
        let only = lib.ranked(&pts, frame.proportions(), Some("robot_prop"));
        assert_eq!(only.len(), 1);
        assert_eq!(lib.entries[only[0].0].name, "cube");
        // A category the library does not hold falls back to every entry.
        assert_eq!(lib.ranked(&pts, frame.proportions(), Some("fish")).len(), 3);
    }

    #[test]
    fn the_warp_moves_the_hand_to_the_new_arm_and_leaves_an_identical_mesh_alone() {
        let lib = library();
        let armed = &lib.entries[0];
        // Same mesh: the borrowed skeleton stays where it was.
        let same = body_with_arm(0.8);
        let f = BoxFrame::of(&same);
        let mut fit = armed.fit(&shape_points(&same, 3), true);
        fit.map_points(|q| f.invert(q));
        for (a, b) in fit.bones.iter().zip(&skeleton(0.8).bones) {
            assert!(
                a.head.distance(b.head) < 0.08,
                "{:?} vs {:?}",
                a.head,
                b.head
            );
        }
        // A longer arm on a mesh of the same size, so the box stretch alone cannot follow:
        // the body is thinner in box coordinates and the hand must move out with the arm.
        let long = body_with_arm(1.6);
        let f = BoxFrame::of(&long);
        let pts = shape_points(&long, 3);
        let mut stretched = armed.fit(&pts, false);
        stretched.map_points(|q| f.invert(q));
        let mut warped = armed.fit(&pts, true);
        warped.map_points(|q| f.invert(q));
        let truth = skeleton(1.6);
        let err = |s: &Skeleton| -> f32 {
            s.bones
                .iter()
                .zip(&truth.bones)
                .map(|(a, b)| a.head.distance(b.head))
                .sum()
        };
        assert!(
            err(&warped) < err(&stretched) * 0.8,
            "{} vs {}",
            err(&warped),
            err(&stretched)
        );
    }

    #[test]
    fn the_mean_fit_averages_the_fits_of_each_draw_joint_by_joint() {
        let lib = library();
        let armed = &lib.entries[0];
        let long = body_with_arm(1.6);
        let (a, b) = (shape_points(&long, 3), shape_points(&long, 4));
        let (fa, fb) = (armed.fit(&a, true), armed.fit(&b, true));
        assert_ne!(fa.bones[2].head, fb.bones[2].head, "draws differ");
        assert_eq!(armed.fit_mean(&[&a]), fa);
        let mean = armed.fit_mean(&[&a, &b]);
        for (i, m) in mean.bones.iter().enumerate() {
            let want = (fa.bones[i].head + fb.bones[i].head) * 0.5;
            assert!(
                m.head.distance(want) < 1e-5,
                "{i}: {:?} vs {want:?}",
                m.head
            );
            let want = (fa.bones[i].tail + fb.bones[i].tail) * 0.5;
            assert!(
                m.tail.distance(want) < 1e-5,
                "{i}: {:?} vs {want:?}",
                m.tail
            );
            assert_eq!((&m.name, m.parent), (&fa.bones[i].name, fa.bones[i].parent));
        }
        assert_eq!(
            armed.fit_mean::<&[Vec3]>(&[]),
            armed.skeleton,
            "no draw: the entry as stored"
        );
    }

    #[test]
    fn files_round_trip_and_bad_ones_are_refused_with_their_code() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("lib.json");
        let lib = library();
        lib.save(&p).unwrap();
        let back = Library::load(&p).unwrap();
        assert_eq!(back.entries.len(), 3);
        assert_eq!(back.entries[0].skeleton, lib.entries[0].skeleton);

        let code = |bytes: &[u8]| {
            std::fs::write(&p, bytes).unwrap();
            Library::load(&p).unwrap_err().code()
        };
        assert_eq!(
            code(b"{\"version\": 1, \"entries\": [tru"),
            "library_malformed"
        );
        assert_eq!(code(b"[1, 2]"), "library_malformed");
        let mut v = serde_json::to_value(&lib).unwrap();
        v["version"] = 99.into();
        assert_eq!(code(&serde_json::to_vec(&v).unwrap()), "library_version");
        let mut v = serde_json::to_value(&lib).unwrap();
        v["entries"][1]["skeleton"]["bones"][0]["parent"] = 5.into();
        assert_eq!(
            code(&serde_json::to_vec(&v).unwrap()),
            "library_entry_invalid"
        );
        let mut v = serde_json::to_value(&lib).unwrap();
        v["entries"][2]["points"] = serde_json::json!([]);
        assert_eq!(
            code(&serde_json::to_vec(&v).unwrap()),
            "library_entry_invalid"
        );
        assert_eq!(
            Library::load(&dir.path().join("missing.json"))
                .unwrap_err()
                .code(),
            "library_unreadable"
        );

        let names = ["cube".to_string()].into_iter().collect();
        let rest = lib.without(&names);
        assert_eq!(
            rest.entries
                .iter()
                .map(|e| e.name.as_str())
                .collect::<Vec<_>>(),
            ["armed", "slab"]
        );
    }

    #[test]
    fn the_compact_file_keeps_skeletons_exact_and_samples_within_a_fixed_point_step() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("lib.bin");
        let lib = library();
        lib.save(&p).unwrap();
        assert_eq!(&std::fs::read(&p).unwrap()[..4], codec::MAGIC);
        let back = Library::load(&p).unwrap();
        assert_eq!(back.entries.len(), lib.entries.len());
        for (a, b) in back.entries.iter().zip(&lib.entries) {
            assert_eq!((&a.name, &a.category), (&b.name, &b.category));
            assert_eq!(a.skeleton, b.skeleton);
            assert_eq!(a.proportions, b.proportions);
            assert_eq!(a.points.len(), b.points.len());
            let worst = a
                .points
                .iter()
                .zip(&b.points)
                .map(|(x, y)| (*x - *y).abs().max_element())
                .fold(0.0f32, f32::max);
            assert!(worst <= 0.5 / 32767.0 + 1e-7, "{worst}");
        }
        // Cut anywhere, or with bytes added, the file is refused, never half-read.
        let bytes = std::fs::read(&p).unwrap();
        for cut in [3, 6, 11, 40, bytes.len() - 1] {
            std::fs::write(&p, &bytes[..cut]).unwrap();
            assert_eq!(
                Library::load(&p).unwrap_err().code(),
                "library_malformed",
                "{cut}"
            );
        }
        let mut longer = bytes.clone();
        longer.push(0);
        std::fs::write(&p, &longer).unwrap();
        assert_eq!(Library::load(&p).unwrap_err().code(), "library_malformed");
        let mut huge = bytes.clone();
        huge[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        std::fs::write(&p, &huge).unwrap();
        assert_eq!(Library::load(&p).unwrap_err().code(), "library_malformed");
    }
}
