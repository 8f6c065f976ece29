//! `render --mpi`: the processes of an MPI job (launched by Open MPI's
//! `mpirun`, on a host or inside a Slurm allocation) as one distribution's team (`illumnet::distribute::Team`),
//! through the `mpi` crate on the system's MPI (Open MPI on Debian). Built
//! with the `mpi` feature only; without it `--mpi` is refused with how to
//! get it.
//!
//! Failure: a member that fails (an unreadable archive, a refused frame)
//! ends the whole job with `MPI_Abort`, never leaving the others waiting
//! in a collective; a member killed from outside ends it too (the
//! launcher's rule, Open MPI's and Slurm's defaults). Images are written
//! by member 0 after the frame's last collective, through the
//! temporary-file-and-rename path: a job that dies writes no image.

/// The MPI job this process is a member of.
#[cfg(feature = "mpi")]
pub struct MpiTeam {
    world: mpi::topology::SimpleCommunicator,
    /// Kept until the team is dropped: dropping it finalises MPI.
    _universe: mpi::environment::Universe,
}

// SAFETY: MPI is initialised with `Threading::Serialized` (checked in
// `MpiTeam::join`), and the distribution calls a team's methods only from
// the one thread that drives its iteration (`distribute::Team`'s
// contract), never from two threads at once: the communicator handle is
// never used concurrently.
#[cfg(feature = "mpi")]
unsafe impl Sync for MpiTeam {}

/// Elements one collective moves at most: MPI counts are 32-bit.
#[cfg(feature = "mpi")]
const MOST_PER_CALL: usize = 1 << 30;

#[cfg(feature = "mpi")]
impl MpiTeam {
    /// Joins the MPI job this process was launched in (a job of one
    /// process when launched alone).
    pub fn join() -> anyhow::Result<Self> {
        use mpi::Threading;
        let Some((universe, level)) = mpi::initialize_with_threading(Threading::Serialized) else {
            anyhow::bail!("--mpi: MPI was already initialised in this process");
        };
        if level < Threading::Serialized {
            anyhow::bail!(
                "--mpi: this MPI library gives thread level {level:?}; the render needs Serialized (calls from \
                 one thread at a time while its workers compute)"
            );
        }
        Ok(Self { world: universe.world(), _universe: universe })
    }

    /// Ends every process of the job with exit code `code` (after this
    /// one has said why): a member that fails must not leave the others
    /// waiting.
    pub fn abort(&self, code: u8) -> ! {
        use mpi::traits::Communicator;
        self.world.abort(code as i32)
    }

    /// The all-gather of `data` by `parts`, in calls of at most
    /// [`MOST_PER_CALL`] elements.
    fn share<T: mpi::traits::Equivalence + Copy>(&self, data: &mut [T], parts: &[std::ops::Range<usize>]) {
        use mpi::datatype::PartitionMut;
        use mpi::traits::{Communicator, CommunicatorCollectives};
        let rank = self.world.rank() as usize;
        let mut start = 0;
        while start < data.len() {
            let end = (start + MOST_PER_CALL).min(data.len());
            // Each member's part of data[start..end], relative to start.
            let cut: Vec<std::ops::Range<usize>> =
                parts.iter().map(|p| p.start.clamp(start, end) - start..p.end.clamp(start, end) - start).collect();
            let counts: Vec<i32> = cut.iter().map(|c| c.len() as i32).collect();
            let displs: Vec<i32> = cut.iter().map(|c| c.start as i32).collect();
            let chunk = &mut data[start..end];
            let mine: Vec<T> = chunk[cut[rank].clone()].to_vec();
            let mut into = PartitionMut::new(chunk, counts, displs);
            self.world.all_gather_varcount_into(&mine[..], &mut into);
            start = end;
        }
    }
}

#[cfg(feature = "mpi")]
impl illumnet::distribute::Team for MpiTeam {
    fn rank(&self) -> usize {
        use mpi::traits::Communicator;
        self.world.rank() as usize
    }

    fn size(&self) -> usize {
        use mpi::traits::Communicator;
        self.world.size() as usize
    }

    fn share_f32(&self, data: &mut [f32], parts: &[std::ops::Range<usize>]) {
        self.share(data, parts)
    }

    fn share_f64(&self, data: &mut [f64], parts: &[std::ops::Range<usize>]) {
        self.share(data, parts)
    }

    fn max_u8(&self, data: &mut [u8]) {
        use mpi::collective::SystemOperation;
        use mpi::traits::CommunicatorCollectives;
        for chunk in data.chunks_mut(MOST_PER_CALL) {
            let mine = chunk.to_vec();
            self.world.all_reduce_into(&mine[..], chunk, SystemOperation::max());
        }
    }

    fn leader_says(&self, value: bool) -> bool {
        use mpi::traits::{Communicator, Root};
        let mut v = value as u8;
        self.world.process_at_rank(0).broadcast_into(&mut v);
        v != 0
    }
}

/// Runs `f` as a member of the MPI job this process was launched in,
/// given the job as its team and the number of its ranks on this node
/// (who share its memory). A member's error ends the whole job with its
/// exit code, and a panic with 101, after saying which member failed and
/// why: never a rank left waiting in a collective (or in `MPI_Finalize`,
/// which unwinding would reach).
#[cfg(feature = "mpi")]
pub fn in_job(f: impl FnOnce(&dyn illumnet::distribute::Team, usize) -> anyhow::Result<()>) -> anyhow::Result<()> {
    use illumnet::distribute::Team;
    use mpi::traits::{Communicator, CommunicatorCollectives};
    let team = MpiTeam::join()?;
    let on_this_node = team.world.split_shared(team.world.rank()).size().max(1) as usize;
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(&team, on_this_node)));
    let ending = |why: String, code: u8| -> ! {
        eprintln!("illumnet: error: MPI rank {} of {}: {why}", team.rank(), team.size());
        eprintln!(
            "illumnet: MPI rank {}: ending the whole job (MPI_Abort): the frame being solved is not written",
            team.rank()
        );
        team.abort(code)
    };
    match result {
        Err(_) if team.size() > 1 => ending("the render panicked (a bug: please report it)".into(), 101),
        Err(panic) => std::panic::resume_unwind(panic),
        Ok(Err(e)) if team.size() > 1 => ending(super::report(&e), super::exit::code(&e)),
        Ok(result) => {
            // Every rank leaves together: none is finalised while another
            // still answers a collective.
            team.world.barrier();
            result
        }
    }
}

/// Without the `mpi` feature: `--mpi` is refused, saying how to get it.
#[cfg(not(feature = "mpi"))]
pub fn in_job(_: impl FnOnce(&dyn illumnet::distribute::Team, usize) -> anyhow::Result<()>) -> anyhow::Result<()> {
    Err(anyhow::Error::new(super::exit::BadInput(
        "--mpi: this illumnet was built without MPI; build it with `cargo build --release --features mpi` \
         (which needs an MPI library and libclang: `bash tools/mpi/install.sh` installs Debian's Open MPI)"
            .into(),
    )))
}
