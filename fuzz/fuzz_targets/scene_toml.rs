//! Scene text (TOML), with an OBJ mesh beside it for `mesh = "m.obj"`:
//! parsed, never built (a parsed scene may ask for hours of tracing).
#![no_main]

use std::path::Path;
use std::sync::OnceLock;

use illumnet::scene::Scene;
use libfuzzer_sys::fuzz_target;

static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();

fuzz_target!(|data: &[u8]| {
    let dir = DIR.get_or_init(|| {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("m.obj"), "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n").unwrap();
        d
    });
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Err(e) = Scene::from_toml(text, Path::new("fuzz.toml"), dir.path()) {
        assert!(!e.to_string().is_empty());
    }
});
