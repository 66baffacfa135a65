//! Skeleton tree tokenization (UniRig §5.1): a skeleton as a token sequence a decoder can
//! learn and generate, and back.
//!
//! # Vocabulary (stable: ids are baked into trained models)
//!
//! | ids       | tokens                                                                   |
//! |-----------|--------------------------------------------------------------------------|
//! | 0..=255   | coordinate bins                                                          |
//! | 256..=262 | `<bos>` `<eos>` `<pad>` `<branch>` `<spring>` `<mixamo:body>` `<mixamo:hand>` |
//! | 263..=271 | class tokens `<cls:…>`, one per entry of [`CATEGORIES`], in that order   |
//! | 272       | `<alt>`                                                                  |
//!
//! `<alt>` came after the class tokens, so it is appended rather than grouped with the other
//! specials: every earlier id keeps its meaning.
//!
//! # Coordinates
//!
//! Coordinates are normalized to [-1, 1] (glTF Y-up). A coordinate `x` becomes bin
//! `clip(floor((x + 1) / 2 · 256), 0, 255)` and bin `t` decodes to its centre
//! `(t + 0.5) / 256 · 2 − 1`. UniRig's code rounds instead of flooring; paired with a
//! centre-of-bin decode that biases every coordinate by half a bin, up to a full bin (1/128)
//! of error. Flooring makes each bin the set of points it decodes nearest to, so a decoded
//! joint is within half a bin (1/256) of the original on every axis.
//!
//! # Sequence
//!
//! ```text
//! <bos> <cls:…> [<mixamo:body> 22×xyz [<mixamo:hand> 15×xyz]{0,2}] joints… <eos> <pad>*
//! ```
//!
//! Template blocks list joints in template order (see [`super::template`]); their parents
//! come from the template. The first hand block belongs to the body hand nearer to the mean
//! of its joints, the second to the other hand.
//!
//! The remaining bones are walked depth-first. A joint is written in one of these forms:
//! - `x y z` — continues the chain: its parent is the joint written just before it;
//! - `<branch> px py pz <alt>{r} x y z` — starts a branch: its parent is the `r`-th (from 0)
//!   of the earlier joints in the cell `(px, py, pz)`, in the order they were written (see
//!   below);
//! - `<branch> <branch> x y z` — a new root (UniRig has no form for extra roots; the doubled
//!   token keeps them apart from branches, whatever their position);
//! - `<spring>` in place of the first `<branch>` of the two forms above starts a spring chain:
//!   that joint and every joint continuing its chain are spring bones. Joints of chains
//!   opened by `<branch>`, bare roots and template joints are not.
//!
//! Only the very first joint of a sequence without a template may be written bare without a
//! parent (the first root). A bone continues the chain when it is the first child visited
//! after its parent *and* has its parent's spring flag; any other bone opens a branch.
//! Children (and roots) are visited by quantized head position: highest Y first, then highest
//! Z, then highest X, then lowest index. This is UniRig's order — its DFS pops the child with
//! the largest vertical coordinate first, and the "tail" it sorts by is, in its bone-as-segment
//! convention, the joint a bone writes, i.e. our head. Keying on quantized heads (never on
//! tails, which decoding re-infers) makes `tokenize(detokenize(t)) == t`.
//!
//! # Coincident joints: `<alt>`
//!
//! A branch names its parent by position, and artist rigs often put several joints in one
//! quantization cell (a root under the hips, IK targets on the root, collapsed fingers).
//! UniRig attaches such a branch to whichever joint its decoder finds first, which silently
//! rewires the tree. Here the encoder follows the parent coordinates with one `<alt>` per
//! earlier-written joint of that cell that comes before the intended parent, so the common
//! case (no other joint in the cell, or the parent written first) costs nothing and the
//! decoded topology is always the original's. The grammar offers `<alt>` only while another
//! joint of the cell is left to pick. [`tokenize_with_order`] also returns where each bone
//! went, for checks that must not guess the correspondence from positions.
//!
//! Nothing else resolves by position in a way that can go wrong: extra roots are written
//! without one, and a hand block whose side the decoder's rule would get wrong is written as
//! ordinary branches instead (see [`tokenize`]). A sequence from an unconstrained decoder may
//! name a cell holding no joint; it then snaps to the nearest joint, and `<alt>` counts among
//! the joints of that joint's cell.

use std::collections::HashMap;

use glam::Vec3;

use super::grammar::{Grammar, GrammarError, TemplateSlot};
use super::skeleton::{Bone, Skeleton, Template};
use super::template::{self, Side, BODY_BONES, HAND_BONES, LEFT_HAND, RIGHT_HAND};

/// Number of coordinate bins; bins are token ids `0..COORD_BINS`.
pub const COORD_BINS: u32 = 256;
pub const BOS: u32 = 256;
pub const EOS: u32 = 257;
pub const PAD: u32 = 258;
pub const BRANCH: u32 = 259;
pub const SPRING: u32 = 260;
pub const MIXAMO_BODY: u32 = 261;
pub const MIXAMO_HAND: u32 = 262;
/// Id of the first class token; class `k` is `CLS_BASE + k` for `CATEGORIES[k]`.
pub const CLS_BASE: u32 = 263;
/// Categories with a class token, in token order. `none` stands for "no or unknown category".
pub const CATEGORIES: [&str; 9] = [
    "none",
    "humanoid",
    "humanoid_creature",
    "quadruped",
    "bird_flyer",
    "insect_spider",
    "fish_snake_tail",
    "other_creature",
    "robot_prop",
];
pub const CLS_NONE: u32 = CLS_BASE;
/// One past the last class token.
const CLS_END: u32 = CLS_BASE + CATEGORIES.len() as u32;
/// Picks the next earlier joint of a branch parent's cell (see the module docs).
pub const ALT: u32 = 272;
const _: () = assert!(
    ALT == CLS_END,
    "<alt> must directly follow the class tokens"
);
pub const VOCAB_SIZE: usize = ALT as usize + 1;

const SPECIAL_NAMES: [&str; 7] = [
    "<bos>",
    "<eos>",
    "<pad>",
    "<branch>",
    "<spring>",
    "<mixamo:body>",
    "<mixamo:hand>",
];

pub fn is_coord(tok: u32) -> bool {
    tok < COORD_BINS
}

pub fn is_class_token(tok: u32) -> bool {
    (CLS_BASE..CLS_END).contains(&tok)
}

/// Human-readable name of a token: the bin number for coordinates, `<…>` for the rest,
/// `<unk:N>` outside the vocabulary.
pub fn token_name(id: u32) -> String {
    if is_coord(id) {
        id.to_string()
    } else if id < CLS_BASE {
        SPECIAL_NAMES[(id - BOS) as usize].to_string()
    } else if is_class_token(id) {
        format!("<cls:{}>", CATEGORIES[(id - CLS_BASE) as usize])
    } else if id == ALT {
        "<alt>".to_string()
    } else {
        format!("<unk:{id}>")
    }
}

/// The class token for a category (case-insensitive); missing or unknown ones map to
/// `<cls:none>`.
pub fn class_token(category: Option<&str>) -> u32 {
    category
        .and_then(|c| {
            CATEGORIES
                .iter()
                .position(|k| k.eq_ignore_ascii_case(c.trim()))
        })
        .map_or(CLS_NONE, |k| CLS_BASE + k as u32)
}

/// The category a class token stands for; `None` for `<cls:none>` and for tokens that are
/// not class tokens.
pub fn category_of_class_token(tok: u32) -> Option<&'static str> {
    if is_class_token(tok) && tok != CLS_NONE {
        Some(CATEGORIES[(tok - CLS_BASE) as usize])
    } else {
        None
    }
}

/// Bin of a coordinate in [-1, 1]; values outside are clipped, NaN goes to bin 0.
pub fn quantize(x: f32) -> u32 {
    let v = ((x + 1.0) * 0.5 * COORD_BINS as f32).floor();
    if v.is_nan() {
        0
    } else {
        v.clamp(0.0, (COORD_BINS - 1) as f32) as u32
    }
}

/// Centre of a bin; ids past the last bin are clamped to it.
pub fn dequantize(t: u32) -> f32 {
    (t.min(COORD_BINS - 1) as f32 + 0.5) / COORD_BINS as f32 * 2.0 - 1.0
}

pub fn quantize3(p: Vec3) -> [u8; 3] {
    [
        quantize(p.x) as u8,
        quantize(p.y) as u8,
        quantize(p.z) as u8,
    ]
}

pub fn dequantize3(q: [u8; 3]) -> Vec3 {
    Vec3::new(
        dequantize(q[0] as u32),
        dequantize(q[1] as u32),
        dequantize(q[2] as u32),
    )
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TokenizeError {
    #[error("the skeleton has no bones")]
    Empty,
    #[error("bone {0} has a parent index {1} that does not come before it")]
    BadParent(usize, usize),
    #[error("bone {0} has a non-finite head")]
    NonFinite(usize),
    #[error("the skeleton claims the Mixamo body template but its first 22 bones do not have the template's parents")]
    TemplateMismatch,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DetokenizeError {
    #[error("token {pos}: {error}")]
    Invalid { pos: usize, error: GrammarError },
    #[error("the token sequence ends before <eos>")]
    Unterminated,
}

/// Which body hand a hand block belongs to: the one nearer to the block's mean joint
/// (left on a tie). Integer arithmetic keeps encoder and decoder bit-for-bit in agreement.
pub fn hand_side(left_hand: [u8; 3], right_hand: [u8; 3], block: &[[u8; 3]]) -> Side {
    let n = block.len() as i64;
    let mut sum = [0i64; 3];
    for q in block {
        for a in 0..3 {
            sum[a] += q[a] as i64;
        }
    }
    let dist = |h: [u8; 3]| -> i64 { (0..3).map(|a| (sum[a] - n * h[a] as i64).pow(2)).sum() };
    if dist(right_hand) < dist(left_hand) {
        Side::Right
    } else {
        Side::Left
    }
}

/// Tokenizes a skeleton whose heads are normalized to [-1, 1] (coordinates outside are
/// clipped). Tails are ignored: decoding re-infers them.
///
/// `template == Some(MixamoBody)` promises that the first 22 bones are the body template
/// (their parents are checked); hand blocks are then recognised structurally at bones 22
/// and 37 (see [`template::hand_block_at`]). Hand blocks are written in an order for which
/// the decoder's side rule ([`hand_side`]) gives each back to its own side (left first when
/// both orders work); a lone hand posed nearer the other hand, or two hands each nearer the
/// other, are written as ordinary branches instead. `Some(MixamoHand)` alone
/// has no body to hang from and is treated as no template.
pub fn tokenize(skel: &Skeleton) -> Result<Vec<u32>, TokenizeError> {
    tokenize_with_order(skel).map(|(tokens, _)| tokens)
}

/// [`tokenize`], plus the order the bones are written in: `order[k]` is the index in `skel`
/// of bone `k` of [`detokenize`]'s result. Decoded bone `k` then has as parent the position
/// in `order` of `skel`'s parent of `order[k]`, the same spring flag, and a head within half
/// a bin of the (clipped) original; [`same_topology_in_order`] checks exactly that.
pub fn tokenize_with_order(skel: &Skeleton) -> Result<(Vec<u32>, Vec<usize>), TokenizeError> {
    let n = skel.bones.len();
    if n == 0 {
        return Err(TokenizeError::Empty);
    }
    for (i, b) in skel.bones.iter().enumerate() {
        if let Some(p) = b.parent {
            if p >= i {
                return Err(TokenizeError::BadParent(i, p));
            }
        }
        if !b.head.is_finite() {
            return Err(TokenizeError::NonFinite(i));
        }
    }
    let q: Vec<[u8; 3]> = skel.bones.iter().map(|b| quantize3(b.head)).collect();
    let mut w = Writer {
        q: &q,
        out: vec![BOS, class_token(skel.category.as_deref())],
        order: Vec::with_capacity(n),
        cells: HashMap::new(),
    };

    let mut in_template = vec![false; n];
    if skel.template == Some(Template::MixamoBody) {
        if !template::body_matches(skel) {
            return Err(TokenizeError::TemplateMismatch);
        }
        w.out.push(MIXAMO_BODY);
        (0..BODY_BONES).for_each(|i| w.joint(i));
        in_template[..BODY_BONES].fill(true);
        for start in hand_blocks(skel, &q) {
            w.out.push(MIXAMO_HAND);
            (start..start + HAND_BONES).for_each(|i| w.joint(i));
            in_template[start..start + HAND_BONES].fill(true);
        }
    }

    let mut roots = Vec::new();
    let mut children = vec![Vec::new(); n];
    for (i, b) in skel.bones.iter().enumerate() {
        if in_template[i] {
            continue;
        }
        match b.parent {
            Some(p) if !in_template[p] => children[p].push(i),
            _ => roots.push(i),
        }
    }
    let visit_key = |&i: &usize| {
        let [x, y, z] = q[i];
        (std::cmp::Reverse((y, z, x)), i)
    };
    roots.sort_by_key(visit_key);
    for c in &mut children {
        c.sort_by_key(visit_key);
    }

    let mut any_joint = skel.template == Some(Template::MixamoBody);
    // The last non-template joint written: only it can be continued.
    let mut prev: Option<usize> = None;
    let mut stack: Vec<usize> = roots.into_iter().rev().collect();
    while let Some(b) = stack.pop() {
        let bone = &skel.bones[b];
        let opener = if bone.spring { SPRING } else { BRANCH };
        match bone.parent {
            Some(p) if prev == Some(p) && skel.bones[p].spring == bone.spring => {}
            Some(p) => {
                w.out.push(opener);
                w.parent(p);
            }
            None if !any_joint && !bone.spring => {}
            None => w.out.extend([opener, BRANCH]),
        }
        w.joint(b);
        any_joint = true;
        prev = Some(b);
        stack.extend(children[b].iter().rev());
    }
    w.out.push(EOS);
    Ok((w.out, w.order))
}

/// Token output that tracks what the decoder will have seen, so branches can name their
/// parent the way the decoder resolves it.
struct Writer<'a> {
    q: &'a [[u8; 3]],
    out: Vec<u32>,
    order: Vec<usize>,
    /// Joints written so far per cell, in writing order, which is the decoder's candidate
    /// order for a branch parent in that cell.
    cells: HashMap<[u8; 3], Vec<usize>>,
}

impl Writer<'_> {
    fn coords(&mut self, i: usize) {
        self.out.extend(self.q[i].iter().map(|&c| c as u32));
    }

    fn joint(&mut self, i: usize) {
        self.coords(i);
        self.order.push(i);
        self.cells.entry(self.q[i]).or_default().push(i);
    }

    fn parent(&mut self, p: usize) {
        self.coords(p);
        let rank = self.cells[&self.q[p]]
            .iter()
            .position(|&j| j == p)
            .expect("the walk writes parents before their children");
        self.out.extend(std::iter::repeat_n(ALT, rank));
    }
}

/// Start indices of the hand blocks to write, in writing order, such that the decoder's
/// side rule hands each block back to its own side.
fn hand_blocks(skel: &Skeleton, q: &[[u8; 3]]) -> Vec<usize> {
    let mut found: Vec<(usize, Side)> = Vec::new();
    if let Some(s) = template::hand_block_at(skel, BODY_BONES) {
        found.push((BODY_BONES, s));
        let second = BODY_BONES + HAND_BONES;
        if let Some(s2) = template::hand_block_at(skel, second).filter(|&s2| s2 != s) {
            found.push((second, s2));
        }
    }
    let first_side =
        |start: usize| hand_side(q[LEFT_HAND], q[RIGHT_HAND], &q[start..start + HAND_BONES]);
    match found.as_slice() {
        [(a, sa)] if first_side(*a) == *sa => vec![*a],
        [(a, sa), (b, sb)] => {
            // The second block always goes to the side the first did not take.
            if first_side(*a) == *sa {
                vec![*a, *b]
            } else if first_side(*b) == *sb {
                vec![*b, *a]
            } else {
                Vec::new()
            }
        }
        _ => Vec::new(),
    }
}

/// Rebuilds a skeleton from tokens: `<bos>`, a class token, the joints, `<eos>`, then
/// optionally `<pad>`s. Accepts exactly what [`Grammar::lenient`] accepts, so any sequence
/// generated under a [`Grammar`] decodes; anything else is an error, never a panic.
///
/// Template joints get template names, the others `bone_{index}`; tails come from
/// [`Skeleton::infer_tails`]; `<cls:none>` gives no category.
pub fn detokenize(tokens: &[u32]) -> Result<Skeleton, DetokenizeError> {
    let mut g = Grammar::lenient(usize::MAX);
    for (pos, &t) in tokens.iter().enumerate() {
        g.advance(t)
            .map_err(|error| DetokenizeError::Invalid { pos, error })?;
    }
    if !g.is_done() {
        return Err(DetokenizeError::Unterminated);
    }
    let bones = g
        .joints()
        .iter()
        .enumerate()
        .map(|(i, j)| {
            let head = dequantize3(j.q);
            Bone {
                name: match j.slot {
                    Some(TemplateSlot::Body(k)) => template::body_name(k),
                    Some(TemplateSlot::Hand(side, k)) => template::hand_bone_name(side, k),
                    None => format!("bone_{i}"),
                },
                parent: j.parent,
                head,
                tail: head,
                spring: j.spring,
            }
        })
        .collect();
    let mut skel = Skeleton {
        bones,
        template: g.has_body_template().then_some(Template::MixamoBody),
        category: g
            .class_token()
            .and_then(category_of_class_token)
            .map(str::to_string),
    };
    skel.infer_tails();
    Ok(skel)
}

/// Checks that `b` is `a` re-indexed as [`tokenize_with_order`] reports: bone `k` of `b` is
/// bone `order[k]` of `a`, with the corresponding parent (or both roots), the same spring
/// flag, and a head within `tol` on every axis. For a tokenizer round trip, `tol` is half a
/// bin, `1/256`, plus float slack, and the heads of `a` must lie in [-1, 1].
pub fn same_topology_in_order(
    a: &Skeleton,
    b: &Skeleton,
    order: &[usize],
    tol: f32,
) -> Result<(), String> {
    let n = a.len();
    if b.len() != n || order.len() != n {
        return Err(format!(
            "{} decoded bones and {} order entries, expected {n}",
            b.len(),
            order.len()
        ));
    }
    let mut at = vec![usize::MAX; n];
    for (k, &i) in order.iter().enumerate() {
        if i >= n || at[i] != usize::MAX {
            return Err(format!("order is not a permutation: entry {k} is {i}"));
        }
        at[i] = k;
    }
    for (k, (&i, d)) in order.iter().zip(&b.bones).enumerate() {
        let o = &a.bones[i];
        let want = o.parent.map(|p| at.get(p).copied().unwrap_or(usize::MAX));
        if d.parent != want {
            return Err(format!(
                "decoded bone {k} is original {i} ({}), whose parent {:?} was written as {want:?}, but its parent is {:?}",
                o.name, o.parent, d.parent
            ));
        }
        if d.spring != o.spring {
            return Err(format!(
                "decoded bone {k} has spring={}, original {i} ({}) has {}",
                d.spring, o.name, o.spring
            ));
        }
        let err = head_gap(d.head, o.head);
        if err > tol {
            return Err(format!(
                "decoded bone {k} at {:?} is {err} from original {i} ({}) at {:?}, more than {tol}",
                d.head, o.name, o.head
            ));
        }
    }
    Ok(())
}

/// Checks that `b` has the topology of `a` when no correspondence is known (say, a prediction
/// against ground truth): some one-to-one mapping of `b`'s bones onto `a`'s pairs heads within
/// `tol` on every axis, keeps parents (and roots), and keeps spring flags. Coincident joints
/// cannot fool it: it decides whether such a mapping exists, rather than committing to the
/// nearest head. For a tokenizer round trip, prefer [`same_topology_in_order`].
pub fn same_topology(a: &Skeleton, b: &Skeleton, tol: f32) -> Result<(), String> {
    if a.len() != b.len() {
        return Err(format!("{} bones, expected {}", b.len(), a.len()));
    }
    let n = a.len();
    for (name, s) in [("original", a), ("decoded", b)] {
        if let Some((i, p)) = s
            .bones
            .iter()
            .enumerate()
            .find_map(|(i, x)| x.parent.filter(|&p| p >= i).map(|p| (i, p)))
        {
            return Err(format!(
                "{name} bone {i} has parent {p}, not an earlier bone"
            ));
        }
    }
    let dist = |i: usize, j: usize| head_gap(a.bones[i].head, b.bones[j].head);
    let mut cands: Vec<Vec<usize>> = Vec::with_capacity(n);
    for j in 0..n {
        let mut c: Vec<usize> = (0..n).filter(|&i| dist(i, j) <= tol).collect();
        c.sort_by(|&x, &y| dist(x, j).total_cmp(&dist(y, j)).then(x.cmp(&y)));
        if c.is_empty() {
            return Err(format!(
                "decoded bone {j} ({}) at {:?} has no original bone within {tol}",
                b.bones[j].name, b.bones[j].head
            ));
        }
        cands.push(c);
    }
    let (ca, cb) = (a.children(), b.children());
    // fits[j]: the originals whose whole subtree can map onto decoded j's subtree. Children
    // come after their parents, so a backward sweep has every child's answer ready; each
    // step is a bipartite matching of children, which settles coincident siblings exactly.
    let mut fits: Vec<Vec<usize>> = vec![Vec::new(); n];
    let mut scratch = vec![usize::MAX; n];
    let mut first_misfit: Option<(usize, String)> = None;
    for j in (0..n).rev() {
        let mut why = String::new();
        for &i in &cands[j] {
            if a.bones[i].spring != b.bones[j].spring {
                why = why_not(&why, || {
                    format!("original {i} has spring={}", a.bones[i].spring)
                });
            } else if ca[i].len() != cb[j].len() {
                why = why_not(&why, || {
                    format!(
                        "original {i} ({}) has {} children, not {}",
                        a.bones[i].name,
                        ca[i].len(),
                        cb[j].len()
                    )
                });
            } else if !perfect_matching(&ca[i], &cb[j], &fits, &mut scratch) {
                why = why_not(&why, || {
                    format!(
                        "the children of original {i} ({}) do not match its children",
                        a.bones[i].name
                    )
                });
            } else {
                fits[j].push(i);
            }
        }
        if fits[j].is_empty() && first_misfit.is_none() {
            first_misfit = Some((j, why));
        }
    }
    let roots_a: Vec<usize> = a.roots().collect();
    let roots_b: Vec<usize> = b.roots().collect();
    if roots_a.len() == roots_b.len() && perfect_matching(&roots_a, &roots_b, &fits, &mut scratch) {
        return Ok(());
    }
    Err(match first_misfit {
        Some((j, why)) => format!(
            "decoded bone {j} ({}) at {:?}: no original bone nearby has its subtree ({why})",
            b.bones[j].name, b.bones[j].head
        ),
        None => format!("roots differ: original {roots_a:?}, decoded {roots_b:?} cannot be paired"),
    })
}

/// Largest per-axis distance; infinite when either point has a NaN, which `max_element`
/// would skip.
fn head_gap(a: Vec3, b: Vec3) -> f32 {
    let d = (a - b).abs();
    if d.is_nan() {
        f32::INFINITY
    } else {
        d.max_element()
    }
}

/// Keeps the first reason: it belongs to the nearest candidate.
fn why_not(so_far: &str, reason: impl FnOnce() -> String) -> String {
    if so_far.is_empty() {
        reason()
    } else {
        so_far.to_string()
    }
}

/// Whether `left` (bones of the original) and `right` (decoded bones) can be paired so that
/// every decoded bone gets an original listed in its `fits`. `slot` must be all
/// `usize::MAX` and is left so.
fn perfect_matching(
    left: &[usize],
    right: &[usize],
    fits: &[Vec<usize>],
    slot: &mut [usize],
) -> bool {
    if left.len() != right.len() {
        return false;
    }
    for (l, &i) in left.iter().enumerate() {
        slot[i] = l;
    }
    let adj: Vec<Vec<usize>> = right
        .iter()
        .map(|&j| {
            fits[j]
                .iter()
                .filter_map(|&i| (slot[i] != usize::MAX).then_some(slot[i]))
                .collect()
        })
        .collect();
    for &i in left {
        slot[i] = usize::MAX;
    }
    // Kuhn's augmenting paths; `owner[l]` is the right index holding left slot `l`.
    fn augment(r: usize, adj: &[Vec<usize>], owner: &mut [usize], seen: &mut [bool]) -> bool {
        for &l in &adj[r] {
            if seen[l] {
                continue;
            }
            seen[l] = true;
            if owner[l] == usize::MAX || augment(owner[l], adj, owner, seen) {
                owner[l] = r;
                return true;
            }
        }
        false
    }
    let mut owner = vec![usize::MAX; left.len()];
    let mut seen = vec![false; left.len()];
    for r in 0..right.len() {
        seen.fill(false);
        if !augment(r, &adj, &mut owner, &mut seen) {
            return false;
        }
    }
    true
}

#[cfg(test)]
pub(crate) mod test_support {
    use super::*;

    /// xorshift64*: tiny, deterministic, good enough to drive property tests.
    pub struct Rng(u64);

    impl Rng {
        pub fn new(seed: u64) -> Self {
            Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
        }
        pub fn next_u64(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        /// Uniform in `0..n` (n > 0).
        pub fn below(&mut self, n: usize) -> usize {
            (self.next_u64() % n as u64) as usize
        }
        pub fn unit(&mut self) -> f32 {
            (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
        }
        pub fn coord(&mut self) -> f32 {
            self.unit() * 2.0 - 1.0
        }
        pub fn chance(&mut self, p: f32) -> bool {
            self.unit() < p
        }
    }

    /// A random forest of up to `max_bones` bones with heads in [-1, 1], random spring flags,
    /// and a random (possibly unknown) category. Some skeletons have every head in its own
    /// quantization cell; the others put heads in the cell of an earlier joint (its parent,
    /// a sibling-to-be, anyone), sometimes most of them, as artist rigs do.
    pub fn random_skeleton(rng: &mut Rng, max_bones: usize) -> Skeleton {
        let n = 1 + rng.below(max_bones);
        let share = [0.0, 0.15, 0.7][rng.below(3)];
        let mut used = std::collections::HashSet::new();
        let mut bones: Vec<Bone> = Vec::with_capacity(n);
        for i in 0..n {
            let parent = if i == 0 || rng.chance(0.05) {
                None
            } else if rng.chance(0.6) {
                Some(i - 1)
            } else {
                Some(rng.below(i))
            };
            let head = if i > 0 && rng.chance(share) {
                let other = match parent {
                    Some(p) if rng.chance(0.5) => p,
                    _ => rng.below(i),
                };
                let base = bones[other].head;
                // Anywhere in the same cell, not only the same point.
                let moved = base + Vec3::new(rng.coord(), rng.coord(), rng.coord()) / 600.0;
                if quantize3(moved) == quantize3(base) && moved.abs().max_element() <= 1.0 {
                    moved
                } else {
                    base
                }
            } else {
                loop {
                    let p = Vec3::new(rng.coord(), rng.coord(), rng.coord());
                    if used.insert(quantize3(p)) {
                        break p;
                    }
                }
            };
            used.insert(quantize3(head));
            bones.push(Bone {
                name: format!("b{i}"),
                parent,
                head,
                tail: head + Vec3::new(rng.coord(), rng.coord(), rng.coord()) * 0.1,
                spring: rng.chance(0.25),
            });
        }
        let category = match rng.below(4) {
            0 => None,
            1 => Some("martian".to_string()),
            _ => Some(CATEGORIES[rng.below(CATEGORIES.len())].to_string()),
        };
        Skeleton {
            bones,
            template: None,
            category,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::test_support::*;
    use super::*;
    use crate::rig::template::{match_mixamo, synthetic_mixamo};

    const HALF_BIN: f32 = 1.0 / 256.0 + 1e-5;

    fn bone(parent: Option<usize>, p: [f32; 3], spring: bool) -> Bone {
        Bone {
            name: String::new(),
            parent,
            head: Vec3::from(p),
            tail: Vec3::from(p),
            spring,
        }
    }

    fn skel(bones: Vec<Bone>) -> Skeleton {
        let mut s = Skeleton {
            bones,
            template: None,
            category: None,
        };
        for (i, b) in s.bones.iter_mut().enumerate() {
            b.name = format!("n{i}");
        }
        s
    }

    /// tokenize → detokenize keeps topology exactly (bone for bone, through the returned
    /// order) and joints within half a bin, decodes a valid skeleton that the order-free
    /// check accepts too, and re-tokenizing the decoded skeleton gives the same tokens in
    /// the same order.
    fn round_trip(s: &Skeleton) -> (Vec<u32>, Skeleton) {
        let (t, order) = tokenize_with_order(s).unwrap();
        assert_eq!(tokenize(s).unwrap(), t);
        let d = detokenize(&t).unwrap_or_else(|e| panic!("{e}: {:?}", names(&t)));
        d.validate(usize::MAX).unwrap();
        same_topology_in_order(s, &d, &order, HALF_BIN)
            .unwrap_or_else(|e| panic!("{e}\n{:?}", names(&t)));
        same_topology(s, &d, HALF_BIN).unwrap_or_else(|e| panic!("{e}\n{:?}", names(&t)));
        assert_eq!(
            d.category.as_deref(),
            category_of_class_token(class_token(s.category.as_deref()))
        );
        let (again, identity) = tokenize_with_order(&d).unwrap();
        assert_eq!(again, t, "re-tokenizing is not idempotent");
        assert!(identity.iter().enumerate().all(|(k, &i)| k == i));
        (t, d)
    }

    fn names(t: &[u32]) -> Vec<String> {
        t.iter().map(|&x| token_name(x)).collect()
    }

    #[test]
    fn vocabulary_layout_is_stable() {
        assert_eq!(VOCAB_SIZE, 273);
        assert_eq!(token_name(0), "0");
        assert_eq!(token_name(255), "255");
        assert_eq!(token_name(BOS), "<bos>");
        assert_eq!(token_name(EOS), "<eos>");
        assert_eq!(token_name(PAD), "<pad>");
        assert_eq!(token_name(BRANCH), "<branch>");
        assert_eq!(token_name(SPRING), "<spring>");
        assert_eq!(token_name(MIXAMO_BODY), "<mixamo:body>");
        assert_eq!(token_name(MIXAMO_HAND), "<mixamo:hand>");
        assert_eq!(token_name(263), "<cls:none>");
        assert_eq!(token_name(271), "<cls:robot_prop>");
        assert_eq!(token_name(272), "<alt>");
        assert_eq!(ALT, 272);
        assert!(!is_class_token(ALT) && !is_coord(ALT));
        assert_eq!(token_name(273), "<unk:273>");
        let all: std::collections::HashSet<String> =
            (0..VOCAB_SIZE as u32).map(token_name).collect();
        assert_eq!(all.len(), VOCAB_SIZE);
    }

    #[test]
    fn class_tokens_map_both_ways() {
        assert_eq!(class_token(None), CLS_NONE);
        assert_eq!(class_token(Some("martian")), CLS_NONE);
        assert_eq!(class_token(Some("Quadruped")), CLS_BASE + 3);
        for (k, c) in CATEGORIES.iter().enumerate().skip(1) {
            let t = class_token(Some(c));
            assert_eq!(t, CLS_BASE + k as u32);
            assert_eq!(category_of_class_token(t), Some(*c));
        }
        assert_eq!(category_of_class_token(CLS_NONE), None);
        assert_eq!(category_of_class_token(BOS), None);
        assert_eq!(category_of_class_token(5), None);
    }

    #[test]
    fn quantization_is_within_half_a_bin() {
        for t in 0..COORD_BINS {
            assert_eq!(quantize(dequantize(t)), t);
        }
        let mut rng = Rng::new(1);
        for k in 0..=100_000 {
            let x = if k < 50_000 {
                -1.0 + 2.0 * k as f32 / 50_000.0
            } else {
                rng.coord()
            };
            let err = (dequantize(quantize(x)) - x).abs();
            assert!(err <= 1.0 / 256.0 + 1e-6, "{x}: {err}");
        }
        assert_eq!(quantize(-1.0), 0);
        assert_eq!(quantize(1.0), 255);
        assert_eq!(quantize(-7.0), 0);
        assert_eq!(quantize(7.0), 255);
        assert_eq!(quantize(f32::NAN), 0);
        assert_eq!(dequantize(1000), dequantize(255));
    }

    #[test]
    fn chain_with_branch_has_the_documented_tokens() {
        // Root, a chain going up, and a lower side branch off the root.
        let s = skel(vec![
            bone(None, [0.0, 0.0, 0.0], false),
            bone(Some(0), [0.0, 0.5, 0.0], false),
            bone(Some(1), [0.0, 0.9, 0.0], false),
            bone(Some(0), [0.3, -0.5, 0.0], false),
        ]);
        let (t, d) = round_trip(&s);
        let c = |x: f32| quantize(x);
        let z = c(0.0);
        assert_eq!(
            t,
            vec![
                BOS,
                CLS_NONE,
                z,
                z,
                z,
                z,
                c(0.5),
                z,
                z,
                c(0.9),
                z,
                BRANCH,
                z,
                z,
                z,
                c(0.3),
                c(-0.5),
                z,
                EOS
            ]
        );
        assert_eq!(d.bones[3].name, "bone_3");
        assert_eq!(
            d.bones[0].tail,
            d.bones[0].head + Vec3::Y * 0.05 * d.scale()
        );
        assert_eq!(d.bones[1].tail, d.bones[2].head);
    }

    #[test]
    fn random_skeletons_round_trip() {
        let mut rng = Rng::new(7);
        for _ in 0..400 {
            let s = random_skeleton(&mut rng, 120);
            round_trip(&s);
        }
    }

    #[test]
    fn springs_round_trip() {
        // Non-spring body, a spring chain off it that forks, a non-spring bone under a
        // spring one, and a spring root.
        let s = skel(vec![
            bone(None, [0.0, 0.0, 0.0], false),
            bone(Some(0), [0.0, 0.4, 0.0], false),
            bone(Some(1), [0.1, 0.3, 0.0], true),
            bone(Some(2), [0.2, 0.2, 0.0], true),
            bone(Some(2), [0.2, 0.1, 0.1], true),
            bone(Some(3), [0.3, 0.1, 0.0], false),
            bone(None, [-0.5, 0.5, 0.5], true),
            bone(Some(6), [-0.5, 0.4, 0.5], true),
        ]);
        let (t, d) = round_trip(&s);
        assert_eq!(
            t.iter().filter(|&&x| x == SPRING).count(),
            3,
            "{:?}",
            names(&t)
        );
        assert_eq!(d.bones.iter().filter(|b| b.spring).count(), 5);
        // A spring first root is written with its opener.
        let s = skel(vec![
            bone(None, [0.0, 0.0, 0.0], true),
            bone(Some(0), [0.0, -0.2, 0.0], true),
        ]);
        let (t, _) = round_trip(&s);
        assert_eq!(&t[2..4], &[SPRING, BRANCH]);
        assert_eq!(t.len(), 2 + 2 + 6 + 1);
    }

    #[test]
    fn multiple_roots_round_trip() {
        let s = skel(vec![
            bone(None, [0.0, 0.0, 0.0], false),
            bone(Some(0), [0.0, 0.5, 0.0], false),
            bone(None, [0.5, 0.9, 0.0], false),
            bone(None, [-0.5, -0.9, 0.0], false),
            bone(Some(3), [-0.5, -0.8, 0.0], false),
        ]);
        let (t, d) = round_trip(&s);
        assert_eq!(d.roots().count(), 3);
        // Highest root first, written bare; the others as <branch> <branch> xyz.
        assert_eq!(&t[2..5], &[quantize(0.5), quantize(0.9), quantize(0.0)]);
        assert_eq!(t.windows(2).filter(|w| w == &[BRANCH, BRANCH]).count(), 2);
    }

    #[test]
    fn mixamo_template_round_trips_with_hands_and_extras() {
        let m = match_mixamo(&synthetic_mixamo(true, true)).unwrap();
        let (t, d) = round_trip(&m);
        assert_eq!(t[0], BOS);
        assert_eq!(t[1], class_token(Some("humanoid")));
        assert_eq!(t[2], MIXAMO_BODY);
        let hand1 = 3 + 3 * BODY_BONES;
        assert_eq!(t[hand1], MIXAMO_HAND);
        let hand2 = hand1 + 1 + 3 * HAND_BONES;
        assert_eq!(t[hand2], MIXAMO_HAND);
        let rest = hand2 + 1 + 3 * HAND_BONES;
        assert_eq!(t[rest], BRANCH, "extras hang off template joints");
        assert!(t[3..rest].iter().all(|&x| is_coord(x) || x == MIXAMO_HAND));
        assert_eq!(d.template, Some(Template::MixamoBody));
        assert_eq!(d.category.as_deref(), Some("humanoid"));
        for (a, b) in m
            .bones
            .iter()
            .zip(&d.bones)
            .take(BODY_BONES + 2 * HAND_BONES)
        {
            assert_eq!(a.name, b.name);
        }
        assert!(d.bones[BODY_BONES + 2 * HAND_BONES..]
            .iter()
            .all(|b| b.name.starts_with("bone_")));
        assert!(template::match_mixamo(&d).is_some());

        for (l, r) in [(false, true), (true, false), (false, false)] {
            let m = match_mixamo(&synthetic_mixamo(l, r)).unwrap();
            let (t, d) = round_trip(&m);
            assert_eq!(
                t.iter().filter(|&&x| x == MIXAMO_HAND).count(),
                l as usize + r as usize
            );
            let hand = template::hand_block_at(&d, BODY_BONES);
            assert_eq!(
                hand,
                if r {
                    Some(Side::Right)
                } else if l {
                    Some(Side::Left)
                } else {
                    None
                }
            );
        }
    }

    #[test]
    fn hands_posed_at_the_wrong_side_fall_back_to_branches() {
        let mut m = match_mixamo(&synthetic_mixamo(true, true)).unwrap();
        // Swap the hands' fingers geometrically: the left fingers now sit by the right hand.
        for k in 0..HAND_BONES {
            let (l, r) = (BODY_BONES + k, BODY_BONES + HAND_BONES + k);
            let (hl, hr) = (m.bones[l].head, m.bones[r].head);
            m.bones[l].head = hr;
            m.bones[r].head = hl;
        }
        let (t, _) = round_trip(&m);
        assert!(!t.contains(&MIXAMO_HAND));
        // Only the left hand misplaced: writing the right hand first lets the side rule take
        // the right block, and the second block goes to the other side, left.
        let mut m = match_mixamo(&synthetic_mixamo(true, true)).unwrap();
        for k in 0..HAND_BONES {
            m.bones[BODY_BONES + k].head.x -= 1.2;
        }
        let (t, d) = round_trip(&m);
        assert_eq!(t.iter().filter(|&&x| x == MIXAMO_HAND).count(), 2);
        assert_eq!(template::hand_block_at(&d, BODY_BONES), Some(Side::Right));
        assert_eq!(
            template::hand_block_at(&d, BODY_BONES + HAND_BONES),
            Some(Side::Left)
        );
        // A lone hand nearer the other side cannot be a block.
        let mut m = match_mixamo(&synthetic_mixamo(true, false)).unwrap();
        for k in 0..HAND_BONES {
            m.bones[BODY_BONES + k].head.x -= 1.2;
        }
        let (t, d) = round_trip(&m);
        assert!(!t.contains(&MIXAMO_HAND));
        assert_eq!(template::hand_block_at(&d, BODY_BONES), None);
    }

    #[test]
    fn coincident_joints_round_trip_through_alt() {
        // Joints 1 and 3 share a cell; 4 and 5 hang off 3, the later-written joint there.
        let s = skel(vec![
            bone(None, [0.0, 0.0, 0.0], false),
            bone(Some(0), [0.0, 0.5, 0.0], false),
            bone(Some(1), [0.0, 0.9, 0.0], false),
            bone(Some(0), [0.001, 0.501, 0.0], false),
            bone(Some(3), [0.4, 0.5, 0.0], false),
            bone(Some(3), [0.4, 0.3, 0.0], false),
        ]);
        let (t, d) = round_trip(&s);
        let c = |x: f32| quantize(x);
        let (z, h) = (c(0.0), c(0.5));
        // 4 continues 3's chain; 5 names 3's cell, where 1 comes first, so it needs one <alt>.
        let tail = [BRANCH, z, h, z, ALT, c(0.4), c(0.3), z, EOS];
        assert_eq!(&t[t.len() - tail.len()..], &tail, "{:?}", names(&t));
        assert_eq!(d.bones[5].parent, Some(3));
        assert_eq!(t.iter().filter(|&&x| x == ALT).count(), 1);
        // The parent written first needs none.
        let mut first = s.clone();
        first.bones[5].parent = Some(1);
        let (t, _) = round_trip(&first);
        assert!(!t.contains(&ALT));

        // Everything in one cell: a root with a chain and branches, ranks up to n - 2.
        let parents = [None, Some(0), Some(1), Some(0), Some(2), Some(1), Some(5)];
        let parents = parents.into_iter().chain([3, 0, 4, 8, 10].map(Some));
        let pile: Vec<Bone> = parents
            .enumerate()
            .map(|(i, p)| bone(p, [0.2, 0.2, 0.2], i % 5 == 3))
            .collect();
        let (t, _) = round_trip(&skel(pile));
        assert!(t.windows(3).any(|w| w == [ALT; 3]), "{:?}", names(&t));
    }

    #[test]
    fn coincident_template_joints_round_trip() {
        // Collapse a finger and put a tail on the hips and a bone on the left hand: branches
        // off those cells must find template joints among extras.
        let mut m = match_mixamo(&synthetic_mixamo(true, false)).unwrap();
        let (hips, hand) = (m.bones[0].head, m.bones[LEFT_HAND].head);
        for k in 0..3 {
            m.bones[BODY_BONES + 3 + k].head = hand;
        }
        for b in m.bones.iter_mut().skip(BODY_BONES + HAND_BONES) {
            if b.name.starts_with("Tail") {
                b.head = hips;
            }
        }
        m.bones.push(Bone {
            name: "prop".into(),
            parent: Some(LEFT_HAND),
            head: hand,
            tail: hand,
            spring: false,
        });
        let n = m.len();
        m.bones.push(Bone {
            name: "prop_tip".into(),
            parent: Some(n - 1),
            head: hand + Vec3::X * 0.3,
            tail: hand,
            spring: true,
        });
        let (t, _) = round_trip(&m);
        assert!(t.contains(&ALT), "{:?}", names(&t));
    }

    #[test]
    fn random_skeletons_with_coincident_joints_round_trip_exactly() {
        let mut rng = Rng::new(99);
        let mut alts = 0;
        for _ in 0..600 {
            let mut s = random_skeleton(&mut rng, 60);
            let n = s.len();
            // Force a few more collisions, anywhere in the tree.
            for _ in 0..rng.below(4) {
                let (a, b) = (rng.below(n), rng.below(n));
                s.bones[a].head = s.bones[b].head;
            }
            let (t, _) = round_trip(&s);
            alts += t.iter().filter(|&&x| x == ALT).count();
        }
        assert!(
            alts > 500,
            "only {alts} <alt> tokens: the test lost its collisions"
        );
        // Templates with coincident extras.
        for _ in 0..100 {
            let mut m = match_mixamo(&synthetic_mixamo(rng.chance(0.5), rng.chance(0.5))).unwrap();
            let n = m.len();
            for _ in 0..1 + rng.below(6) {
                let (a, b) = (rng.below(n), rng.below(n));
                m.bones[a].head = m.bones[b].head;
            }
            round_trip(&m);
        }
    }

    #[test]
    fn same_topology_in_order_notices_differences() {
        let s = skel(vec![
            bone(None, [0.0, 0.0, 0.0], false),
            bone(Some(0), [0.0, 0.5, 0.0], false),
            bone(Some(0), [0.0, 0.5, 0.0], false),
        ]);
        assert!(same_topology_in_order(&s, &s, &[0, 1, 2], 0.0).is_ok());
        // Bones 1 and 2 are interchangeable.
        assert!(same_topology_in_order(&s, &s, &[0, 2, 1], 0.0).is_ok());
        assert!(same_topology_in_order(&s, &s, &[1, 0, 2], 0.0).is_err());
        assert!(same_topology_in_order(&s, &s, &[0, 1, 1], 0.0).is_err());
        assert!(same_topology_in_order(&s, &s, &[0, 1], 0.0).is_err());
        let mut other = s.clone();
        other.bones[2].parent = Some(1);
        assert!(same_topology_in_order(&s, &other, &[0, 1, 2], 0.0).is_err());
        let mut other = s.clone();
        other.bones[2].head.x = 0.01;
        assert!(same_topology_in_order(&s, &other, &[0, 1, 2], 0.005).is_err());
        other.bones[2].head.x = f32::NAN;
        assert!(same_topology_in_order(&s, &other, &[0, 1, 2], 0.005).is_err());
        let mut other = s.clone();
        other.bones[1].spring = true;
        assert!(same_topology_in_order(&s, &other, &[0, 1, 2], 0.0).is_err());
    }

    #[test]
    fn tokenize_rejects_invalid_skeletons() {
        assert_eq!(tokenize(&Skeleton::default()), Err(TokenizeError::Empty));
        let mut s = skel(vec![
            bone(None, [0.0; 3], false),
            bone(Some(1), [0.1; 3], false),
        ]);
        assert_eq!(tokenize(&s), Err(TokenizeError::BadParent(1, 1)));
        s.bones[1].parent = Some(0);
        s.bones[1].head.y = f32::INFINITY;
        assert_eq!(tokenize(&s), Err(TokenizeError::NonFinite(1)));
        s.bones[1].head.y = 0.0;
        s.template = Some(Template::MixamoBody);
        assert_eq!(tokenize(&s), Err(TokenizeError::TemplateMismatch));
        s.template = Some(Template::MixamoHand);
        assert!(tokenize(&s).is_ok());
    }

    #[test]
    fn malformed_sequences_are_errors() {
        let z = 128;
        let cases: Vec<Vec<u32>> = vec![
            vec![],
            vec![BOS],
            vec![BOS, CLS_NONE],
            vec![BOS, CLS_NONE, EOS],
            vec![CLS_NONE, z, z, z, EOS],
            vec![BOS, z, z, z, EOS],
            vec![BOS, CLS_NONE, z, z, EOS],
            vec![BOS, CLS_NONE, z, z, z, z, EOS],
            vec![BOS, CLS_NONE, BRANCH, z, z, z, z, z, z, EOS],
            vec![BOS, CLS_NONE, z, z, z, BRANCH, z, z, EOS],
            vec![BOS, CLS_NONE, z, z, z, BRANCH, BRANCH, BRANCH, z, z, z, EOS],
            vec![BOS, CLS_NONE, z, z, z, SPRING, EOS],
            vec![BOS, CLS_NONE, MIXAMO_BODY, z, z, z, EOS],
            vec![BOS, CLS_NONE, MIXAMO_HAND, z, z, z, EOS],
            vec![BOS, CLS_NONE, z, z, z, MIXAMO_BODY, EOS],
            vec![BOS, CLS_NONE, z, z, z, EOS, z],
            vec![BOS, CLS_NONE, z, z, z, EOS, PAD, EOS],
            vec![BOS, CLS_NONE, z, z, z, 5000, EOS],
            vec![BOS, BOS, CLS_NONE, z, z, z, EOS],
            vec![BOS, CLS_NONE, z, z, z, PAD, EOS],
        ];
        for c in cases {
            assert!(detokenize(&c).is_err(), "{:?}", names(&c));
        }
        let ok = detokenize(&[BOS, CLS_NONE, z, z, z, EOS, PAD, PAD]).unwrap();
        assert_eq!(ok.len(), 1);
        assert_eq!(
            detokenize(&[BOS, CLS_NONE, z, z]),
            Err(DetokenizeError::Unterminated)
        );
        assert!(matches!(
            detokenize(&[BOS, CLS_NONE, z, z, z, 9999]),
            Err(DetokenizeError::Invalid {
                pos: 5,
                error: GrammarError::OutOfVocabulary(9999)
            })
        ));
    }

    #[test]
    fn random_and_mutated_sequences_never_panic() {
        let mut rng = Rng::new(3);
        let mut valid = Vec::new();
        for _ in 0..50 {
            valid.push(tokenize(&random_skeleton(&mut rng, 30)).unwrap());
        }
        valid.push(tokenize(&match_mixamo(&synthetic_mixamo(true, true)).unwrap()).unwrap());
        for _ in 0..20_000 {
            let mut t = valid[rng.below(valid.len())].clone();
            match rng.below(5) {
                0 => t.truncate(rng.below(t.len() + 1)),
                1 => {
                    let i = rng.below(t.len());
                    t.remove(i);
                }
                2 => {
                    let i = rng.below(t.len() + 1);
                    t.insert(i, rng.below(VOCAB_SIZE + 3) as u32);
                }
                3 => {
                    let i = rng.below(t.len());
                    t[i] = rng.below(VOCAB_SIZE + 3) as u32;
                }
                _ => {
                    let len = rng.below(60);
                    t = (0..len).map(|_| rng.below(VOCAB_SIZE + 3) as u32).collect();
                    if rng.chance(0.5) && !t.is_empty() {
                        t[0] = BOS;
                    }
                }
            }
            if let Ok(s) = detokenize(&t) {
                s.validate(usize::MAX).unwrap();
            }
        }
        let _ = detokenize(&[u32::MAX, 0, BOS]);
    }

    #[test]
    fn same_topology_notices_differences() {
        let s = skel(vec![
            bone(None, [0.0, 0.0, 0.0], false),
            bone(Some(0), [0.0, 0.5, 0.0], false),
            bone(Some(1), [0.0, 0.9, 0.0], false),
        ]);
        assert!(same_topology(&s, &s, 0.0).is_ok());
        let mut other = s.clone();
        other.bones[2].parent = Some(0);
        assert!(same_topology(&s, &other, HALF_BIN).is_err());
        let mut other = s.clone();
        other.bones[2].head.x += 0.1;
        assert!(same_topology(&s, &other, HALF_BIN).is_err());
        let mut other = s.clone();
        other.bones[1].spring = true;
        assert!(same_topology(&s, &other, HALF_BIN).is_err());
        let mut other = s.clone();
        other.bones.pop();
        assert!(same_topology(&s, &other, HALF_BIN).is_err());
        // Order does not matter, only structure.
        let fork = skel(vec![
            bone(None, [0.0, 0.0, 0.0], false),
            bone(Some(0), [0.0, 0.5, 0.0], false),
            bone(Some(0), [0.5, 0.0, 0.0], false),
            bone(Some(2), [0.9, 0.0, 0.0], false),
        ]);
        let shuffled = skel(vec![
            bone(None, [0.0, 0.0, 0.0], false),
            bone(Some(0), [0.5, 0.0, 0.0], false),
            bone(Some(1), [0.9, 0.0, 0.0], false),
            bone(Some(0), [0.0, 0.5, 0.0], false),
        ]);
        assert!(same_topology(&fork, &shuffled, 0.0).is_ok());
        let mut wrong = shuffled.clone();
        wrong.bones[2].parent = Some(0);
        assert!(same_topology(&fork, &wrong, 0.0).is_err());

        // A root and its child within a hair of each other: pairing by nearest head swaps
        // them, yet a consistent pairing exists.
        let a = skel(vec![
            bone(None, [0.0, 0.0, 0.0], false),
            bone(Some(0), [0.001, 0.0, 0.0], false),
            bone(Some(1), [0.0, 0.5, 0.0], false),
            bone(Some(0), [0.5, 0.0, 0.0], false),
        ]);
        let mut b = a.clone();
        b.bones[0].head.x = 0.001;
        b.bones[1].head.x = 0.0;
        assert!(same_topology(&a, &b, HALF_BIN).is_ok());
        // Coincident siblings whose subtrees differ must pair up by subtree.
        let a = skel(vec![
            bone(None, [0.0, 0.0, 0.0], false),
            bone(Some(0), [0.3, 0.3, 0.3], false),
            bone(Some(0), [0.3, 0.3, 0.3], false),
            bone(Some(1), [0.5, 0.5, 0.5], false),
            bone(Some(2), [0.6, 0.6, 0.6], true),
        ]);
        let mut b = a.clone();
        b.bones[3].parent = Some(2);
        b.bones[4].parent = Some(1);
        assert!(same_topology(&a, &b, HALF_BIN).is_ok());
        b.bones[3].parent = Some(1);
        let err = same_topology(&a, &b, HALF_BIN).unwrap_err();
        assert!(err.contains("subtree"), "{err}");
        let mut b = a.clone();
        b.bones[4].spring = false;
        assert!(same_topology(&a, &b, HALF_BIN).is_err());
    }
}
