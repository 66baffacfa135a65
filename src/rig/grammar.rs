//! The token grammar as a state machine, for constrained decoding and for parsing.
//!
//! At every step [`Grammar::allowed`] says which tokens may come next, so a decoder that only
//! samples allowed tokens always produces a sequence that [`detokenize`] turns into a valid
//! tree of at most `max_bones` bones. The grammar also *is* the parser: it tracks the decoded
//! joints as it goes, and `detokenize` is a replay through [`Grammar::lenient`], so the two can
//! never disagree.
//!
//! Beyond the shape of the sequence (see [`super::tokenizer`]), [`Grammar::new`] only lets a
//! branch's parent position be the exact position of a joint already decoded: the parent is
//! found by position, and a position matching no joint would be snapped to the nearest one
//! anyway. It then offers `<alt>` only while the parent's cell holds another earlier joint
//! to step to, so every `<alt>` changes the parent. The lenient grammar accepts any parent
//! position and snaps it to the nearest joint, whose cell `<alt>` then steps through, which
//! is what a sequence from an unconstrained decoder needs.
//!
//! [`detokenize`]: super::tokenizer::detokenize

use super::template::{self, Side, BODY_BONES, BODY_PARENTS, HAND_BONES, LEFT_HAND, RIGHT_HAND};
use super::tokenizer::{
    hand_side, is_class_token, is_coord, token_name, ALT, BOS, BRANCH, COORD_BINS, EOS,
    MIXAMO_BODY, MIXAMO_HAND, PAD, SPRING, VOCAB_SIZE,
};

const MASK_WORDS: usize = VOCAB_SIZE.div_ceil(64);

/// A set of token ids below [`VOCAB_SIZE`].
#[derive(Clone, Copy, PartialEq, Eq, Default)]
pub struct TokenMask([u64; MASK_WORDS]);

impl TokenMask {
    pub fn contains(&self, tok: u32) -> bool {
        (tok as usize) < VOCAB_SIZE && self.0[tok as usize / 64] >> (tok % 64) & 1 == 1
    }

    /// Adds `tok`; ids outside the vocabulary are ignored.
    pub fn insert(&mut self, tok: u32) {
        if (tok as usize) < VOCAB_SIZE {
            self.0[tok as usize / 64] |= 1 << (tok % 64);
        }
    }

    pub fn len(&self) -> usize {
        self.0.iter().map(|w| w.count_ones() as usize).sum()
    }

    pub fn is_empty(&self) -> bool {
        self.0.iter().all(|&w| w == 0)
    }

    pub fn iter(&self) -> impl Iterator<Item = u32> + '_ {
        (0..VOCAB_SIZE as u32).filter(|&t| self.contains(t))
    }
}

impl std::fmt::Debug for TokenMask {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let coords = self.iter().filter(|&t| is_coord(t)).count();
        let mut l = f.debug_list();
        if coords > 0 {
            l.entry(&format_args!("{coords} coordinates"));
        }
        for t in self.iter().filter(|&t| !is_coord(t)) {
            l.entry(&format_args!("{}", token_name(t)));
        }
        l.finish()
    }
}

/// Where a decoded joint sits in a template.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TemplateSlot {
    /// Index into the body template.
    Body(usize),
    /// A hand bone (0..15) of the given side.
    Hand(Side, usize),
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DecodedJoint {
    /// Quantized position (coordinate bins).
    pub q: [u8; 3],
    /// Always smaller than the joint's own index.
    pub parent: Option<usize>,
    pub spring: bool,
    pub slot: Option<TemplateSlot>,
}

#[derive(Debug, thiserror::Error, Clone, PartialEq, Eq)]
pub enum GrammarError {
    #[error("token {0} is outside the vocabulary")]
    OutOfVocabulary(u32),
    #[error("token {} after <eos>; only <pad> may follow", token_name(*.0))]
    AfterEnd(u32),
    #[error("token {name} would add a bone past the cap of {cap}", name = token_name(*.0), cap = .1)]
    TooManyBones(u32, usize),
    #[error("coordinate {0} puts the branch's parent where no joint is")]
    NoSuchParent(u32),
    #[error("<alt> past the last of the {0} earlier joints in the branch parent's cell")]
    NoMoreAlternatives(usize),
    #[error("token {} cannot come here; expected {expected}", token_name(*token))]
    Unexpected { token: u32, expected: &'static str },
}

/// A prefix the grammar rejects, with the position of the offending token.
#[derive(Debug, thiserror::Error, Clone, PartialEq, Eq)]
#[error("token {pos}: {error}")]
pub struct PrefixError {
    pub pos: usize,
    pub error: GrammarError,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Block {
    Body,
    Hand,
}

impl Block {
    fn len(self) -> usize {
        match self {
            Block::Body => BODY_BONES,
            Block::Hand => HAND_BONES,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    Bos,
    Cls,
    /// Between joints.
    Boundary,
    /// After an opener (`<branch>` or `<spring>`): a second `<branch>` (new root) or the
    /// parent's position.
    Opened {
        spring: bool,
    },
    Parent {
        spring: bool,
        got: [u8; 3],
        n: usize,
    },
    /// After a branch's parent position: each `<alt>` steps to the next earlier joint of
    /// `cell`, of which there are `count`; the joint's first coordinate settles the parent.
    Alt {
        spring: bool,
        cell: [u8; 3],
        rank: usize,
        count: usize,
    },
    Joint {
        parent: Option<usize>,
        spring: bool,
        got: [u8; 3],
        n: usize,
    },
    Template {
        block: Block,
        got: [u8; 3],
        n: usize,
    },
    Done,
}

#[derive(Clone, Debug)]
pub struct Grammar {
    state: State,
    max_bones: usize,
    snap_parents: bool,
    joints: Vec<DecodedJoint>,
    class: Option<u32>,
    body: bool,
    hands: usize,
    first_hand: Option<Side>,
    /// Right after template blocks, before any other joint: another hand block may come.
    templates_open: bool,
    /// `<mixamo:body>` is refused (a caller asked for a free-form skeleton).
    no_templates: bool,
    /// Spring flag of the chain the last joint belongs to; `None` when the last joint is a
    /// template joint (or there is none), which cannot be continued.
    chain: Option<bool>,
}

impl Grammar {
    /// A grammar for sequences of at most `max_bones` bones (at least 1: a skeleton needs a
    /// bone) whose branch parents are existing joint positions.
    pub fn new(max_bones: usize) -> Self {
        Grammar {
            state: State::Bos,
            max_bones: max_bones.max(1),
            snap_parents: true,
            joints: Vec::new(),
            class: None,
            body: false,
            hands: 0,
            first_hand: None,
            templates_open: false,
            no_templates: false,
            chain: None,
        }
    }

    /// Like [`Grammar::new`] but a branch's parent may be any position: it snaps to the
    /// nearest joint, and `<alt>` steps through the joints sharing that joint's cell. Accepts
    /// exactly the sequences `detokenize` accepts.
    pub fn lenient(max_bones: usize) -> Self {
        Grammar {
            snap_parents: false,
            ..Grammar::new(max_bones)
        }
    }

    /// A grammar that has already consumed `tokens` (starting with `<bos>`), to continue a
    /// partial skeleton.
    pub fn from_prefix(max_bones: usize, tokens: &[u32]) -> Result<Self, PrefixError> {
        let mut g = Grammar::new(max_bones);
        for (pos, &t) in tokens.iter().enumerate() {
            g.advance(t).map_err(|error| PrefixError { pos, error })?;
        }
        Ok(g)
    }

    /// Refuses template blocks from now on (`template=none`).
    pub fn without_templates(mut self) -> Self {
        self.no_templates = true;
        self
    }

    pub fn max_bones(&self) -> usize {
        self.max_bones
    }

    /// Bones decoded so far (a bone counts once all three of its coordinates are in).
    pub fn bones(&self) -> usize {
        self.joints.len()
    }

    /// Joints decoded so far. The first-segment parents of a hand block are settled when the
    /// block ends (its side depends on all its joints); until then they point at `LeftHand`.
    pub fn joints(&self) -> &[DecodedJoint] {
        &self.joints
    }

    pub fn class_token(&self) -> Option<u32> {
        self.class
    }

    pub fn has_body_template(&self) -> bool {
        self.body
    }

    /// `<eos>` has been consumed.
    pub fn is_done(&self) -> bool {
        self.state == State::Done
    }

    fn room(&self, bones: usize) -> bool {
        self.joints
            .len()
            .checked_add(bones)
            .is_some_and(|n| n <= self.max_bones)
    }

    /// Whether a parent coordinate `tok` may follow the parent coordinates `got`.
    fn parent_coord_ok(&self, got: &[u8], tok: u32) -> bool {
        if !self.snap_parents {
            return true;
        }
        let n = got.len();
        self.joints
            .iter()
            .any(|j| j.q[..n] == *got && j.q[n] as u32 == tok)
    }

    /// Tokens allowed at a boundary, ignoring the bone cap: the cap is checked separately so
    /// that errors can say which rule a token broke.
    fn boundary_shape_allows(&self, tok: u32) -> bool {
        let n = self.joints.len();
        match tok {
            t if is_coord(t) => n == 0 || self.chain.is_some(),
            SPRING => true,
            BRANCH => n > 0,
            MIXAMO_BODY => n == 0 && !self.no_templates,
            MIXAMO_HAND => self.templates_open && self.hands < 2,
            EOS => n > 0,
            _ => false,
        }
    }

    /// How many bones `tok` commits to at a boundary.
    fn boundary_cost(tok: u32) -> usize {
        match tok {
            MIXAMO_BODY => BODY_BONES,
            MIXAMO_HAND => HAND_BONES,
            EOS => 0,
            _ => 1,
        }
    }

    pub fn is_allowed(&self, tok: u32) -> bool {
        match self.state {
            State::Bos => tok == BOS,
            State::Cls => is_class_token(tok),
            State::Boundary => {
                self.boundary_shape_allows(tok) && self.room(Self::boundary_cost(tok))
            }
            State::Opened { .. } => {
                tok == BRANCH
                    || (is_coord(tok) && !self.joints.is_empty() && self.parent_coord_ok(&[], tok))
            }
            State::Parent { got, n, .. } => is_coord(tok) && self.parent_coord_ok(&got[..n], tok),
            State::Alt { rank, count, .. } => is_coord(tok) || (tok == ALT && rank + 1 < count),
            State::Joint { .. } | State::Template { .. } => is_coord(tok),
            State::Done => tok == PAD,
        }
    }

    /// The tokens that may come next; never empty. After `<eos>` it is `<pad>`, so a batch
    /// decoder can keep stepping a finished sequence.
    pub fn allowed(&self) -> TokenMask {
        let mut m = TokenMask::default();
        let coords_any = match self.state {
            State::Joint { .. } | State::Template { .. } | State::Alt { .. } => true,
            State::Parent { got, n, .. } => {
                self.insert_parent_coords(&mut m, &got[..n]);
                false
            }
            State::Opened { .. } => {
                self.insert_parent_coords(&mut m, &[]);
                false
            }
            State::Boundary => self.is_allowed(0),
            _ => false,
        };
        if coords_any {
            m.0[..COORD_BINS as usize / 64].fill(u64::MAX);
        }
        for t in COORD_BINS..VOCAB_SIZE as u32 {
            if self.is_allowed(t) {
                m.insert(t);
            }
        }
        m
    }

    fn insert_parent_coords(&self, m: &mut TokenMask, got: &[u8]) {
        let n = got.len();
        if self.joints.is_empty() {
            return;
        }
        if !self.snap_parents {
            m.0[..COORD_BINS as usize / 64].fill(u64::MAX);
            return;
        }
        for j in &self.joints {
            if j.q[..n] == *got {
                m.insert(j.q[n] as u32);
            }
        }
    }

    /// Writes the allowed set into `out[..VOCAB_SIZE]`; entries past it become `false`.
    pub fn allowed_into(&self, out: &mut [bool]) {
        let m = self.allowed();
        for (t, o) in out.iter_mut().enumerate() {
            *o = m.contains(t as u32);
        }
    }

    /// Sets the logits of tokens that may not come next (including ids past the vocabulary,
    /// for models with a padded output layer) to negative infinity.
    pub fn mask_logits(&self, logits: &mut [f32]) {
        let m = self.allowed();
        for (t, l) in logits.iter_mut().enumerate() {
            if !m.contains(t as u32) {
                *l = f32::NEG_INFINITY;
            }
        }
    }

    /// Consumes one token. On error the grammar is unchanged.
    pub fn advance(&mut self, tok: u32) -> Result<(), GrammarError> {
        if !self.is_allowed(tok) {
            return Err(self.explain(tok));
        }
        let c = tok as u8;
        self.state = match self.state {
            State::Bos => State::Cls,
            State::Cls => {
                self.class = Some(tok);
                State::Boundary
            }
            State::Boundary => match tok {
                EOS => State::Done,
                MIXAMO_BODY => State::Template {
                    block: Block::Body,
                    got: [0; 3],
                    n: 0,
                },
                MIXAMO_HAND => State::Template {
                    block: Block::Hand,
                    got: [0; 3],
                    n: 0,
                },
                opener @ (BRANCH | SPRING) => {
                    self.templates_open = false;
                    State::Opened {
                        spring: opener == SPRING,
                    }
                }
                _ => {
                    self.templates_open = false;
                    let (parent, spring) = match self.chain {
                        Some(spring) => (Some(self.joints.len() - 1), spring),
                        None => (None, false),
                    };
                    State::Joint {
                        parent,
                        spring,
                        got: [c, 0, 0],
                        n: 1,
                    }
                }
            },
            State::Opened { spring } => {
                if tok == BRANCH {
                    State::Joint {
                        parent: None,
                        spring,
                        got: [0; 3],
                        n: 0,
                    }
                } else {
                    State::Parent {
                        spring,
                        got: [c, 0, 0],
                        n: 1,
                    }
                }
            }
            State::Parent { spring, mut got, n } => {
                got[n] = c;
                if n + 1 < 3 {
                    State::Parent {
                        spring,
                        got,
                        n: n + 1,
                    }
                } else {
                    let cell = self.joints[self.nearest(got)].q;
                    State::Alt {
                        spring,
                        cell,
                        rank: 0,
                        count: self.joints.iter().filter(|j| j.q == cell).count(),
                    }
                }
            }
            State::Alt {
                spring,
                cell,
                rank,
                count,
            } => {
                if tok == ALT {
                    State::Alt {
                        spring,
                        cell,
                        rank: rank + 1,
                        count,
                    }
                } else {
                    State::Joint {
                        parent: Some(self.nth_in_cell(cell, rank)),
                        spring,
                        got: [c, 0, 0],
                        n: 1,
                    }
                }
            }
            State::Joint {
                parent,
                spring,
                mut got,
                n,
            } => {
                got[n] = c;
                if n + 1 < 3 {
                    State::Joint {
                        parent,
                        spring,
                        got,
                        n: n + 1,
                    }
                } else {
                    self.joints.push(DecodedJoint {
                        q: got,
                        parent,
                        spring,
                        slot: None,
                    });
                    self.chain = Some(spring);
                    State::Boundary
                }
            }
            State::Template { block, mut got, n } => {
                got[n] = c;
                if n + 1 < 3 {
                    State::Template {
                        block,
                        got,
                        n: n + 1,
                    }
                } else {
                    self.push_template_joint(block, got)
                }
            }
            State::Done => State::Done,
        };
        Ok(())
    }

    fn push_template_joint(&mut self, block: Block, q: [u8; 3]) -> State {
        let start = match block {
            Block::Body => 0,
            Block::Hand => BODY_BONES + HAND_BONES * self.hands,
        };
        let k = self.joints.len() - start;
        let (parent, slot) = match block {
            Block::Body => (BODY_PARENTS[k], TemplateSlot::Body(k)),
            Block::Hand => (
                Some(template::hand_parent(k).map_or(LEFT_HAND, |rel| start + rel)),
                TemplateSlot::Hand(Side::Left, k),
            ),
        };
        self.joints.push(DecodedJoint {
            q,
            parent,
            spring: false,
            slot: Some(slot),
        });
        if k + 1 < block.len() {
            return State::Template {
                block,
                got: [0; 3],
                n: 0,
            };
        }
        match block {
            Block::Body => self.body = true,
            Block::Hand => {
                let side = match self.first_hand {
                    Some(first) => first.other(),
                    None => {
                        let qs: Vec<[u8; 3]> = self.joints[start..].iter().map(|j| j.q).collect();
                        let s = hand_side(self.joints[LEFT_HAND].q, self.joints[RIGHT_HAND].q, &qs);
                        self.first_hand = Some(s);
                        s
                    }
                };
                for (k, j) in self.joints[start..].iter_mut().enumerate() {
                    j.slot = Some(TemplateSlot::Hand(side, k));
                    if template::hand_parent(k).is_none() {
                        j.parent = Some(side.hand_index());
                    }
                }
                self.hands += 1;
            }
        }
        self.templates_open = true;
        self.chain = None;
        State::Boundary
    }

    /// The `rank`-th (from 0) joint in `cell`, in decoding order. The caller has checked
    /// that the cell holds more than `rank` joints.
    fn nth_in_cell(&self, cell: [u8; 3], rank: usize) -> usize {
        self.joints
            .iter()
            .enumerate()
            .filter(|(_, j)| j.q == cell)
            .nth(rank)
            .map(|(i, _)| i)
            .expect("<alt> is only allowed while the cell has another joint")
    }

    /// The earliest joint nearest to a quantized position. Joints of its cell are all as
    /// near, so it is the first of them, where `<alt>` counts from.
    fn nearest(&self, q: [u8; 3]) -> usize {
        let d2 = |j: &DecodedJoint| -> i32 {
            (0..3).map(|a| (j.q[a] as i32 - q[a] as i32).pow(2)).sum()
        };
        let mut best = (i32::MAX, 0);
        for (i, j) in self.joints.iter().enumerate() {
            let d = d2(j);
            if d < best.0 {
                best = (d, i);
            }
        }
        best.1
    }

    fn explain(&self, tok: u32) -> GrammarError {
        if tok as usize >= VOCAB_SIZE {
            return GrammarError::OutOfVocabulary(tok);
        }
        let expected = match self.state {
            State::Bos => "<bos>",
            State::Cls => "a class token",
            State::Boundary => {
                if self.boundary_shape_allows(tok) {
                    return GrammarError::TooManyBones(tok, self.max_bones);
                }
                match (self.joints.is_empty(), self.chain.is_some()) {
                    (true, _) => "a first joint, <spring> or <mixamo:body>",
                    (false, true) => "a joint, <branch>, <spring> or <eos>",
                    (false, false) => "<branch>, <spring>, <eos> or another hand block",
                }
            }
            State::Opened { .. } => {
                if is_coord(tok) && !self.joints.is_empty() {
                    return GrammarError::NoSuchParent(tok);
                }
                if self.joints.is_empty() {
                    "<branch> (a first joint has no parent)"
                } else {
                    "<branch> or a parent coordinate"
                }
            }
            State::Parent { .. } => {
                if is_coord(tok) {
                    return GrammarError::NoSuchParent(tok);
                }
                "a parent coordinate"
            }
            State::Alt { count, .. } => {
                if tok == ALT {
                    return GrammarError::NoMoreAlternatives(count);
                }
                "<alt> or a coordinate"
            }
            State::Joint { .. } | State::Template { .. } => "a coordinate",
            State::Done => return GrammarError::AfterEnd(tok),
        };
        GrammarError::Unexpected {
            token: tok,
            expected,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::template::{match_mixamo, synthetic_mixamo};
    use crate::rig::tokenizer::test_support::{random_skeleton, Rng};
    use crate::rig::tokenizer::{detokenize, tokenize, CLS_BASE, CLS_NONE};

    /// Longest sequence a walk may take: `<bos> <cls> <eos>` plus at most 7 tokens per bone
    /// (`<spring>` + parent + joint) and an `<alt>` per earlier joint, plus a template token
    /// per block and trailing slack.
    fn bound(max_bones: usize) -> usize {
        3 + (7 + max_bones) * max_bones + 3
    }

    /// Walks the grammar picking uniformly among allowed tokens, or, with `bias`, among the
    /// allowed non-coordinate tokens half the time, so templates and springs show up often.
    /// With `narrow`, coordinates come from bins 0 and 1 when allowed, so joints pile up in
    /// a few cells and `<alt>` gets exercised.
    fn walk(rng: &mut Rng, g: &mut Grammar, bias: bool, narrow: bool) -> Vec<u32> {
        let mut out = Vec::new();
        let limit = bound(g.max_bones());
        while !g.is_done() {
            let m = g.allowed();
            assert!(!m.is_empty(), "dead end after {out:?}");
            let all: Vec<u32> = m.iter().collect();
            let specials: Vec<u32> = all.iter().copied().filter(|&t| !is_coord(t)).collect();
            let few: Vec<u32> = all.iter().copied().filter(|&t| t >= 2).collect();
            let all = if narrow && few.len() < all.len() && rng.chance(0.9) {
                all.iter()
                    .copied()
                    .filter(|&t| !is_coord(t) || t < 2)
                    .collect()
            } else {
                all
            };
            let pool = if bias && !specials.is_empty() && rng.chance(0.5) {
                &specials
            } else {
                &all
            };
            let t = pool[rng.below(pool.len())];
            // allowed() and advance() agree on every token, allowed or not.
            for probe in [t, rng.below(VOCAB_SIZE + 4) as u32] {
                let mut c = g.clone();
                assert_eq!(
                    c.advance(probe).is_ok(),
                    m.contains(probe),
                    "{probe} after {out:?}"
                );
                assert_eq!(g.is_allowed(probe), m.contains(probe));
            }
            g.advance(t).unwrap();
            out.push(t);
            assert!(out.len() <= limit, "no <eos> within {limit} tokens");
        }
        out
    }

    #[test]
    fn random_walks_end_and_decode_to_valid_skeletons() {
        let mut rng = Rng::new(11);
        let mut saw = [0usize; 5]; // body template, hands, springs, extra roots, <alt>
        for i in 0..3000 {
            let max = 1 + rng.below(if i % 3 == 0 { 70 } else { 12 });
            let mut g = if i % 2 == 0 {
                Grammar::new(max)
            } else {
                Grammar::lenient(max)
            };
            let t = walk(&mut rng, &mut g, i % 4 < 2, i % 5 < 2);
            let s = detokenize(&t).unwrap_or_else(|e| panic!("{e}: {t:?}"));
            s.validate(max).unwrap();
            assert_eq!(s.len(), g.bones());
            saw[0] += t.contains(&MIXAMO_BODY) as usize;
            saw[1] += t.contains(&MIXAMO_HAND) as usize;
            saw[2] += t.contains(&SPRING) as usize;
            saw[3] += (s.roots().count() > 1) as usize;
            saw[4] += t.contains(&ALT) as usize;
            for (i, b) in s.bones.iter().enumerate() {
                assert!(b.parent.is_none_or(|p| p < i));
            }
        }
        assert!(saw.iter().all(|&k| k > 10), "{saw:?}");
    }

    #[test]
    fn tokenizer_output_is_accepted_token_by_token() {
        let mut rng = Rng::new(5);
        let mut cases: Vec<_> = (0..300).map(|_| random_skeleton(&mut rng, 100)).collect();
        for (l, r) in [(true, true), (true, false), (false, true), (false, false)] {
            cases.push(match_mixamo(&synthetic_mixamo(l, r)).unwrap());
        }
        for s in &cases {
            let t = tokenize(s).unwrap();
            let mut g = Grammar::new(s.len());
            for (pos, &tok) in t.iter().enumerate() {
                assert!(
                    g.allowed().contains(tok),
                    "token {pos} {}: {t:?}",
                    token_name(tok)
                );
                g.advance(tok).unwrap();
            }
            assert!(g.is_done());
            assert_eq!(g.bones(), s.len());
            // One bone fewer than needed: the grammar must refuse somewhere.
            if s.len() > 1 {
                let mut g = Grammar::new(s.len() - 1);
                assert!(t.iter().any(|&tok| g.advance(tok).is_err()));
            }
        }
    }

    #[test]
    fn from_prefix_continues_where_the_prefix_stopped() {
        let mut rng = Rng::new(8);
        for _ in 0..100 {
            let s = random_skeleton(&mut rng, 40);
            let t = tokenize(&s).unwrap();
            let cut = rng.below(t.len() + 1);
            let mut g = Grammar::from_prefix(s.len(), &t[..cut]).unwrap();
            for &tok in &t[cut..] {
                g.advance(tok).unwrap();
            }
            assert!(g.is_done());
        }
        let err = Grammar::from_prefix(5, &[BOS, CLS_NONE, EOS]).unwrap_err();
        assert_eq!(err.pos, 2);
        assert!(Grammar::from_prefix(5, &[CLS_NONE]).is_err());
    }

    #[test]
    fn cap_leaves_only_eos() {
        let mut g =
            Grammar::from_prefix(2, &[BOS, CLS_BASE + 1, 1, 2, 3, BRANCH, 1, 2, 3, 4, 5, 6])
                .unwrap();
        assert_eq!(g.bones(), 2);
        let m = g.allowed();
        assert_eq!(m.iter().collect::<Vec<_>>(), vec![EOS]);
        assert_eq!(g.advance(7), Err(GrammarError::TooManyBones(7, 2)));
        assert_eq!(
            g.advance(BRANCH),
            Err(GrammarError::TooManyBones(BRANCH, 2))
        );
        g.advance(EOS).unwrap();
        assert_eq!(g.allowed().iter().collect::<Vec<_>>(), vec![PAD]);
        assert_eq!(g.advance(EOS), Err(GrammarError::AfterEnd(EOS)));
        // Templates need room for all their bones.
        let g = Grammar::from_prefix(21, &[BOS, CLS_NONE]).unwrap();
        assert!(!g.allowed().contains(MIXAMO_BODY));
        assert!(Grammar::from_prefix(22, &[BOS, CLS_NONE])
            .unwrap()
            .allowed()
            .contains(MIXAMO_BODY));
    }

    #[test]
    fn shape_rules() {
        let g = Grammar::new(10);
        assert_eq!(g.allowed().iter().collect::<Vec<_>>(), vec![BOS]);
        let g = Grammar::from_prefix(10, &[BOS]).unwrap();
        assert_eq!(g.allowed().len(), 9);
        // Start: a bare joint, <spring>, or the body template; no <eos>, <branch> or hand.
        let g = Grammar::from_prefix(30, &[BOS, CLS_NONE]).unwrap();
        let m = g.allowed();
        assert_eq!(m.len(), 256 + 2);
        assert!(m.contains(SPRING) && m.contains(MIXAMO_BODY));
        // A spring first root must be a root.
        let g = Grammar::from_prefix(30, &[BOS, CLS_NONE, SPRING]).unwrap();
        assert_eq!(g.allowed().iter().collect::<Vec<_>>(), vec![BRANCH]);
        // Branch parents snap to existing joints, coordinate by coordinate.
        let g = Grammar::from_prefix(30, &[BOS, CLS_NONE, 10, 20, 30, 40, 50, 60, BRANCH]).unwrap();
        assert_eq!(g.allowed().iter().collect::<Vec<_>>(), vec![10, 40, BRANCH]);
        let mut g =
            Grammar::from_prefix(30, &[BOS, CLS_NONE, 10, 20, 30, 40, 50, 60, BRANCH, 40]).unwrap();
        assert_eq!(g.allowed().iter().collect::<Vec<_>>(), vec![50]);
        assert_eq!(g.advance(20), Err(GrammarError::NoSuchParent(20)));
        // The lenient grammar takes any parent and snaps it to the nearest joint.
        let mut g = Grammar::lenient(30);
        for t in [
            BOS, CLS_NONE, 10, 20, 30, 40, 50, 60, BRANCH, 38, 49, 61, 0, 0, 0,
        ] {
            g.advance(t).unwrap();
        }
        assert_eq!(g.joints()[2].parent, Some(1));
        // After a template block: no bare continuation, but hands and branches.
        let mut body = vec![BOS, CLS_NONE, MIXAMO_BODY];
        body.extend(std::iter::repeat_n(7, 66));
        let g = Grammar::from_prefix(100, &body).unwrap();
        let m = g.allowed();
        assert!(!m.contains(7));
        assert!(
            m.contains(MIXAMO_HAND) && m.contains(BRANCH) && m.contains(SPRING) && m.contains(EOS)
        );
        let mut two = body.clone();
        for _ in 0..2 {
            two.push(MIXAMO_HAND);
            two.extend(std::iter::repeat_n(9, 45));
        }
        let g = Grammar::from_prefix(100, &two).unwrap();
        assert!(!g.allowed().contains(MIXAMO_HAND));
        let mut late = body.clone();
        late.extend([BRANCH, 7, 7, 7, 1, 2, 3]);
        let g = Grammar::from_prefix(100, &late).unwrap();
        assert!(!g.allowed().contains(MIXAMO_HAND));
        assert!(g.allowed().contains(1));
    }

    #[test]
    fn alt_steps_through_the_parent_cell() {
        // Joints 0 and 1 share cell (1, 2, 3); joint 2 sits elsewhere.
        let pre = [BOS, CLS_NONE, 1, 2, 3, 1, 2, 3, 9, 9, 9, BRANCH];
        let mut g = Grammar::from_prefix(10, &pre).unwrap();
        for t in [1, 2, 3] {
            g.advance(t).unwrap();
        }
        let m = g.allowed();
        assert!(m.contains(ALT) && m.contains(0) && m.len() == 257);
        g.advance(ALT).unwrap();
        assert!(!g.allowed().contains(ALT));
        assert_eq!(g.advance(ALT), Err(GrammarError::NoMoreAlternatives(2)));
        for t in [5, 5, 5] {
            g.advance(t).unwrap();
        }
        assert_eq!(g.joints()[3].parent, Some(1));
        // A cell with one joint has no alternative.
        let mut g = Grammar::from_prefix(10, &pre).unwrap();
        for t in [9, 9, 9] {
            g.advance(t).unwrap();
        }
        assert!(!g.allowed().contains(ALT));
        assert_eq!(g.advance(ALT), Err(GrammarError::NoMoreAlternatives(1)));
        // Nowhere else.
        let g = Grammar::from_prefix(10, &pre[..11]).unwrap();
        assert!(!g.allowed().contains(ALT));
        assert!(!Grammar::from_prefix(10, &pre)
            .unwrap()
            .allowed()
            .contains(ALT));
        assert!(Grammar::from_prefix(
            10,
            &[BOS, CLS_NONE, 1, 2, 3, 1, 2, 3, BRANCH, 1, 2, 3, 4, ALT]
        )
        .is_err());
        // Lenient: an empty cell snaps to the nearest joint, and <alt> walks that joint's cell.
        let mut g = Grammar::lenient(10);
        for t in pre.iter().copied().chain([1, 2, 4, ALT, 7, 7, 7, EOS]) {
            g.advance(t).unwrap();
        }
        assert_eq!(g.joints()[3].parent, Some(1));
        let d = detokenize(&[
            BOS, CLS_NONE, 1, 2, 3, 1, 2, 3, BRANCH, 1, 2, 3, ALT, 7, 7, 7, EOS,
        ])
        .unwrap();
        assert_eq!(d.bones[2].parent, Some(1));
    }

    #[test]
    fn hand_blocks_go_to_the_nearer_hand_then_the_other() {
        let m = match_mixamo(&synthetic_mixamo(true, true)).unwrap();
        let t = tokenize(&m).unwrap();
        let g = Grammar::from_prefix(m.len(), &t).unwrap();
        let j = g.joints();
        assert_eq!(j[BODY_BONES].slot, Some(TemplateSlot::Hand(Side::Left, 0)));
        assert_eq!(j[BODY_BONES].parent, Some(LEFT_HAND));
        assert_eq!(
            j[BODY_BONES + HAND_BONES].slot,
            Some(TemplateSlot::Hand(Side::Right, 0))
        );
        assert_eq!(j[BODY_BONES + HAND_BONES].parent, Some(RIGHT_HAND));
        assert_eq!(
            j[BODY_BONES + HAND_BONES + 1].parent,
            Some(BODY_BONES + HAND_BONES)
        );
    }

    #[test]
    fn masks_and_logits() {
        let g = Grammar::from_prefix(4, &[BOS, CLS_NONE, 1, 2, 3]).unwrap();
        let mut logits = vec![0.5f32; VOCAB_SIZE + 8];
        g.mask_logits(&mut logits);
        let kept: Vec<usize> = (0..logits.len())
            .filter(|&i| logits[i].is_finite())
            .collect();
        let m = g.allowed();
        assert_eq!(kept, m.iter().map(|t| t as usize).collect::<Vec<_>>());
        assert!(m.contains(EOS) && m.contains(BRANCH) && m.contains(200) && !m.contains(PAD));
        let mut flags = vec![true; VOCAB_SIZE + 2];
        g.allowed_into(&mut flags);
        assert_eq!(flags.iter().filter(|&&b| b).count(), m.len());
        assert!(!flags[VOCAB_SIZE]);
        assert!(format!("{m:?}").contains("<eos>"));
    }
}
