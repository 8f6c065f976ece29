//! The address ranges of the archives mapped by this process, kept where a
//! signal handler can read them: a file truncated under its mapping makes
//! the next read of a page past its new end fault with SIGBUS, and the
//! CLI's handler ([`fault_in`]) turns such a fault into an error message
//! and exit 5 instead of a crash. Lock-free atomics only, so that the
//! handler reads them async-signal-safely.

use std::sync::atomic::{AtomicU8, AtomicUsize, Ordering};

/// Archives mapped at once that a fault can be told for (more are mapped
/// but not recorded: a fault in them stays a crash).
const SLOTS: usize = 8;
/// Path bytes kept per mapping (longer paths are cut).
const PATH_BYTES: usize = 256;

struct Slot {
    /// 0 when free, else the mapping's first address.
    start: AtomicUsize,
    len: AtomicUsize,
    path_len: AtomicUsize,
    path: [AtomicU8; PATH_BYTES],
}

#[allow(clippy::declare_interior_mutable_const)]
const FREE: Slot = Slot {
    start: AtomicUsize::new(0),
    len: AtomicUsize::new(0),
    path_len: AtomicUsize::new(0),
    path: [const { AtomicU8::new(0) }; PATH_BYTES],
};

static MAPPED: [Slot; SLOTS] = [FREE; SLOTS];

/// A mapping recorded in [`MAPPED`]; dropped, it is forgotten again.
#[derive(Debug)]
pub(crate) struct Recorded(Option<usize>);

/// Records the mapping of `len` bytes at `start` of the file at `path`.
pub(crate) fn record(start: *const u8, len: usize, path: &std::path::Path) -> Recorded {
    let path = path.as_os_str().as_encoded_bytes();
    for (i, s) in MAPPED.iter().enumerate() {
        // Claimed with a placeholder length of 0 (matches no address) until
        // the path is written, then published with the real length.
        if s.start.compare_exchange(0, start as usize, Ordering::AcqRel, Ordering::Relaxed).is_ok() {
            let n = path.len().min(PATH_BYTES);
            for (d, &b) in s.path.iter().zip(&path[..n]) {
                d.store(b, Ordering::Relaxed);
            }
            s.path_len.store(n, Ordering::Relaxed);
            s.len.store(len, Ordering::Release);
            return Recorded(Some(i));
        }
    }
    Recorded(None)
}

impl Drop for Recorded {
    fn drop(&mut self) {
        if let Some(i) = self.0 {
            MAPPED[i].len.store(0, Ordering::Release);
            MAPPED[i].start.store(0, Ordering::Release);
        }
    }
}

/// Whether `addr` lies in a recorded mapping; if so, copies the start of
/// its file's path into `path` and returns its length. Async-signal-safe
/// (atomic loads only): made for a SIGBUS handler.
pub fn fault_in(addr: usize, path: &mut [u8]) -> Option<usize> {
    for s in &MAPPED {
        let len = s.len.load(Ordering::Acquire);
        let start = s.start.load(Ordering::Acquire);
        if start != 0 && addr >= start && addr - start < len {
            let n = s.path_len.load(Ordering::Relaxed).min(path.len());
            for (d, b) in path.iter_mut().zip(&s.path[..n]) {
                *d = b.load(Ordering::Relaxed);
            }
            return Some(n);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recorded_range_is_found_until_dropped() {
        let bytes = [0u8; 64];
        let mut path = [0u8; 32];
        let r = record(bytes.as_ptr(), 64, std::path::Path::new("a.inet"));
        let at = bytes.as_ptr() as usize;
        assert_eq!(fault_in(at + 63, &mut path), Some(6));
        assert_eq!(&path[..6], b"a.inet");
        assert_eq!(fault_in(at + 64, &mut path), None);
        drop(r);
        assert_eq!(fault_in(at, &mut path), None);
    }
}
