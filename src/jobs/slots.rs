//! A counting semaphore for the CPU-heavy stages of jobs (skinning and export).
//!
//! Workers decide how many jobs are in flight, and so how many skeleton candidates share
//! each decode batch on the inference thread: the more, the cheaper each token. Every
//! in-flight job also skins on a worker thread; more skinnings at once than cores only
//! add memory and switches, so `permits` of them run at once, by default one per core.
//! The decoder does not need a core kept for it: it runs at a lower priority
//! (`--decode-nice`), so under load its rows wait for each other and share steps, the
//! cheaper way to decode (README, "Service load"). A job may also take a spare slot
//! ([`CpuSlots::acquire_spare`]) to prepare its skinning while its skeleton decodes.

use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::Duration;

pub struct CpuSlots {
    state: Mutex<State>,
    freed: Condvar,
}

struct State {
    free: usize,
    /// Jobs blocked in [`CpuSlots::acquire`]: spare work leaves them the free slots.
    waiting: usize,
}

/// Holds a slot until dropped.
pub struct Slot<'a>(&'a CpuSlots);

impl Drop for Slot<'_> {
    fn drop(&mut self) {
        self.0.state.lock().unwrap_or_else(|e| e.into_inner()).free += 1;
        // All, not one: the one woken might be spare work that must leave the slot to a
        // waiting job, and that job would then sleep on until its next look.
        self.0.freed.notify_all();
    }
}

/// How often a waiting job looks whether it was canceled.
const CANCEL_CHECK: Duration = Duration::from_millis(100);

impl CpuSlots {
    /// At least one permit.
    pub fn new(permits: usize) -> CpuSlots {
        CpuSlots {
            state: Mutex::new(State {
                free: permits.max(1),
                waiting: 0,
            }),
            freed: Condvar::new(),
        }
    }

    /// One per core.
    pub fn default_permits() -> usize {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    }

    /// Wakes every waiting [`CpuSlots::acquire`] and [`CpuSlots::acquire_spare`] to look
    /// at its `canceled` or `give_up` again (they otherwise look when a slot is freed, or
    /// every 100 ms).
    pub fn wake_waiters(&self) {
        // Under the lock: a waiter is either before its look (and will see the change)
        // or already waiting (and is woken), never in between.
        let _state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        self.freed.notify_all();
    }

    /// Blocks until a slot is free; `None` when `canceled` turns true first.
    pub fn acquire(&self, canceled: impl Fn() -> bool) -> Option<Slot<'_>> {
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        state.waiting += 1;
        let slot = loop {
            if canceled() {
                break None;
            }
            if state.free > 0 {
                state.free -= 1;
                break Some(Slot(self));
            }
            state = self.wait(state);
        };
        state.waiting -= 1;
        slot
    }

    /// For work that only uses a core nobody needs (a job preparing ahead while its
    /// skeleton decodes): blocks until more slots are free than jobs wait in
    /// [`CpuSlots::acquire`], so it never delays one; `None` when `give_up` turns true
    /// first.
    pub fn acquire_spare(&self, give_up: impl Fn() -> bool) -> Option<Slot<'_>> {
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        loop {
            if give_up() {
                return None;
            }
            if state.free > state.waiting {
                state.free -= 1;
                return Some(Slot(self));
            }
            state = self.wait(state);
        }
    }

    fn wait<'a>(&self, state: MutexGuard<'a, State>) -> MutexGuard<'a, State> {
        self.freed
            .wait_timeout(state, CANCEL_CHECK)
            .unwrap_or_else(|e| e.into_inner())
            .0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Arc;

    #[test]
    fn never_more_holders_than_permits() {
        let slots = Arc::new(CpuSlots::new(2));
        let (now, most) = (Arc::new(AtomicUsize::new(0)), Arc::new(AtomicUsize::new(0)));
        let threads: Vec<_> = (0..8)
            .map(|_| {
                let (slots, now, most) = (slots.clone(), now.clone(), most.clone());
                std::thread::spawn(move || {
                    for _ in 0..20 {
                        let _slot = slots.acquire(|| false).expect("not canceled");
                        let n = now.fetch_add(1, Ordering::SeqCst) + 1;
                        most.fetch_max(n, Ordering::SeqCst);
                        std::thread::sleep(Duration::from_micros(200));
                        now.fetch_sub(1, Ordering::SeqCst);
                    }
                })
            })
            .collect();
        threads.into_iter().for_each(|t| t.join().unwrap());
        assert_eq!(most.load(Ordering::SeqCst), 2);
    }

    #[test]
    fn a_canceled_wait_gives_up() {
        let slots = CpuSlots::new(1);
        let _held = slots.acquire(|| false).unwrap();
        assert!(slots.acquire(|| true).is_none());
    }

    #[test]
    fn spare_work_leaves_free_slots_to_waiting_jobs() {
        let slots = CpuSlots::new(2);
        // One job blocked in `acquire`, as it counts itself.
        slots.state.lock().unwrap().waiting = 1;
        let looks = AtomicUsize::new(0);
        // Gives up at its second look, so a refusal shows as None instead of a hang.
        let give_up = || looks.fetch_add(1, Ordering::SeqCst) > 0;
        let spare = slots.acquire_spare(give_up);
        assert!(spare.is_some(), "two free, one job waiting: one is spare");
        looks.store(0, Ordering::SeqCst);
        assert!(
            slots.acquire_spare(give_up).is_none(),
            "one free, one job waiting: the slot is the job's"
        );
        slots.state.lock().unwrap().waiting = 0;
        looks.store(0, Ordering::SeqCst);
        assert!(
            slots.acquire_spare(give_up).is_some(),
            "nobody waits any more"
        );
    }

    #[test]
    fn a_freed_slot_reaches_the_waiting_job_then_spare_work() {
        let slots = CpuSlots::new(1);
        let held = slots.acquire(|| false).unwrap();
        std::thread::scope(|s| {
            let job = s.spawn(|| slots.acquire(|| false).is_some());
            while slots.state.lock().unwrap().waiting == 0 {
                std::thread::yield_now();
            }
            let spare = s.spawn(|| slots.acquire_spare(|| false).is_some());
            drop(held);
            assert!(job.join().unwrap());
            // The job's slot came back (its closure dropped it): now it is spare.
            assert!(spare.join().unwrap());
        });
    }

    #[test]
    fn woken_waiters_give_up_or_wait_on_as_their_condition_says() {
        use std::sync::atomic::AtomicBool;
        let slots = CpuSlots::new(1);
        let done = AtomicBool::new(false);
        let held = slots.acquire(|| false).unwrap();
        std::thread::scope(|s| {
            // A job's early preparation: gives up once its skeleton is done.
            let early = s.spawn(|| slots.acquire(|| done.load(Ordering::SeqCst)).is_some());
            // A job waiting to skin: never gives up.
            let skinning = s.spawn(|| slots.acquire(|| false).is_some());
            std::thread::sleep(Duration::from_millis(20));
            done.store(true, Ordering::SeqCst);
            slots.wake_waiters();
            assert!(
                !early.join().unwrap(),
                "the early wait gives up without a slot"
            );
            // The slot, freed now, goes to the one still waiting.
            drop(held);
            assert!(skinning.join().unwrap());
        });
        assert!(slots.acquire(|| false).is_some(), "the slot came back");
    }
}
