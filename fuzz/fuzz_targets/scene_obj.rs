//! OBJ mesh bytes, loaded through a scene that names them.
#![no_main]

use std::path::Path;
use std::sync::OnceLock;

use illumnet::scene::Scene;
use libfuzzer_sys::fuzz_target;

static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();

const SCENE: &str = "[camera]\nposition = [0, 0, -3]\nlook_at = [0, 0, 0]\nfov_y_deg = 40\nwidth = 8\nheight = 8\n\
[[material]]\nname = 'w'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n\
[[surface]]\nname = 'm'\nmaterial = 'w'\nmesh = 'm.obj'\n";

fuzz_target!(|data: &[u8]| {
    let dir = DIR.get_or_init(|| tempfile::tempdir().unwrap());
    std::fs::write(dir.path().join("m.obj"), data).unwrap();
    let _ = Scene::from_toml(SCENE, Path::new("fuzz.toml"), dir.path());
});
