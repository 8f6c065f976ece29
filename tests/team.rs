//! A distribution shared by a team of processes (`distribute::Team`, what
//! `render --mpi` runs on): each member gathers over its own receivers'
//! link ends and the members exchange what their receivers got. Here the
//! members are threads exchanging through shared memory, so that the
//! partition itself (ranges, narrowed windows mapped and streamed, the
//! setup pass, warm-started frames, glossy tables) is held to one
//! process's light bit for bit in every test run; `tools/mpi/test.sh`
//! runs the same with Open MPI.

mod common;
use std::ops::Range;
use std::path::Path;
use std::sync::{Barrier, Mutex};

use illumnet::archive::Archive;
use illumnet::distribute::{DistributeOptions, Distributor, Lighting, Solution, Team};
use illumnet::progress::NoProgress;

/// What the members of a thread team share.
struct Hub {
    members: usize,
    barrier: Barrier,
    f32s: Mutex<Vec<f32>>,
    f64s: Mutex<Vec<f64>>,
    u8s: Mutex<Vec<u8>>,
    flag: Mutex<bool>,
}

/// One member of a thread team.
struct Member<'h> {
    hub: &'h Hub,
    rank: usize,
}

impl Member<'_> {
    /// The all-gather through `buf`: each member writes its part, all
    /// wait, each reads the others' parts, all wait again (so that no
    /// part is overwritten before everyone has read it).
    fn share<T: Copy + Default>(&self, buf: &Mutex<Vec<T>>, data: &mut [T], parts: &[Range<usize>]) {
        {
            let mut b = buf.lock().unwrap();
            if b.len() != data.len() {
                b.resize(data.len(), T::default());
            }
            let mine = parts[self.rank].clone();
            b[mine.clone()].copy_from_slice(&data[mine]);
        }
        self.hub.barrier.wait();
        {
            let b = buf.lock().unwrap();
            for (r, p) in parts.iter().enumerate() {
                if r != self.rank {
                    data[p.clone()].copy_from_slice(&b[p.clone()]);
                }
            }
        }
        self.hub.barrier.wait();
    }
}

impl Team for Member<'_> {
    fn rank(&self) -> usize {
        self.rank
    }
    fn size(&self) -> usize {
        self.hub.members
    }
    fn share_f32(&self, data: &mut [f32], parts: &[Range<usize>]) {
        self.share(&self.hub.f32s, data, parts)
    }
    fn share_f64(&self, data: &mut [f64], parts: &[Range<usize>]) {
        self.share(&self.hub.f64s, data, parts)
    }
    fn max_u8(&self, data: &mut [u8]) {
        {
            let mut b = self.hub.u8s.lock().unwrap();
            if b.len() != data.len() {
                *b = vec![0; data.len()];
            }
            for (b, d) in b.iter_mut().zip(data.iter()) {
                *b = (*b).max(*d);
            }
        }
        self.hub.barrier.wait();
        data.copy_from_slice(&self.hub.u8s.lock().unwrap());
        self.hub.barrier.wait();
        if self.rank == 0 {
            self.hub.u8s.lock().unwrap().clear();
        }
        self.hub.barrier.wait();
    }
    fn leader_says(&self, value: bool) -> bool {
        if self.rank == 0 {
            *self.hub.flag.lock().unwrap() = value;
        }
        self.hub.barrier.wait();
        let v = *self.hub.flag.lock().unwrap();
        self.hub.barrier.wait();
        v
    }
}

/// Every frame of `a`, each warm-started from the last, as one
/// distributor (in `team`, when given) does them; and the bytes it
/// received from the team.
fn solve_all(a: &Archive, team: Option<&dyn Team>) -> (Vec<Solution>, u64) {
    let v = a.view();
    let opts = DistributeOptions { tolerance: 1e-5, ..Default::default() };
    let d = Distributor::new_in(&v, &opts, &Lighting::from_view(&v), team).unwrap();
    let frames = v.sequence.map_or(1, |s| s.frames());
    let mut out: Vec<Solution> = Vec::new();
    for k in 0..frames {
        let s = d.frame(k, out.last(), &NoProgress).unwrap();
        out.push(s);
    }
    (out, d.exchange_totals().0)
}

/// Every member's solutions and bytes received, `members` threads each
/// opening `path` (streamed in windows of `window` ends, when given).
fn solve_in_team(path: &Path, members: usize, window: Option<usize>) -> Vec<(Vec<Solution>, u64)> {
    let hub = Hub {
        members,
        barrier: Barrier::new(members),
        f32s: Mutex::default(),
        f64s: Mutex::default(),
        u8s: Mutex::default(),
        flag: Mutex::default(),
    };
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..members)
            .map(|rank| {
                let hub = &hub;
                scope.spawn(move || {
                    let a = match window {
                        Some(w) => Archive::open_streamed(path, w).unwrap(),
                        None => Archive::open(path).unwrap(),
                    };
                    let member = Member { hub, rank };
                    solve_all(&a, Some(&member))
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    })
}

#[test]
fn a_team_of_any_size_gives_one_process_light_bit_for_bit() {
    let cases = common::coarse_scenes();
    for (name, h) in cases {
        let dir = tempfile::tempdir().unwrap();
        let path = common::write_scene(&common::scene_file(name), h, dir.path());
        let (want, none) = solve_all(&Archive::open(&path).unwrap(), None);
        assert_eq!(none, 0, "{name}: one process exchanges nothing");
        // Mapped with 1 to 4 members; streamed in windows of a few
        // hundred ends, whose boundaries fall anywhere in a member's range.
        for (members, window) in [(1, None), (2, None), (3, None), (4, None), (3, Some(300))] {
            let what = format!("{name}, {members} members, windows {window:?}");
            let got = solve_in_team(&path, members, window);
            for (rank, (solutions, received)) in got.iter().enumerate() {
                common::assert_same_light(&want, solutions, &format!("{what}, member {rank}"));
                assert_eq!(*received > 0, members > 1, "{what}, member {rank}: {received} bytes received");
            }
        }
        eprintln!("{name}: {} frames, {} iterations in frame 0", want.len(), want[0].balance.iterations);
    }
}
