//! Writer and reader agree (issue 14): every scene the parser accepts
//! builds an archive the reader opens and the distribution solves to
//! finite light — over generated scenes: any mix of diffuse, rough
//! conductor and broad specular materials (used or not), emitters, boxes
//! and quads, stills and short sequences.

use illumnet::archive::{self, Archive};
use illumnet::bake::{self, BuildSettings};
use illumnet::distribute::{DistributeOptions, Distributor, Lighting};
use illumnet::progress::NoProgress;
use illumnet::scene::{BuildHints, Scene};
use proptest::prelude::*;

#[derive(Debug, Clone)]
enum Kind {
    Diffuse,
    Conductor { au: f32, av: f32 },
    BroadSpecular { alpha: f32 },
}

fn kind() -> impl Strategy<Value = Kind> {
    prop_oneof![
        Just(Kind::Diffuse),
        (0.01f32..1.0, 0.01f32..1.0).prop_map(|(au, av)| Kind::Conductor { au, av }),
        (0.01f32..1.0).prop_map(|alpha| Kind::BroadSpecular { alpha }),
    ]
}

/// A box: material index, corner, size, emission, whether it moves.
type GenBox = (usize, [f32; 3], [f32; 3], f32, bool);

#[derive(Debug, Clone)]
struct Generated {
    materials: Vec<(Kind, f32)>,
    boxes: Vec<GenBox>,
    frames: u32,
}

fn generated() -> impl Strategy<Value = Generated> {
    (
        prop::collection::vec((kind(), 0.0f32..0.45), 1..4),
        prop::collection::vec(
            (
                0usize..4,
                [0.1f32..1.4, 0.1f32..1.4, 0.1f32..1.4],
                [0.05f32..0.5, 0.05f32..0.5, 0.05f32..0.5],
                prop_oneof![Just(0.0f32), 0.1f32..20.0],
                any::<bool>(),
            ),
            1..4,
        ),
        1u32..4,
    )
        .prop_map(|(materials, boxes, frames)| Generated { materials, boxes, frames })
}

fn toml(g: &Generated) -> String {
    let mut t =
        String::from("[camera]\nposition = [1, 1, -1.5]\nlook_at = [1, 1, 1]\nfov_y_deg = 60\nwidth = 8\nheight = 8\n");
    if g.frames > 1 {
        t += &format!("[animation]\nframes = {}\n", g.frames);
    }
    t += "[[material]]\nname = 'room'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n";
    for (i, (k, r)) in g.materials.iter().enumerate() {
        t += &format!("[[material]]\nname = 'm{i}'\n");
        t += &match k {
            Kind::Diffuse => format!("type = 'diffuse'\nreflectance = [{r}, {r}, {r}]\n"),
            Kind::Conductor { au, av } => {
                format!("type = 'rough_conductor'\nspecular = [0.9, 0.8, 0.7]\nalpha_u = {au}\nalpha_v = {av}\n")
            }
            Kind::BroadSpecular { alpha } => format!(
                "type = 'broad_specular'\nreflectance = [{r}, {r}, {r}]\nspecular = [0.5, 0.5, 0.5]\nalpha = {alpha}\n"
            ),
        };
    }
    t += "[[surface]]\nname = 'room'\nmaterial = 'room'\nbox = { min = [0, 0, 0], max = [2, 2, 2], inward = true }\n";
    t += "[[surface]]\nname = 'lamp'\nmaterial = 'room'\nemission = [5, 5, 5]\n";
    t += "quad = [[0.8, 1.95, 0.8], [1.2, 1.95, 0.8], [1.2, 1.95, 1.2], [0.8, 1.95, 1.2]]\n";
    for (i, (m, lo, size, e, moves)) in g.boxes.iter().enumerate() {
        // Materials beyond the list fall back to the first: some stay unused.
        let m = if *m < g.materials.len() { *m } else { 0 };
        let hi = [0, 1, 2].map(|c| (lo[c] + size[c]).min(1.9));
        t += &format!("[[surface]]\nname = 'b{i}'\nmaterial = 'm{m}'\nbox = {{ min = {lo:?}, max = {hi:?} }}\n");
        if *e > 0.0 {
            t += &format!("emission = [{e}, {e}, {e}]\n");
        }
        if *moves && g.frames > 1 {
            t += &format!(
                "keyframes = [{{ frame = 0 }}, {{ frame = {}, translate = [0.05, 0, 0.05] }}]\n",
                g.frames - 1
            );
        }
    }
    t
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn every_scene_that_parses_builds_an_archive_that_opens_and_solves(g in generated()) {
        let text = toml(&g);
        let scene = Scene::from_toml(&text, std::path::Path::new("gen.toml"), std::path::Path::new("."))
            .map_err(|e| TestCaseError::fail(format!("{e}\n{text}")))?;
        let hints = BuildHints { patch_size: Some(0.25), frequency: Some(3), ray_spacing: Some(0.05), buckets: None };
        let mut settings = BuildSettings::resolve(&scene, hints);
        settings.prototype_library = None;
        let c = bake::build_sequence(&scene, &settings, &NoProgress).map_err(TestCaseError::fail)?.contents;
        let bytes = archive::write_to_vec(&c).unwrap();
        let a = Archive::from_bytes(&bytes).map_err(|e| TestCaseError::fail(format!("{e}\n{text}")))?;
        let v = a.view();
        let d = Distributor::new(&v, &DistributeOptions::default(), &Lighting::from_view(&v)).unwrap();
        // A sequence without motion builds a still.
        for f in 0..v.sequence.map_or(1, |s| s.frames()) {
            let s = d.frame(f, None, &NoProgress).map_err(|e| TestCaseError::fail(format!("frame {f}: {e}\n{text}")))?;
            prop_assert!(s.radiance.iter().flatten().all(|x| x.is_finite()));
            prop_assert!(s.balance.converged, "frame {f} did not converge\n{text}");
        }
    }
}

fn parse(text: &str) -> Result<Scene, illumnet::scene::SceneError> {
    Scene::from_toml(text, std::path::Path::new("gen.toml"), std::path::Path::new("."))
}

const ROOM: &str = "[[material]]\nname = 'w'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n\
[[surface]]\nname = 'room'\nmaterial = 'w'\nbox = { min = [0, 0, 0], max = [2, 2, 2], inward = true }\n\
[[surface]]\nname = 'lamp'\nmaterial = 'w'\nemission = [5, 5, 5]\n\
quad = [[0.8, 1.95, 0.8], [1.2, 1.95, 0.8], [1.2, 1.95, 1.2], [0.8, 1.95, 1.2]]\n";

#[test]
fn a_camera_that_looks_along_up_between_its_keys_is_refused_when_parsed() {
    // Keys fine, but halfway the view turns straight down onto `up`'s line.
    let text = format!(
        "[camera]\nposition = [1, 1, 1]\nlook_at = [1, 0, 0]\nfov_y_deg = 60\nwidth = 8\nheight = 8\n\
         keyframes = [{{ frame = 0, position = [1, 1, 1], look_at = [1, 0, 0] }}, {{ frame = 2, position = [1, 1, 1], look_at = [1, 0, 2] }}]\n\
         [animation]\nframes = 3\n{ROOM}"
    );
    let e = parse(&text).unwrap_err();
    assert_eq!(e.field, "camera.keyframes", "{e}");
    assert!(e.message.contains("at frame 1"), "{e}");
}

#[test]
fn motion_beyond_the_archives_coordinates_is_refused_by_the_build() {
    let text = format!(
        "[camera]\nposition = [1, 1, -1.5]\nlook_at = [1, 1, 1]\nfov_y_deg = 60\nwidth = 8\nheight = 8\n\
         [animation]\nframes = 2\n{ROOM}\
         [[surface]]\nname = 'far'\nmaterial = 'w'\nbox = {{ min = [0.2, 0.2, 0.2], max = [0.4, 0.4, 0.4] }}\n\
         keyframes = [{{ frame = 0 }}, {{ frame = 1, translate = [2e9, 0, 0] }}]\n"
    );
    let scene = parse(&text).unwrap();
    let settings = BuildSettings::resolve(&scene, BuildHints { frequency: Some(2), ..Default::default() });
    let Err(e) = bake::build_sequence(&scene, &settings, &NoProgress) else { panic!("built") };
    assert!(e.contains("surface `far` at frames 1..=1") && e.contains("beyond ±1e9 m"), "{e}");
}

#[test]
fn a_coplanar_poster_that_leaves_a_wall_gives_frames_that_solve() {
    // A poster flush with a wall at frame 0 (its coplanar hits deduplicated
    // there), gone from it later: every frame's links must still carry no
    // more rays than cross each patch.
    let text = format!(
        "[camera]\nposition = [1, 1, -1.5]\nlook_at = [1, 1, 1]\nfov_y_deg = 60\nwidth = 8\nheight = 8\n\
         [animation]\nframes = 3\n{ROOM}\
         [[surface]]\nname = 'poster'\nmaterial = 'w'\n\
         quad = [[0.5, 0.5, 1.999], [0.5, 1.5, 1.999], [1.5, 1.5, 1.999], [1.5, 0.5, 1.999]]\n\
         keyframes = [{{ frame = 0 }}, {{ frame = 2, translate = [0, 0, -0.8] }}]\n\
         [[surface]]\nname = 'flush'\nmaterial = 'w'\n\
         quad = [[0.001, 0.5, 0.5], [0.001, 0.5, 1.5], [0.001, 1.5, 1.5], [0.001, 1.5, 0.5]]\n\
         keyframes = [{{ frame = 0 }}, {{ frame = 2, translate = [0.7, 0, 0] }}]\n"
    );
    let scene = parse(&text).unwrap();
    let hints = BuildHints { patch_size: Some(0.25), frequency: Some(3), ray_spacing: Some(0.04), buckets: None };
    let mut settings = BuildSettings::resolve(&scene, hints);
    settings.prototype_library = None;
    let c = bake::build_sequence(&scene, &settings, &NoProgress).unwrap().contents;
    let a = Archive::from_bytes(&archive::write_to_vec(&c).unwrap()).unwrap();
    let v = a.view();
    let d = Distributor::new(&v, &DistributeOptions::default(), &Lighting::from_view(&v)).unwrap();
    for f in 0..3 {
        let s = d.frame(f, None, &NoProgress).unwrap_or_else(|e| panic!("frame {f}: {e}"));
        assert!(s.balance.converged && s.radiance.iter().flatten().all(|x| x.is_finite()));
    }
}
