//! The inference thread's CPU priority.
//!
//! On a small machine the decoder and the jobs' own CPU work (loading, skinning,
//! export) share the cores. A decode step costs about as much for eight rows as for two
//! (`rigserve bench decode`), so under load it pays to let the jobs' work go first: rows
//! that arrive while the decoder waits for a core join the next step instead of each
//! job's best-of-N decoding alone. A lower priority (a higher nice value) does that and
//! costs nothing when a core is free, which is the case whenever the machine is not full.

/// Sets the calling thread's nice value (-20 highest, 19 lowest; raising it above the
/// process's needs no privilege, lowering it does).
#[cfg(target_os = "linux")]
pub fn set_thread_nice(nice: i32) -> std::io::Result<()> {
    // SAFETY: neither call takes a pointer; on Linux PRIO_PROCESS with a thread id
    // applies to that thread alone.
    let r = unsafe { libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, nice) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(not(target_os = "linux"))]
pub fn set_thread_nice(_nice: i32) -> std::io::Result<()> {
    Err(std::io::Error::other(
        "thread priorities are set on Linux only",
    ))
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    fn own_nice() -> i32 {
        // SAFETY: no pointers; the errno dance is not needed for a thread that exists.
        unsafe { libc::getpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t) }
    }

    #[test]
    fn only_the_calling_thread_is_lowered() {
        let before = own_nice();
        let inside = std::thread::spawn(|| {
            set_thread_nice(19).unwrap();
            own_nice()
        })
        .join()
        .unwrap();
        assert_eq!(inside, 19);
        assert_eq!(own_nice(), before, "the test thread keeps its priority");
    }
}
