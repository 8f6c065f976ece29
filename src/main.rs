//! The `illumnet` command: a thin layer over the library (see `cli`).

mod cli;

/// mimalloc keeps freed memory for reuse where the system allocator maps
/// and unmaps every large vector: a sequence build allocates and frees
/// hundreds of MB (per-pair link lists, the link table, delta blocks), and
/// the page faults of fresh memory were a fifth of its time.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// `mi_option_purge_delay` (`mimalloc.h`, v2 and v3): how long freed memory
/// is kept before it is returned to the OS; -1 keeps it for the process's
/// lifetime, which suits a command that runs one job and exits (peak RSS is
/// unchanged: freed memory is reused, not added to).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

fn main() -> std::process::ExitCode {
    // SAFETY: sets a plain integer option; called before any thread starts.
    unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1) };
    cli::main()
}
