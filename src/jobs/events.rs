//! In-process wake-ups for job changes. The store holds the events; this only tells
//! waiting SSE streams and idle workers to look now instead of at their next poll. In
//! cluster mode a change made by another replica is seen at the next poll instead.

use tokio::sync::broadcast;

#[derive(Clone)]
pub struct Notifier {
    changed: broadcast::Sender<String>,
    queued: broadcast::Sender<()>,
}

impl Default for Notifier {
    fn default() -> Self {
        Notifier {
            // Lagging receivers only miss wake-ups, never events: they re-read the store.
            changed: broadcast::channel(1024).0,
            queued: broadcast::channel(64).0,
        }
    }
}

impl Notifier {
    /// Job `id` has a new event.
    pub fn changed(&self, id: &str) {
        let _ = self.changed.send(id.to_string());
    }

    /// A job was queued (or re-queued).
    pub fn queued(&self) {
        let _ = self.queued.send(());
    }

    pub fn subscribe_changes(&self) -> broadcast::Receiver<String> {
        self.changed.subscribe()
    }

    pub fn subscribe_queue(&self) -> broadcast::Receiver<()> {
        self.queued.subscribe()
    }
}
