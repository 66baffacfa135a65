//! The `rigserve` command line. `anyhow` lives here only: the library reports typed
//! errors, and this is the one place they become messages for a person.

mod cli;

use clap::Parser;

/// Keeps freed memory in the process instead of handing it back to the kernel.
///
/// The decoder allocates and frees its KV cache tensors (megabytes each) every step. With
/// glibc's defaults, blocks that size are mmap'd and unmapped each time, or the heap top is
/// trimmed, so every step page-faults fresh zeroed pages back in: with 32 clients that was a
/// third of the inference thread's time. Served from the heap and kept, they are reused.
/// The cost is that the resident size stays at its high-water mark.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn keep_freed_memory() {
    // 32 MiB is the largest mmap threshold glibc accepts on 64-bit.
    const MMAP_THRESHOLD: libc::c_int = 32 << 20;
    const TRIM_THRESHOLD: libc::c_int = 1 << 30;
    // SAFETY: mallopt only sets allocator parameters; called before any thread starts.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD);
        libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn keep_freed_memory() {}

/// A command whose output is piped into `head` ends quietly when the reader goes away,
/// as other command-line tools do, instead of panicking in `println!` on the broken pipe.
/// Not for `serve`: there a client that hangs up must not end the process.
#[cfg(unix)]
fn die_quietly_on_broken_pipe() {
    // SAFETY: restores the default disposition before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

#[cfg(not(unix))]
fn die_quietly_on_broken_pipe() {}

fn main() -> std::process::ExitCode {
    keep_freed_memory();
    let args = cli::Cli::parse();
    if !matches!(args.command, cli::Command::Serve(_)) {
        die_quietly_on_broken_pipe();
    }
    match cli::run(args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
