//! `retain_freed_memory` in a process of its own (it changes the process's allocator).

/// Minor page faults of the calling thread so far.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn thread_faults() -> i64 {
    // SAFETY: getrusage writes into the zeroed struct we own.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `u` is a valid, writable rusage.
    assert_eq!(unsafe { libc::getrusage(libc::RUSAGE_THREAD, &mut u) }, 0);
    u.ru_minflt
}

/// Faults of allocating, filling and freeing a buffer of `bytes`.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn faults_of_one_buffer(bytes: usize) -> i64 {
    let before = thread_faults();
    let v = std::hint::black_box(vec![7u8; bytes]);
    assert_eq!(v[bytes - 1], 7);
    drop(v);
    thread_faults() - before
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[test]
fn a_freed_frame_buffer_is_reused_without_faulting_its_pages_in_again() {
    const BYTES: usize = 12 << 20; // a few 640×480 f32 planes
    let pages = (BYTES / 4096) as i64;
    // glibc's defaults: the first buffer of this size is mapped and unmapped, the second
    // comes from a grown heap; both fault every page in.
    let untuned = [faults_of_one_buffer(BYTES), faults_of_one_buffer(BYTES)];
    assert!(
        untuned.iter().all(|f| *f > pages / 2),
        "{untuned:?} faults for {pages} pages"
    );
    assert!(dynapix::bench::retain_freed_memory());
    // After the change, a buffer of a new size is faulted in once and then reused.
    let size = BYTES + (2 << 20);
    faults_of_one_buffer(size);
    for _ in 0..3 {
        let tuned = faults_of_one_buffer(size);
        assert!(tuned < pages / 20, "{tuned} faults for {pages} pages");
    }
}
