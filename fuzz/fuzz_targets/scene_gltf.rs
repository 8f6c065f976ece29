//! glTF 2.0 bytes (JSON when they start with `{`, else GLB) imported as a
//! scene, with the test files' buffer and texture beside them; then the
//! file's camera alone, as `render --camera-from` reads it.
#![no_main]

use std::sync::OnceLock;

use illumnet::scene::{CameraPath, Scene};
use libfuzzer_sys::fuzz_target;

static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();

fuzz_target!(|data: &[u8]| {
    let dir = DIR.get_or_init(|| {
        let d = tempfile::tempdir().unwrap();
        let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/gltf");
        for f in ["features.bin", "checker.png"] {
            std::fs::copy(src.join(f), d.path().join(f)).unwrap();
        }
        d
    });
    let name = if data.first() == Some(&b'{') { "m.gltf" } else { "m.glb" };
    let path = dir.path().join(name);
    std::fs::write(&path, data).unwrap();
    if let Ok(scene) = Scene::from_file(&path) {
        for f in 0..scene.frame_count().min(4) {
            let _ = scene.at_frame(f);
        }
    }
    let _ = CameraPath::from_file(&path);
});
