//! Forged archives that pass every checksum: a still, a glossy and a
//! sequence archive (built once, tiny) patched as the input says and
//! resealed (`archive::reseal`), then opened, distributed (every frame)
//! and rendered. The input is a script, not bytes of an archive, so the
//! fuzzer explores values behind the checksums: byte 0 picks the seed;
//! then per patch 1 byte section (mod the section count; bit 7: its
//! table entry instead), 4 bytes offset (mod the length), 1 byte length
//! (1..=8) and that many bytes written there; or, when the length byte's
//! bit 7 is set, the first 4 of those bytes an f32 factor that scales
//! every f32 of the section from the offset on (products and sums of
//! fields: every solid angle doubled, every area denormal; issue 42).
//!
//! Must hold: no panic; every solution handed out and every pixel
//! finite; and an archive that opens distributes to finite light
//! (format-spec/archive.md §7): the distribution may refuse a frame, but
//! never with a non-finite result.
#![no_main]

use std::sync::OnceLock;

use illumnet::archive::layout::{self, HeaderRecord, SectionEntry};
use illumnet::archive::{self, Archive};
use illumnet::bake::{self, BuildSettings};
use illumnet::distribute::{DistributeError, DistributeOptions, Distributor, Lighting};
use illumnet::progress::NoProgress;
use illumnet::render::{self, RenderOptions, Renderer};
use illumnet::scene::{BuildHints, Scene};
use libfuzzer_sys::fuzz_target;

const ROOM: &str = "[camera]\nposition = [1, 1, -1.5]\nlook_at = [1, 1, 1]\nfov_y_deg = 60\nwidth = 8\nheight = 8\n\
[[material]]\nname = 'grey'\ntype = 'diffuse'\nreflectance = [0.6, 0.5, 0.4]\n\
[[surface]]\nname = 'room'\nmaterial = 'grey'\nbox = { min = [0, 0, 0], max = [2, 2, 2], inward = true }\n\
[[surface]]\nname = 'lamp'\nmaterial = 'grey'\nemission = [5, 5, 5]\n\
quad = [[0.8, 1.9, 0.8], [1.2, 1.9, 0.8], [1.2, 1.9, 1.2], [0.8, 1.9, 1.2]]\n";
const GLOSSY: &str = "[[material]]\nname = 'metal'\ntype = 'rough_conductor'\nspecular = [0.9, 0.8, 0.7]\n\
alpha_u = 0.2\nalpha_v = 0.4\n[[surface]]\nname = 'plate'\nmaterial = 'metal'\n\
quad = [[0.5, 0.3, 0.5], [1.5, 0.3, 0.5], [1.5, 0.3, 1.5], [0.5, 0.3, 1.5]]\n";
const MOVING: &str = "[animation]\nframes = 3\nfps = 10\n[[surface]]\nname = 'mover'\nmaterial = 'grey'\n\
box = { min = [0.3, 0.2, 0.3], max = [0.7, 0.6, 0.7] }\n\
keyframes = [{ frame = 0 }, { frame = 2, translate = [0.8, 0.2, 0.6] }]\n";

fn seed(text: &str) -> Vec<u8> {
    let scene = Scene::from_toml(text, std::path::Path::new("seed.toml"), std::path::Path::new(".")).unwrap();
    let hints = BuildHints { patch_size: Some(0.4), frequency: Some(2), ray_spacing: Some(0.08), buckets: None };
    let mut settings = BuildSettings::resolve(&scene, hints);
    settings.prototype_library = None;
    archive::write_to_vec(&bake::build_sequence(&scene, &settings, &NoProgress).unwrap().contents).unwrap()
}

static SEEDS: OnceLock<[Vec<u8>; 3]> = OnceLock::new();

fuzz_target!(|data: &[u8]| {
    let seeds = SEEDS.get_or_init(|| [seed(ROOM), seed(&format!("{ROOM}{GLOSSY}")), seed(&format!("{ROOM}{MOVING}"))]);
    let Some((&pick, mut script)) = data.split_first() else { return };
    let mut bytes = seeds[pick as usize % 3].clone();
    let header: HeaderRecord = bytemuck::pod_read_unaligned(&bytes[..layout::HEADER_SIZE]);
    let entries: Vec<SectionEntry> = (0..header.section_count as usize)
        .map(|i| {
            let at = header.table_offset as usize + i * layout::ENTRY_SIZE;
            bytemuck::pod_read_unaligned(&bytes[at..at + layout::ENTRY_SIZE])
        })
        .collect();
    while script.len() >= 6 {
        let (sel, offset, len) = (script[0], u32::from_le_bytes(script[1..5].try_into().unwrap()), script[5]);
        script = &script[6..];
        let scale = len & 0x80 != 0;
        let len = (len as usize % 8 + 1).min(script.len());
        let (value, rest) = script.split_at(len);
        script = rest;
        let i = (sel & 0x7f) as usize % entries.len();
        let (start, span) = match sel & 0x80 {
            0 => (entries[i].offset as usize, entries[i].stored_length as usize),
            _ => (header.table_offset as usize + i * layout::ENTRY_SIZE, layout::ENTRY_SIZE),
        };
        if span == 0 {
            continue;
        }
        let at = start + offset as usize % span;
        if scale && value.len() >= 4 && sel & 0x80 == 0 {
            let factor = f32::from_le_bytes(value[..4].try_into().unwrap());
            let from = start + (at - start) / 4 * 4;
            for w in bytes[from..start + span / 4 * 4].chunks_exact_mut(4) {
                let x = f32::from_le_bytes(w.try_into().unwrap()) * factor;
                w.copy_from_slice(&x.to_le_bytes());
            }
            continue;
        }
        let n = value.len().min(start + span - at);
        bytes[at..at + n].copy_from_slice(&value[..n]);
    }
    archive::reseal(&mut bytes);
    let Ok(a) = Archive::from_bytes(&bytes) else { return };
    let v = a.view();
    let opts = DistributeOptions { max_iterations: 6, ..Default::default() };
    // The invariant of §7: refused, maybe, but never non-finite.
    let finite_or_refused = |e: DistributeError| {
        assert!(!matches!(e, DistributeError::NotFinite { .. }), "an archive that opened made non-finite light: {e}");
    };
    let d = match Distributor::new(&v, &opts, &Lighting::from_view(&v)) {
        Ok(d) => d,
        Err(e) => return finite_or_refused(e),
    };
    let small = (v.camera.width as u64 * v.camera.height as u64) <= 64 * 64;
    let mut renderer = small.then(|| Renderer::new(&v, RenderOptions { samples_per_axis: 1, ..Default::default() }));
    for f in 0..v.sequence.map_or(1, |s| s.frames().min(3)) {
        let s = match d.frame(f, None, &NoProgress) {
            Ok(s) => s,
            Err(e) => return finite_or_refused(e),
        };
        assert!(s.radiance.iter().flatten().all(|c| c.is_finite()), "a non-finite radiance was handed out");
        if let Some(renderer) = &mut renderer {
            let light = render::DirectLight::new(&v, &s, 1);
            let (image, direct) = renderer.frame_direct(f, &render::indirect_frame_radiance(&v, f, &s), &light);
            assert!(image.pixels.iter().chain(&direct.pixels).flatten().all(|c| c.is_finite()), "a non-finite pixel");
        }
    }
});
