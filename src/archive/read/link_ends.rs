//! Frame 0's link ends (§5.10): `LOFF` rows, `LROF` and `LRUN` runs,
//! `LOTH` ids against their runs, `LCNT` with `LCNX`, each patch's
//! weights within its `PHIT`, `LDIR` directions; of a streamed archive,
//! what its stream did not already check as it opened.

use super::views::InetView;
use super::{bad, check, count, csr};
use crate::archive::ArchiveError;
use crate::archive::ends::Links;
use crate::archive::links::{IdCheck, check_rows, check_run_offsets};
use crate::archive::weights::{self, WeightSums};

/// The link-end columns and their runs, whole when resident; the link
/// end count when streamed (the stream checked the rest).
pub(super) fn check_link_ends(v: &InetView<'_>) -> Result<(), ArchiveError> {
    let b = v.build;
    let (p, nd) = (b.patch_count as usize, b.direction_count as usize);
    match v.links {
        Links::Resident(l) => {
            let ends = l.local_ids().len();
            count("LCNT", l.weight.len(), ends)?;
            count("LDIR", l.direction.len(), ends)?;
            check(b.link_end_count == ends as u64, || "BILD: link end count disagrees with LOTH".into())?;
            csr("LOFF", v.link_offsets.iter().copied(), ends)?;
            let runs = l.runs.records();
            check_run_offsets(l.runs.offsets(), p, runs.len() as u64).map_err(bad)?;
            check_rows(v.link_offsets, l.runs.offsets(), 0..p, runs, b.max_bucket.min(255) as u8).map_err(bad)?;
            let mut ids = IdCheck::new(runs.iter().copied(), p);
            check(ids.add(l.local_ids()) && ids.done(), || "LOTH: patch id out of range".into())?;
            let escapes = l.weight.escapes();
            let mut next = 0;
            weights::check(l.weight.counts(), 0, escapes, &mut next).map_err(ArchiveError::Corrupt)?;
            check(next == escapes.len(), || {
                format!("LCNX: {} entries, but LCNT has {next} zero counts", escapes.len())
            })?;
            WeightSums::new(v.link_offsets, v.patch_hits).add(l.weight)?;
            check(l.direction.iter().all(|&d| (d as usize) < nd), || "LDIR: direction out of range".into())?;
        }
        // The stream checked its columns' lengths and content as it
        // opened them (`LinkStream::open`), and `LOFF` before that.
        Links::Streamed(s, _) => {
            check(b.link_end_count == s.ends() as u64, || "BILD: link end count disagrees with LOFF".into())?;
        }
    }
    Ok(())
}
