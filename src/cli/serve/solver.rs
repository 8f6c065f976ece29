//! The one thread that solves the light for `serve`: it waits for the
//! wanted state (the `--set` values and the frame) to change, solves it
//! warm-started from the last solution, and publishes the result to every
//! page. A change that arrives during a solve cancels it at its next
//! iteration, and changes are not queued: the next solve takes the state
//! as it is then (the last change wins).

use std::sync::{Condvar, Mutex};
use std::time::Instant;

use illumnet::archive::Archive;
use illumnet::distribute::{DistributeError, DistributeOptions, Distributor, Lighting, Solution};

use super::mesh;
use super::protocol::Sets;

/// What the pages want shown, numbered: every accepted change makes a new
/// number.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Wanted {
    /// Bumped by every accepted change.
    pub version: u64,
    /// The light, as `--set` values.
    pub sets: Sets,
    /// The frame shown.
    pub frame: u32,
}

/// A solved state as the pages receive it.
pub struct Solved {
    /// The status message (JSON text).
    pub status: String,
    /// The radiance message (binary): `b"INRD"`, the version, the frame
    /// and the patch count as `u32`, then per patch RGB `f32`
    /// (little-endian; `-1` for patches absent from the frame).
    pub radiance: Vec<u8>,
}

/// The wanted state and the solver's wake-up.
pub struct Desk {
    pub wanted: Mutex<Wanted>,
    pub changed: Condvar,
}

/// The solve of one wanted state, as progress: cancelled as soon as the
/// pages want another (its light would be drawn over at once).
struct Superseded<'d> {
    desk: &'d Desk,
    version: u64,
}

impl illumnet::progress::Progress for Superseded<'_> {
    fn start(&self, _: &str, _: u64) {}
    fn advance(&self, _: u64) {}
    fn finish(&self) {}
    fn cancelled(&self) -> bool {
        self.desk.wanted.lock().is_ok_and(|w| w.version != self.version)
    }
}

/// The lighting `sets` make of the archive's (checked as `render --set`
/// checks it).
pub fn lighting(archive: &Archive, sets: &Sets) -> anyhow::Result<Lighting> {
    let mut l = Lighting::from_view(&archive.view());
    crate::cli::render::relight::relight(&mut l, archive, &sets.args())?;
    Ok(l)
}

/// Solves every new wanted state until `publish` returns false (no one
/// listens any more).
pub fn run(archive: &Archive, desk: &Desk, mut publish: impl FnMut(Solved) -> bool) {
    let v = archive.view();
    let opts = DistributeOptions::default();
    let mut last: Option<Solution> = None;
    let mut done: Option<u64> = None;
    loop {
        let wanted = {
            let mut w = desk.wanted.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            while done == Some(w.version) {
                w = desk.changed.wait(w).unwrap_or_else(std::sync::PoisonError::into_inner);
            }
            w.clone()
        };
        let t = Instant::now();
        let superseded = Superseded { desk, version: wanted.version };
        let solved = lighting(archive, &wanted.sets)
            .and_then(|l| Ok(Distributor::new(&v, &opts, &l)?))
            .map(|d| d.frame(wanted.frame, last.as_ref(), &superseded));
        let seconds = t.elapsed().as_secs_f64();
        done = Some(wanted.version);
        let message = match solved {
            // A newer state is wanted: solve that instead.
            Ok(Err(DistributeError::Cancelled)) => continue,
            Ok(Err(e)) => Err(anyhow::Error::new(e)),
            Ok(Ok(s)) => Ok(s),
            Err(e) => Err(e),
        };
        let message = match message {
            Ok(s) => {
                let message = solved_message(&v, &wanted, &s, seconds);
                last = Some(s);
                message
            }
            // Checked when accepted: only a failing archive gets here.
            Err(e) => Solved {
                status: serde_json::json!({ "type": "error", "message": format!("{e:#}") }).to_string(),
                radiance: Vec::new(),
            },
        };
        if !publish(message) {
            return;
        }
    }
}

/// The messages of a solution.
fn solved_message(v: &illumnet::archive::InetView<'_>, wanted: &Wanted, s: &Solution, seconds: f64) -> Solved {
    let b = &s.balance;
    let sum = |x: &[f64; 3]| x.iter().sum::<f64>();
    let status = serde_json::json!({
        "type": "solved",
        "version": wanted.version,
        "frame": wanted.frame,
        "sets": wanted.sets.args(),
        "iterations": b.iterations,
        "converged": b.converged,
        "solve_ms": seconds * 1e3,
        "emitted": sum(&b.emitted),
        "absorbed": sum(&b.absorbed),
        "escaped": sum(&b.escaped) + sum(&b.back_faces),
        "residual": sum(&b.residual),
        "imbalance": b.imbalance(),
    });
    let present = mesh::present(v, wanted.frame);
    let mut radiance = Vec::with_capacity(16 + s.radiance.len() * 12);
    radiance.extend_from_slice(b"INRD");
    radiance.extend_from_slice(&(wanted.version as u32).to_le_bytes());
    radiance.extend_from_slice(&wanted.frame.to_le_bytes());
    radiance.extend_from_slice(&(s.radiance.len() as u32).to_le_bytes());
    for (r, &here) in s.radiance.iter().zip(&present) {
        let r = if here { *r } else { [-1.0; 3] };
        for c in r {
            radiance.extend_from_slice(&c.to_le_bytes());
        }
    }
    Solved { status: status.to_string(), radiance }
}
