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
