//! In-process wake-ups for job changes. The store holds the events; this only tells
//! waiting SSE streams and idle workers to look now instead of at their next poll. In
//! cluster mode a change made by another replica is seen at the next poll instead.
//!
//! Both wake-ups are targeted. A change wakes only the streams watching that job: one
//! channel for all jobs woke every open stream at every event of every job (at 32
//! clients 32 wake-ups per event, each to compare an id and sleep again), a cost that
//! grows with the square of the clients. A queued job wakes one idle worker: waking them
//! all sent each of them to try the claim, a write transaction, and all but one found
//! nothing (ten claim statements a job at four clients).

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use tokio::sync::{watch, Notify};

#[derive(Clone, Default)]
pub struct Notifier {
    inner: Arc<Inner>,
}

#[derive(Default)]
struct Inner {
    /// Watched jobs: a change counter, and how many watches share it.
    jobs: Mutex<HashMap<String, (watch::Sender<u64>, usize)>>,
    /// One permit per queued job for an idle worker (at most one kept while none waits:
    /// busy workers look for the next job without being told).
    queued: Notify,
}

impl Notifier {
    /// Job `id` has a new event.
    pub fn changed(&self, id: &str) {
        let jobs = self.inner.jobs.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((tx, _)) = jobs.get(id) {
            tx.send_modify(|n| *n = n.wrapping_add(1));
        }
    }

    /// A job was queued (or re-queued): one idle worker looks.
    pub fn queued(&self) {
        self.inner.queued.notify_one();
    }

    /// Waits for [`Notifier::queued`] (or the permit it left while no worker waited).
    pub async fn next_queued(&self) {
        self.inner.queued.notified().await;
    }

    /// Wake-ups for job `id`'s changes from now on. Watch before reading the store: a
    /// change between the read and the wait then still wakes it.
    pub fn watch(&self, id: &str) -> JobWatch {
        let mut jobs = self.inner.jobs.lock().unwrap_or_else(|e| e.into_inner());
        let (tx, watchers) = jobs
            .entry(id.to_string())
            .or_insert_with(|| (watch::channel(0).0, 0));
        *watchers += 1;
        JobWatch {
            rx: tx.subscribe(),
            id: id.to_string(),
            notifier: self.clone(),
        }
    }

    #[cfg(test)]
    fn watched(&self) -> usize {
        self.inner.jobs.lock().unwrap().len()
    }
}

/// One watcher of a job's changes; the job stops being watched when the last one drops.
pub struct JobWatch {
    rx: watch::Receiver<u64>,
    id: String,
    notifier: Notifier,
}

impl JobWatch {
    /// Returns once the job changed since the watch began or this last returned.
    pub async fn changed(&mut self) {
        // The sender lives in the map while this watch does, so this never errs; if it
        // did, waiting for ever leaves the caller's poll to notice changes.
        if self.rx.changed().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

impl Drop for JobWatch {
    fn drop(&mut self) {
        let mut jobs = self
            .notifier
            .inner
            .jobs
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        if let Some((_, watchers)) = jobs.get_mut(&self.id) {
            *watchers -= 1;
            if *watchers == 0 {
                jobs.remove(&self.id);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;
    use tokio::time::timeout;

    const SHORT: Duration = Duration::from_millis(50);

    #[tokio::test]
    async fn a_watch_wakes_for_its_job_only_and_misses_nothing() {
        let n = Notifier::default();
        let mut a = n.watch("a");
        n.changed("b");
        assert!(
            timeout(SHORT, a.changed()).await.is_err(),
            "b's change woke a"
        );
        // A change before the wait (between a store read and the wait) still wakes it.
        n.changed("a");
        assert!(timeout(SHORT, a.changed()).await.is_ok());
        assert!(
            timeout(SHORT, a.changed()).await.is_err(),
            "woke twice for one change"
        );
        // Two watchers of one job both wake.
        let mut a2 = n.watch("a");
        n.changed("a");
        assert!(timeout(SHORT, a.changed()).await.is_ok());
        assert!(timeout(SHORT, a2.changed()).await.is_ok());
    }

    #[tokio::test]
    async fn a_job_is_forgotten_when_its_last_watch_drops() {
        let n = Notifier::default();
        let (a, a2, b) = (n.watch("a"), n.watch("a"), n.watch("b"));
        assert_eq!(n.watched(), 2);
        drop(a);
        assert_eq!(n.watched(), 2);
        drop(a2);
        drop(b);
        assert_eq!(n.watched(), 0);
        n.changed("a");
        assert_eq!(n.watched(), 0, "a change to an unwatched job keeps nothing");
    }

    #[tokio::test]
    async fn a_queued_job_wakes_one_idle_worker() {
        let n = Notifier::default();
        let woken = Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let workers: Vec<_> = (0..4)
            .map(|_| {
                let (n, woken) = (n.clone(), woken.clone());
                tokio::spawn(async move {
                    n.next_queued().await;
                    woken.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                })
            })
            .collect();
        tokio::time::sleep(SHORT).await;
        n.queued();
        tokio::time::sleep(SHORT).await;
        assert_eq!(woken.load(std::sync::atomic::Ordering::SeqCst), 1);
        n.queued();
        n.queued();
        tokio::time::sleep(SHORT).await;
        assert_eq!(woken.load(std::sync::atomic::Ordering::SeqCst), 3);
        for w in workers {
            w.abort();
        }
        // With no worker waiting, the job leaves a permit for the next one that looks.
        let n = Notifier::default();
        n.queued();
        assert!(timeout(SHORT, n.next_queued()).await.is_ok());
    }
}
