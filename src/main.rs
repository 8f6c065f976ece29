//! The `illumnet` command: a thin layer over the library (see `cli`).

mod cli;

/// mimalloc keeps freed memory for reuse where the system allocator maps
/// and unmaps every large vector: a sequence build allocates and frees
/// hundreds of MB (per-pair link lists, the link table, delta blocks), and
/// the page faults of fresh memory were a fifth of its time. It is built
/// to commit its arenas on demand (`.cargo/config.toml`), which spares the
/// zeroing of huge pages the build never fills.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> std::process::ExitCode {
    cli::main()
}

unsafe extern "C" {
    /// mimalloc's collection of freed memory (`mimalloc.h`), from the
    /// static library the `mimalloc` crate links.
    fn mi_collect(force: bool);
}

/// Gives the memory freed so far back to the system: mimalloc keeps it
/// for reuse, where it would count in the next stage's peak (`demo`).
pub(crate) fn return_freed_memory() {
    // SAFETY: a plain call into the linked, initialised allocator; any
    // thread may make it at any time.
    unsafe { mi_collect(true) }
}

#[cfg(test)]
mod tests {
    unsafe extern "C" {
        /// mimalloc's option getter (`mimalloc.h`), from the static library
        /// the `mimalloc` crate links.
        fn mi_option_get(option: std::ffi::c_int) -> std::ffi::c_long;
    }

    /// `mi_option_arena_eager_commit` in mimalloc's option enum (v2 and v3).
    const ARENA_EAGER_COMMIT: std::ffi::c_int = 4;

    #[test]
    fn mimalloc_commits_its_arenas_on_demand() {
        // SAFETY: a plain getter of a C library that is linked and
        // initialised (this process allocates through it).
        let value = unsafe { mi_option_get(ARENA_EAGER_COMMIT) };
        assert_eq!(
            value, 0,
            "mimalloc was built without .cargo/config.toml's CFLAGS (a CFLAGS in the environment replaces it, \
             and `cargo install` does not read it): builds fault in huge pages they never fill"
        );
    }
}
