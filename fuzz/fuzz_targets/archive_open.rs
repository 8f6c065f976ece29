//! Any bytes as an archive: open (validation), then what `inspect` and a
//! render read of it — the view, every frame's delta (checked against the
//! links), presence. Plain byte fuzzing mostly tests the checksums; see
//! `archive_forge` for forgeries that pass them.
#![no_main]

use illumnet::archive::Archive;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(a) = Archive::from_bytes(data) else { return };
    let v = a.view();
    let _ = v.primitive_spans();
    if let Some(s) = v.sequence {
        for f in 0..s.frames().min(4) {
            let _ = v.frame_links(f);
            let _ = v.presence(f);
        }
    }
});
