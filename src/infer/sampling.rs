//! Choosing the next token: grammar mask, length budget, then temperature / top-k / top-p
//! sampling (or greedy) from a per-item SplitMix64, so an item's tokens depend only on
//! its own logits and seed, never on what else shares its batch.

use crate::mesh::sample::SplitMix64;
use crate::rig::grammar::Grammar;
use crate::rig::tokenizer::{is_coord, BRANCH, EOS};

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SamplingParams {
    /// 0 (or less) means greedy: the highest logit, lowest id on ties.
    pub temperature: f32,
    /// Keep only the `top_k` most likely tokens; 0 keeps all.
    pub top_k: usize,
    /// Keep the smallest set of most likely tokens whose probability reaches `top_p`;
    /// 1 keeps all.
    pub top_p: f32,
    pub seed: u64,
}

impl Default for SamplingParams {
    fn default() -> Self {
        SamplingParams {
            temperature: 1.0,
            top_k: 0,
            top_p: 1.0,
            seed: 0,
        }
    }
}

impl SamplingParams {
    pub fn greedy() -> Self {
        SamplingParams {
            temperature: 0.0,
            ..Self::default()
        }
    }

    pub fn is_greedy(&self) -> bool {
        self.temperature <= 0.0 || self.temperature.is_nan()
    }

    pub(crate) fn validate(&self) -> Result<(), String> {
        if !self.temperature.is_finite() {
            return Err(format!("temperature {} is not finite", self.temperature));
        }
        if !(self.top_p > 0.0 && self.top_p <= 1.0) {
            return Err(format!("top_p {} is not in (0, 1]", self.top_p));
        }
        Ok(())
    }
}

/// One item's sampler: its parameters and its own random stream.
#[derive(Clone, Debug)]
pub struct Sampler {
    params: SamplingParams,
    /// State of a [`SplitMix64`] (which is neither `Clone` nor `Debug`).
    rng: u64,
}

impl Sampler {
    pub fn new(params: SamplingParams) -> Self {
        Sampler {
            params,
            rng: params.seed,
        }
    }

    pub fn params(&self) -> &SamplingParams {
        &self.params
    }

    fn next_f64(&mut self) -> f64 {
        let mut r = SplitMix64::new(self.rng);
        let x = r.next_f64();
        self.rng = r.0;
        x
    }

    /// Picks a token from `logits` where forbidden ids are −∞ (NaN counts as forbidden).
    /// `None` when no id is finite. Draws exactly one random number per non-greedy call,
    /// so the stream advances the same way whatever the logits are.
    pub fn sample(&mut self, logits: &[f32]) -> Option<u32> {
        let mut cand: Vec<(u32, f32)> = logits
            .iter()
            .enumerate()
            .filter(|(_, l)| l.is_finite())
            .map(|(i, &l)| (i as u32, l))
            .collect();
        if cand.is_empty() {
            return None;
        }
        if self.params.is_greedy() {
            return cand
                .iter()
                .fold(None::<(u32, f32)>, |best, &(i, l)| match best {
                    Some((_, bl)) if bl >= l => best,
                    _ => Some((i, l)),
                })
                .map(|(i, _)| i);
        }
        let u = self.next_f64();
        // Most likely first, ties by id: a total order, so the outcome of a draw is fully
        // determined. Only top-k / top-p need the order; plain sampling keeps id order.
        let order = |a: &(u32, f32), b: &(u32, f32)| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0));
        let k = self.params.top_k;
        if k > 0 && k < cand.len() {
            cand.select_nth_unstable_by(k - 1, order);
            cand.truncate(k);
        }
        if k > 0 || self.params.top_p < 1.0 {
            cand.sort_unstable_by(order);
        }
        let t = self.params.temperature as f64;
        let top = cand.iter().map(|c| c.1).fold(f32::NEG_INFINITY, f32::max) as f64;
        let mut probs: Vec<f64> = cand
            .iter()
            .map(|&(_, l)| ((l as f64 - top) / t).exp())
            .collect();
        let mut total: f64 = probs.iter().sum();
        if self.params.top_p < 1.0 {
            let want = self.params.top_p as f64 * total;
            let mut acc = 0.0;
            let mut keep = probs.len();
            for (k, p) in probs.iter().enumerate() {
                acc += p;
                if acc >= want {
                    keep = k + 1;
                    break;
                }
            }
            probs.truncate(keep);
            total = probs.iter().sum();
        }
        let target = u * total;
        let mut acc = 0.0;
        for (k, p) in probs.iter().enumerate() {
            acc += p;
            if target < acc {
                return Some(cand[k].0);
            }
        }
        Some(cand[probs.len() - 1].0)
    }
}

/// Most tokens one decision at a bone boundary can commit to before `<eos>` is reachable
/// again: `<mixamo:body>`, 22 joints × 3 coordinates, `<eos>`. Below this many remaining
/// tokens the budget has to be checked.
const BUDGET_HORIZON: usize = 1 + 22 * 3 + 1 + 4;

/// Tokens needed to reach `<eos>` from the grammar's state, taking the shortest way:
/// `<eos>` when allowed, else `<branch>` (after an opener it starts a new root, cheaper
/// than naming a parent), else a coordinate. `None` if the grammar is stuck.
pub fn completion_cost(grammar: &Grammar) -> Option<usize> {
    let mut g = grammar.clone();
    for n in 0..1024 {
        if g.is_done() {
            return Some(n);
        }
        let m = g.allowed();
        let t = if m.contains(EOS) {
            EOS
        } else if m.contains(BRANCH) {
            BRANCH
        } else {
            m.iter()
                .find(|&t| is_coord(t))
                .or_else(|| m.iter().next())?
        };
        g.advance(t).ok()?;
    }
    None
}

/// Masks `logits` (the model's width, which may differ from the tokenizer's) so the token
/// chosen is one the grammar allows and, with `remaining` tokens left including this one,
/// still leaves room to finish the sequence with `<eos>`. So a sequence decoded under it
/// always ends within its budget and always detokenizes.
///
/// With `ignore_eos` (benchmarks with forced lengths) `<eos>` is masked whenever anything
/// else is allowed and the budget is not enforced: the sequence is simply cut.
pub fn constrain_logits(grammar: &Grammar, remaining: usize, ignore_eos: bool, logits: &mut [f32]) {
    grammar.mask_logits(logits);
    for l in logits.iter_mut() {
        if l.is_nan() {
            *l = f32::NEG_INFINITY;
        }
    }
    if ignore_eos {
        let eos = EOS as usize;
        if eos < logits.len()
            && logits
                .iter()
                .enumerate()
                .any(|(i, l)| i != eos && l.is_finite())
        {
            logits[eos] = f32::NEG_INFINITY;
        }
        return;
    }
    if remaining > BUDGET_HORIZON {
        return;
    }
    // Every coordinate allowed in one state leads to completions of the same length, so
    // one stands for all of them; special tokens are checked one by one.
    let mut coord_ok = None;
    for (t, l) in logits.iter_mut().enumerate() {
        if !l.is_finite() {
            continue;
        }
        let tok = t as u32;
        let ok = if is_coord(tok) {
            *coord_ok.get_or_insert_with(|| fits(grammar, tok, remaining))
        } else {
            fits(grammar, tok, remaining)
        };
        if !ok {
            *l = f32::NEG_INFINITY;
        }
    }
}

fn fits(grammar: &Grammar, tok: u32, remaining: usize) -> bool {
    let mut g = grammar.clone();
    if g.advance(tok).is_err() {
        return false;
    }
    // This token plus its completion.
    completion_cost(&g).is_some_and(|c| c < remaining)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::tokenizer::{detokenize, BOS, CLS_NONE, VOCAB_SIZE};

    #[test]
    fn greedy_takes_highest_lowest_id_on_tie() {
        let mut s = Sampler::new(SamplingParams::greedy());
        assert_eq!(s.sample(&[0.0, 2.0, 2.0, f32::NEG_INFINITY]), Some(1));
        assert_eq!(s.sample(&[f32::NEG_INFINITY; 3]), None);
        assert_eq!(s.sample(&[f32::NAN, 1.0]), Some(1));
    }

    #[test]
    fn sampling_is_seeded_and_respects_top_k() {
        let logits: Vec<f32> = (0..50).map(|i| (i % 7) as f32 * 0.3).collect();
        let p = SamplingParams {
            temperature: 1.0,
            top_k: 3,
            top_p: 1.0,
            seed: 9,
        };
        let draw = |p| {
            let mut s = Sampler::new(p);
            (0..200)
                .map(|_| s.sample(&logits).unwrap())
                .collect::<Vec<_>>()
        };
        let a = draw(p);
        assert_eq!(a, draw(p));
        assert_ne!(a, draw(SamplingParams { seed: 10, ..p }));
        // top 3 by logit (ties by id): the three ids with i % 7 == 6 and lowest ids.
        let allowed = [6u32, 13, 20];
        assert!(a.iter().all(|t| allowed.contains(t)), "{a:?}");
    }

    #[test]
    fn top_p_keeps_the_head() {
        let mut logits = vec![0.0f32; 10];
        logits[4] = 10.0;
        let mut s = Sampler::new(SamplingParams {
            temperature: 1.0,
            top_k: 0,
            top_p: 0.5,
            seed: 1,
        });
        assert!((0..100).all(|_| s.sample(&logits) == Some(4)));
    }

    #[test]
    fn budget_forces_termination_and_narrow_vocab_works() {
        // A model one id short of the tokenizer's vocabulary (no <alt>): every id is
        // equally likely, and sequences must still end within budget and detokenize.
        for seed in 0..40u64 {
            let max_tokens = 6 + (seed as usize % 60);
            let mut g = Grammar::new(64);
            let mut toks = vec![BOS, CLS_NONE];
            for &t in &toks {
                g.advance(t).unwrap();
            }
            let mut s = Sampler::new(SamplingParams {
                temperature: 1.0,
                top_k: 0,
                top_p: 1.0,
                seed,
            });
            while !g.is_done() {
                assert!(toks.len() < max_tokens, "ran past budget");
                let mut logits = vec![0.0f32; VOCAB_SIZE - 1];
                constrain_logits(&g, max_tokens - toks.len(), false, &mut logits);
                let t = s.sample(&logits).expect("a token fits");
                g.advance(t).unwrap();
                toks.push(t);
            }
            detokenize(&toks).unwrap();
        }
    }

    #[test]
    fn completion_cost_of_fresh_prompt() {
        let g = Grammar::from_prefix(8, &[BOS, CLS_NONE]).unwrap();
        assert_eq!(completion_cost(&g), Some(4));
    }
}
