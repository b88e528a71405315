//! How a long-running process (the daemon, a relay) keeps its resident set
//! flat under glibc's malloc. A show runs for hours, and now and then it
//! needs tens of megabytes briefly: an export builds a whole stage and a
//! take's frames, a director brings in a picture. With glibc's defaults the
//! memory those freed stayed with the process: each thread allocates from
//! an arena of its own (up to eight per core) that keeps what it freed, and
//! after a large block is freed the threshold for serving blocks straight
//! from the system rises, so the next large blocks come from (and stay in)
//! the arenas too. `puppetry soak` saw the daemon's resident set step up at
//! every export and never come down.

/// Two arenas, blocks of 128 KiB and more straight from the system (and
/// back to it when freed), and the top of the heap given back past 128
/// KiB. Call once, early, in a process that serves for a long time: the
/// settings are the process's. Does nothing off glibc.
pub fn for_a_long_run() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets the allocator's own parameters; it takes
    // the allocator's lock, so other threads may be allocating meanwhile.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, 2);
        // Setting it also stops glibc from raising it after frees.
        libc::mallopt(libc::M_MMAP_THRESHOLD, 128 * 1024);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 128 * 1024);
    }
}

/// Gives the memory freed so far back to the system, from every arena
/// (not only the top of each heap): after a burst such as an export.
pub(crate) fn give_back_freed() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only walks the allocator's own free lists.
    unsafe {
        libc::malloc_trim(0);
    }
}
