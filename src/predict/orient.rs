//! Which way is up: meshes come Z-up from DCC tools and generators, or lying on a side,
//! while the skeleton model and the library only know Y-up characters. The mesh is turned
//! into that frame before it is sampled, rigged there, and the skeleton turned back, so
//! the result lies in the input's own frame.
//!
//! Turns are the signed axis permutations that bring one axis to +Y: applying one and its
//! inverse is exact in floating point, so bones a caller asked to keep come back bit for
//! bit, and no rotation error is added to the figures.

use super::library::{BoxFrame, Library, SHAPE_POINTS};
use glam::Vec3;

/// A signed permutation of the axes: `out[i] = sign[i] * p[axis[i]]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Turn {
    axis: [usize; 3],
    sign: [i8; 3],
}

impl Default for Turn {
    fn default() -> Self {
        Turn::IDENTITY
    }
}

impl Turn {
    pub const IDENTITY: Turn = Turn {
        axis: [0, 1, 2],
        sign: [1, 1, 1],
    };

    pub fn is_identity(&self) -> bool {
        *self == Turn::IDENTITY
    }

    pub fn apply(&self, p: Vec3) -> Vec3 {
        let a = p.to_array();
        Vec3::new(
            self.sign[0] as f32 * a[self.axis[0]],
            self.sign[1] as f32 * a[self.axis[1]],
            self.sign[2] as f32 * a[self.axis[2]],
        )
    }

    pub fn inverse(&self) -> Turn {
        let mut inv = Turn::IDENTITY;
        for i in 0..3 {
            inv.axis[self.axis[i]] = i;
            inv.sign[self.axis[i]] = self.sign[i];
        }
        inv
    }

    pub fn invert(&self, p: Vec3) -> Vec3 {
        self.inverse().apply(p)
    }

    /// The turn that brings the input's `up` axis to +Y (a quarter turn about x or z, or a
    /// half turn about x for upside down).
    pub fn bringing_up(up: Axis) -> Turn {
        let t = |axis: [usize; 3], sign: [i8; 3]| Turn { axis, sign };
        match up {
            Axis::PosY => Turn::IDENTITY,
            // A quarter turn about x by -90°: (x, y, z) -> (x, z, -y).
            Axis::PosZ => t([0, 2, 1], [1, 1, -1]),
            // About x by +90°: (x, y, z) -> (x, -z, y).
            Axis::NegZ => t([0, 2, 1], [1, -1, 1]),
            // About z by +90°: (x, y, z) -> (-y, x, z).
            Axis::PosX => t([1, 0, 2], [-1, 1, 1]),
            // About z by -90°: (x, y, z) -> (y, -x, z).
            Axis::NegX => t([1, 0, 2], [1, -1, 1]),
            // A half turn about x: (x, y, z) -> (x, -y, -z).
            Axis::NegY => t([0, 1, 2], [1, -1, -1]),
        }
    }

    /// A turn named as an axis and a multiple of 90 degrees: `x90`, `x-90`, `z90`,
    /// `y180`, … (what `eval --rotate` applies to a data set).
    pub fn parse_rotation(s: &str) -> Option<Turn> {
        let (axis, deg) = s.split_at(s.len().min(1));
        let quarters = match deg.trim_start_matches('+') {
            "0" => 0,
            "90" => 1,
            "180" | "-180" => 2,
            "-90" | "270" => 3,
            _ => return None,
        };
        let quarter = match axis {
            // A +90° turn about each axis (right-handed).
            "x" => Turn {
                axis: [0, 2, 1],
                sign: [1, -1, 1],
            },
            "y" => Turn {
                axis: [2, 1, 0],
                sign: [1, 1, -1],
            },
            "z" => Turn {
                axis: [1, 0, 2],
                sign: [-1, 1, 1],
            },
            _ => return None,
        };
        Some((0..quarters).fold(Turn::IDENTITY, |t, _| quarter.then(t)))
    }

    /// `self` after `first`.
    fn then(&self, first: Turn) -> Turn {
        let mut out = Turn::IDENTITY;
        for i in 0..3 {
            out.axis[i] = first.axis[self.axis[i]];
            out.sign[i] = self.sign[i] * first.sign[self.axis[i]];
        }
        out
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    PosX,
    NegX,
    PosY,
    NegY,
    PosZ,
    NegZ,
}

const AXES: [Axis; 6] = [
    Axis::PosY,
    Axis::PosZ,
    Axis::NegZ,
    Axis::PosX,
    Axis::NegX,
    Axis::NegY,
];

/// `up` of a request (CLI `--up`, API `up`; the same words both ways): found from the
/// mesh, or given. The default is Y-up, glTF's convention: the search (`Auto`) still turns
/// some upright meshes the wrong way (dev, see `models/MODEL_CARD.md`), so it is asked
/// for, not assumed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum Up {
    Auto,
    Axis(Axis),
}

impl Default for Up {
    fn default() -> Self {
        Up::Axis(Axis::PosY)
    }
}

impl std::str::FromStr for Up {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let axis = match s.to_ascii_lowercase().trim_start_matches('+') {
            "auto" => return Ok(Up::Auto),
            "y" => Axis::PosY,
            "-y" => Axis::NegY,
            "x" => Axis::PosX,
            "-x" => Axis::NegX,
            "z" => Axis::PosZ,
            "-z" => Axis::NegZ,
            _ => return Err(format!("up must be auto, y, -y, x, -x, z or -z, not {s:?}")),
        };
        Ok(Up::Axis(axis))
    }
}

impl TryFrom<String> for Up {
    type Error = String;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        s.parse()
    }
}

impl From<Up> for String {
    fn from(up: Up) -> String {
        match up {
            Up::Auto => "auto",
            Up::Axis(Axis::PosY) => "y",
            Up::Axis(Axis::NegY) => "-y",
            Up::Axis(Axis::PosX) => "x",
            Up::Axis(Axis::NegX) => "-x",
            Up::Axis(Axis::PosZ) => "z",
            Up::Axis(Axis::NegZ) => "-z",
        }
        .to_string()
    }
}

/// How much nearer (box-coordinate shape distance) a turned mesh must come to a library
/// rig than the mesh as given before it is turned: ties and near ties stay as given.
pub const TURN_MARGIN: f32 = 0.02;

/// What the search found: the turn taken and each up axis's nearest library distance.
#[derive(Clone, Debug, PartialEq)]
pub struct Found {
    pub turn: Turn,
    pub distances: Vec<(Axis, f32)>,
}

/// The turn that makes the mesh most like a rigged one in `lib`. `rows` are surface
/// samples (`x y z nx ny nz`) and `bounds` the box, both in the unit frame of the mesh as
/// given; sampling commutes with an axis permutation, so they are turned, not redrawn.
pub fn find_up(
    lib: &Library,
    rows: &[[f32; 6]],
    bounds: (Vec3, Vec3),
    category: Option<&str>,
) -> Found {
    let mut distances = Vec::with_capacity(AXES.len());
    for &up in &AXES {
        let turn = Turn::bringing_up(up);
        let (a, b) = (turn.apply(bounds.0), turn.apply(bounds.1));
        let frame = BoxFrame::from_bounds(a.min(b), a.max(b));
        // The first shape's worth of samples, turned, in box coordinates: what `ranked`
        // compares with a library rig (`shape_of_samples` of the turned rows).
        let shape: Vec<Vec3> = rows
            .iter()
            .take(SHAPE_POINTS)
            .map(|r| frame.apply(turn.apply(Vec3::new(r[0], r[1], r[2]))))
            .collect();
        let nearest = lib
            .ranked(&shape, frame.proportions(), category)
            .first()
            .map_or(f32::INFINITY, |&(_, d)| d);
        distances.push((up, nearest));
    }
    let as_given = distances[0].1;
    let best = distances
        .iter()
        .skip(1)
        .filter(|(_, d)| *d < as_given - TURN_MARGIN)
        .min_by(|a, b| a.1.total_cmp(&b.1));
    Found {
        turn: best.map_or(Turn::IDENTITY, |&(up, _)| Turn::bringing_up(up)),
        distances,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_up_axis_is_brought_to_plus_y_and_back_exactly() {
        let dir = |a: Axis| match a {
            Axis::PosX => Vec3::X,
            Axis::NegX => -Vec3::X,
            Axis::PosY => Vec3::Y,
            Axis::NegY => -Vec3::Y,
            Axis::PosZ => Vec3::Z,
            Axis::NegZ => -Vec3::Z,
        };
        let p = Vec3::new(0.1234567, -7.654321, 3.000001);
        for a in AXES {
            let t = Turn::bringing_up(a);
            assert_eq!(t.apply(dir(a)), Vec3::Y, "{a:?}");
            assert_eq!(t.invert(t.apply(p)), p);
        }
    }

    #[test]
    fn a_rotated_data_set_is_undone_by_the_turn_for_its_up_axis() {
        // eval --rotate x90 makes a Y-up character Z-up; z90 makes it -X-up.
        let cases = [
            ("x90", Axis::PosZ),
            ("x-90", Axis::NegZ),
            ("z90", Axis::NegX),
            ("z-90", Axis::PosX),
        ];
        let p = Vec3::new(1.0, 2.0, 3.0);
        for (rot, up) in cases {
            let r = Turn::parse_rotation(rot).unwrap();
            assert_eq!(Turn::bringing_up(up).apply(r.apply(p)), p, "{rot}");
        }
        assert_eq!(
            Turn::parse_rotation("x180").unwrap().apply(p),
            Vec3::new(1.0, -2.0, -3.0)
        );
        assert_eq!(
            Turn::parse_rotation("y90").unwrap().apply(Vec3::X),
            -Vec3::Z
        );
        assert!(Turn::parse_rotation("q90").is_none());
        assert!(Turn::parse_rotation("x45").is_none());
    }

    #[test]
    fn up_parses_every_axis_and_refuses_others() {
        assert_eq!("auto".parse::<Up>(), Ok(Up::Auto));
        assert_eq!(Up::default(), Up::Axis(Axis::PosY));
        assert_eq!("Z".parse::<Up>(), Ok(Up::Axis(Axis::PosZ)));
        assert_eq!("+y".parse::<Up>(), Ok(Up::Axis(Axis::PosY)));
        assert_eq!("-x".parse::<Up>(), Ok(Up::Axis(Axis::NegX)));
        assert!("w".parse::<Up>().is_err());
        for s in ["auto", "y", "-y", "x", "-x", "z", "-z"] {
            assert_eq!(String::from(s.parse::<Up>().unwrap()), s);
        }
    }
}
