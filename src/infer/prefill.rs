//! Prefill: the per-job model work before a job can join the decode batch. The inference
//! thread runs it for the jobs that fit the batch's room, as one call; the submitting
//! threads have already encoded their points.
//!
//! (A separate prefill thread with its own sessions was measured on the 2-core machine:
//! 331–332 jobs/min at 32 clients against 338–345 without it. Both cores are already busy
//! under load, so overlapping prefill with decode only moved work between threads.)

use super::backend::{Job, Metrics};
use super::kv::KvCache;
use super::model::SkeletonModel;
use super::InferError;
use ndarray::{Array1, Array2, Array3, Axis};
use std::sync::Arc;
use std::time::Instant;

/// A job whose prefill has run: its first-token logits and which row of the batch's
/// prefill cache is its own (jobs with the same mesh and prompt share a row).
pub(super) struct Ready {
    pub(super) job: Job,
    pub(super) logits: Array1<f32>,
    pub(super) row: usize,
}

/// The jobs of one prefill call and the cache rows they will copy from.
pub(super) struct Prepared {
    pub(super) ready: Vec<Ready>,
    pub(super) cache: Arc<KvCache>,
}

/// Prefills `jobs` (encoded by their submitters) as one batch. On error the jobs come
/// back with it.
pub(super) fn prepare(
    model: &mut SkeletonModel,
    metrics: &Metrics,
    jobs: Vec<Job>,
) -> Result<Prepared, (Vec<Job>, InferError)> {
    let Some(prefixes) = jobs
        .iter()
        .map(|j| j.prefix.clone())
        .collect::<Option<Vec<_>>>()
    else {
        let e = InferError::run("prefill", "a job reached the inference thread unencoded");
        return Err((jobs, e));
    };
    // A job's candidates share the mesh (one prefix) and the prompt, so their prefills
    // are the same: run each distinct row once and let the others copy it. Prefill is the
    // costliest call per row (every prefix position), so best-of-N would otherwise pay N
    // times for one result.
    let mut distinct: Vec<usize> = Vec::with_capacity(jobs.len());
    let of_row: Vec<usize> = (0..jobs.len())
        .map(|j| {
            let same = |&u: &usize| {
                Arc::ptr_eq(&prefixes[u], &prefixes[j]) && jobs[u].prompt == jobs[j].prompt
            };
            distinct.iter().position(same).unwrap_or_else(|| {
                distinct.push(j);
                distinct.len() - 1
            })
        })
        .collect();
    let info = model.info();
    let mut stacked = Array3::<f32>::zeros((distinct.len(), info.n_latents, info.d_model));
    for (r, &j) in distinct.iter().enumerate() {
        stacked.index_axis_mut(Axis(0), r).assign(&prefixes[j]);
    }
    let prompts: Vec<&[u32]> = distinct
        .iter()
        .map(|&j| jobs[j].prompt.as_slice())
        .collect();
    let t = Instant::now();
    let res = model.prefill(&stacked, &prompts);
    Metrics::add_time(&metrics.prefill_ns, t);
    Metrics::add(&metrics.prefill_calls, 1);
    Metrics::add(&metrics.prefill_rows, distinct.len() as u64);
    let (logits, cache): (Array2<f32>, KvCache) = match res {
        Ok(x) => x,
        Err(e) => return Err((jobs, e)),
    };
    let ready = jobs
        .into_iter()
        .zip(of_row)
        .map(|(job, row)| Ready {
            job,
            logits: logits.row(row).to_owned(),
            row,
        })
        .collect();
    Ok(Prepared {
        ready,
        cache: Arc::new(cache),
    })
}
