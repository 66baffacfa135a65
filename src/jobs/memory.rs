//! Giving freed memory back to the system after a large job.
//!
//! glibc's allocator keeps the pages of freed blocks in its arenas, so one job on a
//! JSON-heavy upload (a million accessors, a huge `extras` array) left the process at
//! 1.4-2.2 GB for good, long after the job was done. The pages are not lost, only kept
//! for reuse, but a container's memory limit counts them. `malloc_trim(0)` walks every
//! arena and returns their free pages; it costs about a millisecond per hundred megabytes
//! of heap and holds each arena's lock only while that arena is walked, so running it
//! beside other jobs is safe.

/// Returns freed heap pages to the system (glibc only; a no-op elsewhere). Blocking:
/// call it from a blocking thread, never from a runtime worker.
pub fn give_back() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only inspects and releases the allocator's own free lists.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// [`give_back`] on a blocking thread, awaited: after the job's buffers are dropped.
pub async fn give_back_async() {
    let _ = tokio::task::spawn_blocking(give_back).await;
}
