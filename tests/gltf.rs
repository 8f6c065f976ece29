//! glTF 2.0 import (format-spec/scene.md, "glTF 2.0 scenes") on files
//! written by another tool: `tools/make_gltf.py` (pygltflib) made every
//! file of `tests/data/gltf/`.

mod common;

use std::path::{Path, PathBuf};

use glam::Vec3;
use illumnet::archive::Archive;
use illumnet::distribute::{self, DistributeOptions};
use illumnet::geometry::PrimitiveKind;
use illumnet::progress::NoProgress;
use illumnet::render::{self, RenderOptions, image_io};
use illumnet::scene::{BuildHints, GltfOptions, ReflectanceModel, Scene};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf").join(name)
}

fn import(name: &str, options: &GltfOptions) -> Scene {
    Scene::from_file_with(&data(name), options).unwrap_or_else(|e| panic!("{e}"))
}

/// Coarse settings: the comparisons are between two builds of one scene.
fn coarse(scene: &Scene) -> BuildHints {
    let (lo, hi) = scene.bounds();
    let d = (hi - lo).length();
    BuildHints { patch_size: Some(d / 40.0), ray_spacing: Some(d / 90.0), frequency: Some(6), buckets: None }
}

/// Frame `frame` of `archive`, direct light per pixel plus the I-net's
/// indirect light (the renderer's default shading).
fn render_frame(archive: &Archive, frame: u32) -> render::Image {
    let v = archive.view();
    let sol = distribute::distribute_frame(&v, frame, &DistributeOptions::default(), &NoProgress).unwrap();
    let light = render::DirectLight::new(&v, &sol, render::direct::DEFAULT_LIGHT_SAMPLES);
    let indirect = render::indirect_frame_radiance(&v, frame, &sol);
    let opts = RenderOptions { samples_per_axis: 2, ..Default::default() };
    render::Renderer::new(&v, opts).frame_direct(frame, &indirect, &light).0
}

#[test]
fn the_cornell_box_exported_as_gltf_is_the_toml_scene() {
    let toml = Scene::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml")).unwrap();
    let mut glb = import("cornell_box.glb", &GltfOptions::default());
    assert!(glb.notes.is_empty(), "{:?}", glb.notes);
    // Every wall's two triangles are one quad again: the same primitives.
    assert_eq!(glb.surfaces.len(), toml.surfaces.len());
    for (a, b) in glb.surfaces.iter().zip(&toml.surfaces) {
        assert_eq!(a.name, b.name);
        assert_eq!(a.primitives.len(), b.primitives.len(), "{}", a.name);
        for (p, q) in a.primitives.iter().zip(&b.primitives) {
            assert_eq!(p.kind, PrimitiveKind::Quad);
            assert!(p.p.iter().zip(&q.p).all(|(x, y)| (*x - *y).length() < 1e-6), "{}: {p:?} vs {q:?}", a.name);
        }
        let e: Vec3 = a.emission.into();
        assert!((e - Vec3::from(b.emission)).length() < 1e-5 * e.length().max(1.0), "{}", a.name);
        assert_eq!(glb.materials[a.material as usize].model, toml.materials[b.material as usize].model);
    }
    // The camera node: position, view direction and field of view.
    let (c, t) = (glb.camera, toml.camera);
    assert!((c.position - t.position).length() < 1e-6);
    assert!(((c.look_at - c.position).normalize() - (t.look_at - t.position).normalize()).length() < 1e-6);
    assert!((c.fov_y_deg - t.fov_y_deg).abs() < 1e-4);
    assert_eq!((c.width, c.height), (640, 640), "glTF gives an aspect ratio, and the default width is 640");
    glb.camera.width = t.width;
    glb.camera.height = t.height;
    let hints = coarse(&toml);
    let a = render_frame(&common::build_archive(&glb, hints), 0);
    let b = render_frame(&common::build_archive(&toml, hints), 0);
    let err = image_io::relative_l2(&a, &b).unwrap();
    assert!(err < 0.01, "relative L2 {err} between the glTF and the TOML Cornell box (bar 1%)");
}

#[test]
fn the_animated_fan_room_exported_as_gltf_builds_the_same_sequence() {
    let toml = Scene::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/fan_room.toml")).unwrap();
    // glTF has no frame rate: the scene's 15 fps is given, as `--fps 15`.
    let mut glb = import("fan_room.glb", &GltfOptions { fps: Some(15.0), ..Default::default() });
    assert_eq!(glb.frame_count(), 60);
    assert_eq!(glb.animation.unwrap().fps, 15.0);
    let moving: Vec<&str> = glb.surfaces.iter().filter(|s| s.motion.is_some()).map(|s| s.name.as_str()).collect();
    assert_eq!(moving, ["fan_blade_0", "fan_blade_1", "fan_blade_2", "fan_blade_3", "heat_lamp"]);
    // Between keys too, each moving surface is where the TOML's motion puts it.
    for f in [0, 7, 23, 52, 59] {
        let (a, b) = (glb.at_frame(f), toml.at_frame(f));
        for (s, t) in a.surfaces.iter().zip(&b.surfaces) {
            let worst = s
                .primitives
                .iter()
                .zip(&t.primitives)
                .flat_map(|(p, q)| p.p.iter().zip(q.p).map(|(x, y)| (*x - y).length()))
                .fold(0f32, f32::max);
            assert!(worst < 2e-5, "frame {f}, {}: a corner is {worst} m off", s.name);
        }
    }
    glb.camera.width = toml.camera.width / 2;
    glb.camera.height = toml.camera.height / 2;
    let mut toml = toml;
    toml.camera = glb.camera;
    let hints = coarse(&toml);
    let (ga, ta) = (common::build_sequence_archive(&glb, hints), common::build_sequence_archive(&toml, hints));
    for f in [0, 31, 59] {
        let err = image_io::relative_l2(&render_frame(&ga, f), &render_frame(&ta, f)).unwrap();
        assert!(err < 0.01, "frame {f}: relative L2 {err} between the glTF and the TOML fan room (bar 1%)");
    }
}

#[test]
fn features_import_with_their_geometry_materials_lights_and_animation() {
    let s = import("features.gltf", &GltfOptions { light_radius: Some(0.05), ..Default::default() });
    let by_name = |name: &str| {
        s.surfaces.iter().find(|x| x.name == name).unwrap_or_else(|| {
            panic!("no surface `{name}` in {:?}", s.surfaces.iter().map(|x| &x.name).collect::<Vec<_>>())
        })
    };
    let material = |name: &str| &s.materials[by_name(name).material as usize];

    // The first camera: at (0, 1.5, 4) looking at (0, 0.5, 0), 45°, aspect 1.5.
    assert!((s.camera.position - Vec3::new(0.0, 1.5, 4.0)).length() < 1e-5);
    let dir = (s.camera.look_at - s.camera.position).normalize();
    assert!((dir - (Vec3::new(0.0, 0.5, 0.0) - Vec3::new(0.0, 1.5, 4.0)).normalize()).length() < 1e-5);
    assert!((s.camera.fov_y_deg - 45.0).abs() < 1e-3);
    assert_eq!((s.camera.width, s.camera.height), (640, 427));
    // Another by name.
    let side = import("features.gltf", &GltfOptions { camera: Some("side".into()), ..Default::default() });
    assert!((side.camera.position - Vec3::new(4.0, 1.0, 0.0)).length() < 1e-5);
    let err = Scene::from_file_with(
        &data("features.gltf"),
        &GltfOptions { camera: Some("top".into()), ..Default::default() },
    )
    .unwrap_err();
    assert!(err.to_string().contains("no camera named `top` (known: main, side)"), "{err}");

    // One box mesh, two instances under a parent scaled 2× and raised 0.5 m:
    // centres at (±1, 0.5, 0), 0.4 m wide; 6 faces each (quads again), and
    // no back faces although double sided: the box is closed.
    for (name, x) in [("box_a", -1.0f32), ("box_b", 1.0)] {
        let b = by_name(name);
        assert_eq!(b.primitives.len(), 6, "{name}");
        let (lo, hi) = illumnet::geometry::bounds_of(&b.primitives);
        assert!((((lo + hi) / 2.0) - Vec3::new(x, 0.5, 0.0)).length() < 1e-6, "{name}: {lo} {hi}");
        assert!(((hi - lo) - Vec3::splat(0.4)).length() < 1e-6, "{name}");
    }
    // grey: metallic 0, roughness 0.9: diffuse.
    assert_eq!(material("box_a").model, ReflectanceModel::Diffuse { reflectance: [0.5; 3] });

    // The texture's mean linear albedo (red, green, blue, white: 0.5 per
    // band) times the factor 0.8.
    let ReflectanceModel::Diffuse { reflectance } = material("floor").model else { panic!() };
    assert!(reflectance.iter().all(|r| (r - 0.4).abs() < 0.01), "{reflectance:?}");
    // And kept for the render: its texels as sRGB bytes, the floor's
    // coordinates, and a tint of one over that mean.
    assert_eq!(s.textures.len(), 1);
    let t = &s.textures[0];
    assert_eq!((t.width, t.height, &t.srgb[..]), (2, 2, &[255, 0, 0, 0, 255, 0, 0, 0, 255, 255, 255, 255][..]));
    let floor = by_name("floor");
    assert_eq!(floor.shading.len(), floor.primitives.len());
    for sh in &floor.shading {
        assert_eq!(sh.texture, 0);
        assert!(sh.tint.iter().all(|t| (t - 2.0).abs() < 0.05), "{:?}", sh.tint);
    }
    // Untextured meshes without NORMALs carry no detail.
    assert!(by_name("box_a").shading.is_empty());

    // Emission: factor (1, .5, .25) × strength 8.
    assert_eq!(by_name("panel").emission, [8.0, 4.0, 2.0]);

    // Anisotropic metal: α = 0.4² = 0.16 across, 0.16 + 0.84·0.6² along the
    // anisotropy direction, which rotation π/2 turns from the tangent (+x)
    // onto the bitangent N × T = −z.
    let plate = by_name("plate");
    let ReflectanceModel::RoughConductor { specular, lobe } = s.materials[plate.material as usize].model else {
        panic!()
    };
    assert_eq!(specular, [0.9; 3]);
    assert!((lobe.alpha_v - 0.16).abs() < 1e-6 && (lobe.alpha_u - (0.16 + 0.84 * 0.36)).abs() < 1e-6, "{lobe:?}");
    let grain = plate.grain.expect("a grain");
    assert!((grain - Vec3::NEG_Z).length() < 1e-5, "{grain}");

    // Lamps: power equals the light's (4π·I for a point light of I W/sr,
    // 683 cd being 1 W/sr; 2π(1 − cos θ)·I for a spot, θ the mean of its
    // inner and outer cone angles, 0 and 0.6 here), and the spot faces down.
    let power = |name: &str| -> [f64; 3] {
        let e = by_name(name);
        let area: f64 = e.primitives.iter().map(|p| p.area() as f64).sum();
        e.emission.map(|l| std::f64::consts::PI * l as f64 * area)
    };
    let bulb = power("bulb_node:bulb");
    let want = [2.0, 1.0, 0.5].map(|i| 4.0 * std::f64::consts::PI * i);
    assert!(bulb.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-4 * b), "{bulb:?} vs {want:?}");
    let bulb_prims = &by_name("bulb_node:bulb").primitives;
    assert_eq!(bulb_prims.len(), 20);
    assert!(bulb_prims.iter().all(|p| ((p.p[0] - Vec3::new(-1.0, 2.0, 0.0)).length() - 0.05).abs() < 1e-6));
    let spot = by_name("spot_node:spot");
    assert!((spot.primitives[0].normal() - Vec3::NEG_Y).length() < 1e-5);
    let cone = 2.0 * std::f64::consts::PI * (1.0 - 0.3f64.cos());
    let spot_power = power("spot_node:spot");
    assert!(spot_power.iter().all(|p| (p - cone).abs() < 1e-4 * cone), "{spot_power:?} vs {cone}");

    // The animation: 1 s at 24 fps. Translation STEP: (0,1,0) until 1 s;
    // rotation CUBICSPLINE with zero tangents: the quaternions blended with
    // the weight w = 3t² − 2t³ and renormalised (the specification's rule).
    assert_eq!(s.frame_count(), 25);
    let spinner = by_name("spinner");
    let corner = |f: u32| s.at_frame(f).surfaces.iter().find(|x| x.name == "spinner").unwrap().primitives[0].p[1];
    assert!((spinner.primitives[0].p[0] - Vec3::new(0.0, 1.0, 0.0)).length() < 1e-6);
    for f in [0u32, 6, 12, 18, 24] {
        let t = f as f32 / 24.0;
        let w = 3.0 * t * t - 2.0 * t * t * t;
        let half = std::f32::consts::FRAC_PI_4;
        let angle = 2.0 * (w * half.sin()).atan2(1.0 - w + w * half.cos());
        let z = if f == 24 { 1.0 } else { 0.0 };
        let want = Vec3::new(0.0, 1.0, z) + Vec3::new(0.1 * angle.cos(), 0.0, -0.1 * angle.sin());
        assert!((corner(f) - want).length() < 1e-5, "frame {f}: {} vs {want}", corner(f));
    }

    // What could not be mapped is said, by name.
    let said = s.notes.join("\n");
    for expected in
        ["light `sun`: directional lights are not supported", "mesh `morphing`: morph targets", "light `spot`"]
    {
        assert!(said.contains(expected), "no note `{expected}` in:\n{said}");
    }
}

#[test]
fn errors_name_the_file_and_a_json_pointer() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    // An index out of range, caught by the glTF validator.
    let base = std::fs::read_to_string(data("features.gltf")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&base).unwrap();
    let mut bad = json.clone();
    bad["meshes"][0]["primitives"][0]["material"] = 99.into();
    std::fs::copy(data("features.bin"), dir.path().join("features.bin")).unwrap();
    std::fs::copy(data("checker.png"), dir.path().join("checker.png")).unwrap();
    let p = write("bad_material.gltf", &bad.to_string());
    let e = Scene::from_file(&p).unwrap_err().to_string();
    assert!(e.contains("bad_material.gltf") && e.contains("/meshes/0/primitives/0/material"), "{e}");
    // Anisotropy strength out of range.
    let mut bad = json.clone();
    let plate = bad["materials"].as_array().unwrap().iter().position(|m| m["name"] == "brushed").unwrap();
    bad["materials"][plate]["extensions"]["KHR_materials_anisotropy"]["anisotropyStrength"] = 2.0.into();
    let e = Scene::from_file(&write("bad_aniso.gltf", &bad.to_string())).unwrap_err().to_string();
    assert!(e.contains(&format!("/materials/{plate}/extensions/KHR_materials_anisotropy/anisotropyStrength")), "{e}");
    // No light at all: says how to add one.
    let mut dark = json.clone();
    for m in dark["materials"].as_array_mut().unwrap() {
        m.as_object_mut().unwrap().remove("emissiveFactor");
    }
    for n in dark["nodes"].as_array_mut().unwrap() {
        n.as_object_mut().unwrap().remove("extensions");
    }
    let e = Scene::from_file(&write("dark.gltf", &dark.to_string())).unwrap_err().to_string();
    assert!(e.contains("emits no light") && e.contains("KHR_lights_punctual"), "{e}");
    // A buffer file that is missing.
    std::fs::remove_file(dir.path().join("features.bin")).unwrap();
    let e = Scene::from_file(&write("nobin.gltf", &base)).unwrap_err().to_string();
    assert!(e.contains("nobin.gltf") && e.contains("/buffers"), "{e}");
    // Hostile files (found by an adversarial review): each a clear error.
    let hostile = |name: &str, edit: &dyn Fn(&mut serde_json::Value)| {
        let mut j = json.clone();
        edit(&mut j);
        Scene::from_file(&write(name, &j.to_string())).unwrap_err().to_string()
    };
    std::fs::copy(data("features.bin"), dir.path().join("features.bin")).unwrap();
    // A node with two parents would be instanced twice (or exponentially often).
    let e = hostile("two_parents.gltf", &|j| {
        let boxes = j["nodes"].as_array().unwrap().iter().position(|n| n["name"] == "boxes").unwrap();
        let child = j["nodes"][boxes]["children"][0].clone();
        j["scenes"][0]["nodes"].as_array_mut().unwrap().push(child);
    });
    assert!(e.contains("reached twice"), "{e}");
    // A buffer that is not a regular file is not read (it could be endless).
    let e = hostile("devzero.gltf", &|j| j["buffers"][0]["uri"] = "/dev/zero".into());
    assert!(e.contains("/buffers/0/uri") && e.contains("not a regular file"), "{e}");
    let e = hostile("percent.gltf", &|j| j["buffers"][0]["uri"] = "x%FF.bin".into());
    assert!(e.contains("bad percent escape"), "{e}");
    // Float indices would reach `unreachable!` in the gltf crate.
    let e = hostile("float_indices.gltf", &|j| {
        let a = j["meshes"][0]["primitives"][0]["indices"].as_u64().unwrap() as usize;
        j["accessors"][a]["componentType"] = 5126.into();
    });
    assert!(e.contains("indices: Scalar F32 is not a layout glTF allows here"), "{e}");
    // A sparse accessor of 2³⁰ positions would allocate 12 GiB.
    let e = hostile("huge.gltf", &|j| {
        let a = j["meshes"][0]["primitives"][0]["attributes"]["POSITION"].as_u64().unwrap() as usize;
        j["accessors"][a]["count"] = (1u64 << 30).into();
        j["accessors"][a].as_object_mut().unwrap().remove("bufferView");
        j["accessors"][a]["sparse"] = serde_json::json!({"count": 1, "indices": {"bufferView": 0, "componentType": 5125}, "values": {"bufferView": 0}});
    });
    assert!(e.contains("/count") && e.contains("more than 16777216 elements"), "{e}");

    // Panics in the gltf crates found by fuzzing (docs/RELIABILITY.md),
    // refused before the crate reaches them.
    let e = hostile("position_index.gltf", &|j| j["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = 999.into());
    assert!(e.contains("/meshes/0/primitives/0/attributes/POSITION") && e.contains("accessor 999"), "{e}");
    let e = hostile("count0.gltf", &|j| {
        let a = j["meshes"][0]["primitives"][0]["indices"].as_u64().unwrap() as usize;
        j["accessors"][a]["count"] = 0.into();
    });
    assert!(e.contains("/count") && e.contains("at least one element"), "{e}");
    let e = hostile("target_path.gltf", &|j| j["animations"][0]["channels"][0]["target"]["path"] = "pointer".into());
    assert!(e.contains("/animations/0/channels/0/target/path"), "{e}");
    let e = hostile("target_node.gltf", &|j| j["animations"][0]["channels"][0]["target"]["node"] = 999.into());
    assert!(e.contains("/animations/0/channels/0/target/node"), "{e}");
    let e = hostile("image_mime.gltf", &|j| {
        j["images"][0] = serde_json::json!({"bufferView": 0});
    });
    assert!(e.contains("/images/0/mimeType"), "{e}");
    let mut glb = std::fs::read(data("cornell_box.glb")).unwrap();
    glb[8..12].copy_from_slice(&4u32.to_le_bytes());
    let e = Scene::from_file(&write("short_header.glb", "")).unwrap_err().to_string();
    assert!(e.contains("short_header.glb"), "{e}");
    std::fs::write(dir.path().join("short_header.glb"), &glb).unwrap();
    let e = Scene::from_file(&dir.path().join("short_header.glb")).unwrap_err().to_string();
    assert!(e.contains("GLB header's length"), "{e}");

    // Not glTF at all.
    let e = Scene::from_file(&write("junk.glb", "not a glb")).unwrap_err().to_string();
    assert!(e.contains("junk.glb") && e.contains("cannot read glTF"), "{e}");
}

#[test]
fn a_toml_scene_starts_from_a_gltf_file_and_overrides_by_name() {
    let dir = data("");
    let text = r#"
[gltf]
file = "features.gltf"
camera = "side"
light_radius = 0.1

[build]
patch_size = 0.2

# Replaces the file's `grey` (diffuse 0.5) by name.
[[material]]
name = "grey"
type = "diffuse"
reflectance = [0.2, 0.3, 0.4]

[[surface]]
name = "extra"
material = "grey"
emission = [1.0, 1.0, 1.0]
quad = [[-1.0, 3.0, -1.0], [-1.0, 3.0, 1.0], [1.0, 3.0, 1.0], [1.0, 3.0, -1.0]]
"#;
    let s = Scene::from_toml(text, &dir.join("over.toml"), &dir).unwrap_or_else(|e| panic!("{e}"));
    let get = |n: &str| s.surfaces.iter().find(|x| x.name == n).unwrap();
    assert_eq!(s.name, "over");
    assert!((s.camera.position - Vec3::new(4.0, 1.0, 0.0)).length() < 1e-5, "the camera named in [gltf]");
    assert_eq!(s.build.patch_size, Some(0.2));
    assert_eq!(s.materials.iter().filter(|m| m.name == "grey").count(), 1);
    for n in ["box_a", "extra"] {
        assert_eq!(
            s.materials[get(n).material as usize].model,
            ReflectanceModel::Diffuse { reflectance: [0.2, 0.3, 0.4] },
            "{n}"
        );
    }
    // The lamp radius reaches the importer: the bulb's corners lie 0.1 m out.
    assert!(
        get("bulb_node:bulb")
            .primitives
            .iter()
            .all(|p| ((p.p[0] - Vec3::new(-1.0, 2.0, 0.0)).length() - 0.1).abs() < 1e-6)
    );
    assert_eq!(s.frame_count(), 25, "the file's animation");
    assert!(!s.notes.is_empty());

    // A [camera] table wins over the file's; a surface name taken by the file is refused.
    let cam = "[camera]\nposition = [0, 1, 5]\nlook_at = [0, 1, 0]\nfov_y_deg = 30\nwidth = 64\nheight = 48\n";
    let s = Scene::from_toml(&format!("[gltf]\nfile = 'features.gltf'\n{cam}"), &dir.join("c.toml"), &dir).unwrap();
    assert_eq!((s.camera.width, s.camera.height), (64, 48));
    // A partial one takes the rest from the camera [gltf] names: `main`
    // looks from (0, 1.5, 4) at 45°, 3:2; a width alone keeps its ratio.
    let part = "[gltf]\nfile = 'features.gltf'\ncamera = 'main'\n[camera]\nwidth = 300\n";
    let s = Scene::from_toml(part, &dir.join("p.toml"), &dir).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((s.camera.width, s.camera.height), (300, 200));
    assert!((s.camera.position - Vec3::new(0.0, 1.5, 4.0)).length() < 1e-5 && (s.camera.fov_y_deg - 45.0).abs() < 1e-4);
    let e = Scene::from_toml(&part.replace("width = 300", "width = 0"), &dir.join("p.toml"), &dir).unwrap_err();
    assert!(e.field == "camera.width" && e.line == 5, "{e}");
    // `render --camera-from` on such a file completes the table from the
    // file's camera (and its frames: the file's animation), reading only
    // the camera: a surface the scene could not load does not matter.
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("p.toml");
    let gltf = format!("'{}'", dir.join("features.gltf").display());
    let broken = "[[surface]]\nname = 'x'\nmaterial = 'none'\nobj = 'missing.obj'\n";
    std::fs::write(&file, format!("{}{broken}", part.replace("'features.gltf'", &gltf))).unwrap();
    let from = illumnet::scene::CameraPath::from_file(&file).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((from.camera.width, from.camera.height, from.frames), (300, 200, 25));
    assert!((from.camera.position - Vec3::new(0.0, 1.5, 4.0)).length() < 1e-5);
    assert!((from.camera.fov_y_deg - 45.0).abs() < 1e-4);
    // No [camera] at all: the camera [gltf] names, whole.
    std::fs::write(&file, format!("[gltf]\nfile = {gltf}\ncamera = 'side'\n")).unwrap();
    let side = illumnet::scene::CameraPath::from_file(&file).unwrap_or_else(|e| panic!("{e}"));
    assert!((side.camera.position - Vec3::new(4.0, 1.0, 0.0)).length() < 1e-5, "{:?}", side.camera);
    // A whole [camera] is read alone, as before: one frame, the file unread.
    std::fs::write(&file, format!("[gltf]\nfile = 'missing.glb'\n{cam}")).unwrap();
    let whole = illumnet::scene::CameraPath::from_file(&file).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((whole.camera.width, whole.frames), (64, 1));
    // A partial one over a file that cannot be read names the field.
    std::fs::write(&file, "[gltf]\nfile = 'missing.glb'\n[camera]\nwidth = 300\n").unwrap();
    let e = illumnet::scene::CameraPath::from_file(&file).unwrap_err();
    assert!(e.field == "gltf.file" && e.line == 2 && e.message.contains("missing.glb"), "{e}");
    let dup = "[gltf]\nfile = 'features.gltf'\n[[surface]]\nname = 'floor'\nmaterial = 'grey'\nquad = [[0,0,0],[1,0,0],[1,0,1],[0,0,1]]\n";
    let e = Scene::from_toml(dup, &dir.join("d.toml"), &dir).unwrap_err();
    assert!(e.to_string().contains("duplicate surface name `floor`"), "{e}");
    let e = Scene::from_toml("[gltf]\nfile = 'features.gltf'\n[animation]\nframes = 3\n", &dir.join("a.toml"), &dir)
        .unwrap_err();
    assert!(e.field == "animation" && e.line == 3, "{e}");
    // A material that overrides nothing and that no surface uses: a
    // misspelt override, refused where a silent one would change nothing.
    let typo = "[gltf]\nfile = 'features.gltf'\n[[material]]\nname = 'gery'\ntype = 'diffuse'\nreflectance = [0.2, 0.3, 0.4]\n";
    let e = Scene::from_toml(typo, &dir.join("t.toml"), &dir).unwrap_err();
    assert!(e.field == "material[0].name" && e.line == 4 && e.message.contains("grey"), "{e}");
    // Used by a surface of this file, it is a new material.
    let new =
        format!("{typo}[[surface]]\nname = 'extra'\nmaterial = 'gery'\nquad = [[0,0,0],[1,0,0],[1,0,1],[0,0,1]]\n");
    Scene::from_toml(&new, &dir.join("n.toml"), &dir).unwrap_or_else(|e| panic!("{e}"));
}

/// OBJ + MTL scenes (format-spec/scene.md, "OBJ + MTL scenes"), written by
/// `tools/make_gltf.py` too.
/// A glTF file (and its `.bin`) at `dir/name` that keys a lit triangle's
/// translation every `step` seconds for one second (LINEAR), as an
/// exporter keying every frame of a 1/`step` fps animation writes it.
fn keyed_every(dir: &Path, name: &str, step: f32) -> PathBuf {
    let times: Vec<f32> = (0..).map(|k| k as f32 * step).take_while(|t| *t <= 1.0 + 1e-6).collect();
    let mut bin: Vec<u8> = Vec::new();
    let triangle = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    bin.extend(triangle.iter().flat_map(|x| x.to_le_bytes()));
    bin.extend(times.iter().flat_map(|x| x.to_le_bytes()));
    bin.extend(times.iter().flat_map(|t| [0.0f32, *t, -1.0].map(f32::to_le_bytes)).flatten());
    let n = times.len();
    let gltf = serde_json::json!({
        "asset": { "version": "2.0" },
        "scene": 0,
        "scenes": [{ "nodes": [0, 1] }],
        "nodes": [{ "name": "lamp", "mesh": 0 }, { "name": "mover", "mesh": 0, "translation": [0.0, 0.0, -1.0] }],
        "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0 }, "material": 0 }] }],
        "materials": [{ "emissiveFactor": [1.0, 1.0, 1.0] }],
        "buffers": [{ "uri": format!("{name}.bin"), "byteLength": bin.len() }],
        "bufferViews": [
            { "buffer": 0, "byteOffset": 0, "byteLength": 36 },
            { "buffer": 0, "byteOffset": 36, "byteLength": 4 * n },
            { "buffer": 0, "byteOffset": 36 + 4 * n, "byteLength": 12 * n },
        ],
        "accessors": [
            { "bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0] },
            { "bufferView": 1, "componentType": 5126, "count": n, "type": "SCALAR", "min": [0.0], "max": [times[n - 1]] },
            { "bufferView": 2, "componentType": 5126, "count": n, "type": "VEC3" },
        ],
        "animations": [{
            "channels": [{ "sampler": 0, "target": { "node": 1, "path": "translation" } }],
            "samplers": [{ "input": 1, "output": 2, "interpolation": "LINEAR" }],
        }],
    });
    std::fs::write(dir.join(format!("{name}.bin")), bin).unwrap();
    let path = dir.join(format!("{name}.gltf"));
    std::fs::write(&path, gltf.to_string()).unwrap();
    path
}

#[test]
fn keys_between_the_frames_of_the_default_rate_are_warned_of() {
    let dir = tempfile::tempdir().unwrap();
    // Keys every 1/15 s sampled at the default 24 fps: only every fifth
    // (0, 1/3, 2/3 and 1 s) falls on a frame.
    let file = keyed_every(dir.path(), "fifteen", 1.0 / 15.0);
    let warning = "animation: 12 of 16 key times fall between the frames of the default 24 fps; \
                   the keys imply 15 fps: give it with --fps 15 (or [gltf] fps = 15)";
    let s = Scene::from_file(&file).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.frame_count(), 25);
    assert!(s.notes.iter().any(|n| n == warning), "{:?}", s.notes);
    // A rate given (the keys' own, or any other) is the user's: no note.
    for fps in [15.0, 24.0] {
        let s = Scene::from_file_with(&file, &GltfOptions { fps: Some(fps), ..Default::default() }).unwrap();
        assert!(!s.notes.iter().any(|n| n.contains("key times")), "{fps} fps: {:?}", s.notes);
    }
    // Keys on the frames of the default rate: no note.
    let twelve = Scene::from_file(&keyed_every(dir.path(), "twelve", 1.0 / 12.0)).unwrap();
    assert!(!twelve.notes.iter().any(|n| n.contains("key times")), "{:?}", twelve.notes);
    // `illumnet build` prints it as a warning, and not with `--fps`.
    let build = |extra: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_illumnet"))
            .args(["build", "-q", "--frame", "0", "--quality", "draft"])
            .arg(&file)
            .arg("-o")
            .arg(dir.path().join("f.inet"))
            .args(extra)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let err = build(&[]);
    assert_eq!(err.matches(&format!("illumnet: warning: {}: {warning}", file.display())).count(), 1, "{err}");
    assert!(!build(&["--fps", "15"]).contains("key times"));
}

fn obj(name: &str) -> Scene {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/obj").join(name);
    Scene::from_file(&p).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn the_cornell_box_as_obj_and_mtl_is_the_toml_scene() {
    let toml = Scene::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml")).unwrap();
    let mut o = obj("cornell_box.obj");
    assert_eq!(o.notes, ["OBJ has no camera: one looks at the scene along -Z (give one with render --camera-*)"]);
    assert_eq!(o.surfaces.len(), toml.surfaces.len());
    for (a, b) in o.surfaces.iter().zip(&toml.surfaces) {
        assert_eq!(a.name, b.name);
        assert_eq!(a.primitives, b.primitives, "{}: four-corner faces are the same quads", a.name);
        assert_eq!(a.emission, b.emission, "{}", a.name);
        assert_eq!(o.materials[a.material as usize].model, toml.materials[b.material as usize].model, "{}", a.name);
    }
    o.camera = toml.camera;
    let hints = coarse(&toml);
    let err = image_io::relative_l2(
        &render_frame(&common::build_archive(&o, hints), 0),
        &render_frame(&common::build_archive(&toml, hints), 0),
    )
    .unwrap();
    assert!(err < 0.01, "relative L2 {err} between the OBJ and the TOML Cornell box (bar 1%)");
}

#[test]
fn mtl_textures_specular_and_emission() {
    let s = obj("textured.obj");
    let get = |n: &str| s.surfaces.iter().find(|x| x.name == n).unwrap();
    // Kd 0.8 × the checker's mean linear albedo 0.5 (its v flipped: same mean).
    let ReflectanceModel::Diffuse { reflectance } = s.materials[get("floor").material as usize].model else { panic!() };
    assert!(reflectance.iter().all(|r| (r - 0.4).abs() < 1e-5), "{reflectance:?}");
    // Ks 0.9 with Ns 48 and no Kd: a rough conductor of α = √(2/50) = 0.2.
    let ReflectanceModel::RoughConductor { specular, lobe } = s.materials[get("plate").material as usize].model else {
        panic!()
    };
    assert_eq!(specular, [0.9; 3]);
    assert!((lobe.alpha_u - 0.2).abs() < 1e-6);
    assert_eq!(get("lamp").emission, [5.0; 3]);
    // The map is kept for the render: per-texel detail around that mean.
    assert_eq!((s.textures.len(), s.textures[0].width, s.textures[0].height), (1, 2, 2));
    let floor = get("floor");
    assert_eq!(floor.shading.len(), floor.primitives.len());
    assert!(floor.shading.iter().all(|sh| sh.texture == 0 && (sh.tint[0] - 2.0).abs() < 1e-3));
    // No light: an error that says how to add one.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("dark.obj");
    std::fs::write(&p, "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n").unwrap();
    let e = Scene::from_file(&p).unwrap_err().to_string();
    assert!(e.contains("dark.obj") && e.contains("Ke r g b"), "{e}");
}

/// Standard base64 with padding (RFC 4648), for `data:` URIs.
fn base64(bytes: &[u8]) -> String {
    const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for c in bytes.chunks(3) {
        let byte = |i: usize| *c.get(i).unwrap_or(&0) as u32;
        let n = (byte(0) << 16) | (byte(1) << 8) | byte(2);
        for k in 0..4 {
            out.push(if k <= c.len() { A[((n >> (18 - 6 * k)) & 63) as usize] as char } else { '=' });
        }
    }
    out
}

/// `illumnet build` of `scene` (draft): its exit code and stderr.
fn build_exit(scene: &Path) -> (Option<i32>, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["build", "-q", "--quality", "draft"])
        .arg(scene)
        .arg("-o")
        .arg(scene.with_extension("inet"))
        .output()
        .unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn an_image_given_as_a_data_uri_is_read() {
    // Issue 42, §7: refused as "external reference in slice only import".
    let dir = tempfile::tempdir().unwrap();
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("features.gltf")).unwrap()).unwrap();
    let png = std::fs::read(data("checker.png")).unwrap();
    json["images"][0]["uri"] = format!("data:image/png;base64,{}", base64(&png)).into();
    std::fs::copy(data("features.bin"), dir.path().join("features.bin")).unwrap();
    let p = dir.path().join("inline.gltf");
    std::fs::write(&p, json.to_string()).unwrap();
    let inline = Scene::from_file(&p).unwrap_or_else(|e| panic!("{e}"));
    let file = import("features.gltf", &GltfOptions::default());
    assert_eq!(inline.textures, file.textures, "the same texels as from checker.png");
    assert_eq!(inline.materials, file.materials);
    // Not base64: a clear error at the image's uri.
    json["images"][0]["uri"] = "data:image/png,%89PNG".into();
    std::fs::write(&p, json.to_string()).unwrap();
    let e = Scene::from_file(&p).unwrap_err().to_string();
    assert!(e.contains("inline.gltf") && e.contains("/images/0/uri") && e.contains("base64"), "{e}");
}

#[test]
fn a_texture_the_archive_cannot_hold_is_refused_at_import() {
    // Issue 42, §7: accepted, then the build failed at its end with
    // "corrupt archive: TXHD[0]: size out of range" (exit 4).
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::copy(data("features.gltf"), d.join("features.gltf")).unwrap();
    std::fs::copy(data("features.bin"), d.join("features.bin")).unwrap();
    for name in ["textured.obj", "textured.mtl"] {
        std::fs::copy(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/obj").join(name), d.join(name)).unwrap();
    }
    for (w, h) in [(1, 20000), (16385, 2)] {
        image::RgbImage::new(w, h).save(d.join("checker.png")).unwrap();
        let e = Scene::from_file(&d.join("features.gltf")).unwrap_err();
        let text = e.to_string();
        assert!(!e.unreadable, "{text}");
        assert!(
            text.contains("features.gltf") && text.contains("/images/0") && text.contains("`checker.png`"),
            "{text}"
        );
        assert!(text.contains(&format!("{w} × {h} texels")) && text.contains("16384"), "{text}");
        // The same rule for an MTL's map_Kd.
        let text = Scene::from_file(&d.join("textured.obj")).unwrap_err().to_string();
        assert!(text.contains("textured.obj") && text.contains("map_Kd") && text.contains("checker.png"), "{text}");
        assert!(text.contains(&format!("{w} × {h} texels")), "{text}");
    }
    // `illumnet build`: exit 3 naming the file and the image, before work.
    let (code, err) = build_exit(&d.join("features.gltf"));
    assert_eq!(code, Some(3), "{err}");
    assert!(err.contains("features.gltf") && err.contains("image 0") && !err.contains("TXHD"), "{err}");
    // At the limit: read.
    image::RgbImage::new(16384, 2).save(d.join("checker.png")).unwrap();
    let s = Scene::from_file(&d.join("features.gltf")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((s.textures[0].width, s.textures[0].height), (16384, 2));
}

#[test]
fn mtl_values_beyond_the_toml_bounds_are_refused_naming_file_line_and_field() {
    // Issue 42, §8: `Ke inf` became 0, `Ke 1e10` 10⁹, `Kd 2` 1, silently.
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("room.obj");
    std::fs::write(&obj, "mtllib room.mtl\no lamp\nusemtl lamp\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
        .unwrap();
    let with = |lines: &str| {
        std::fs::write(dir.path().join("room.mtl"), format!("# made by a tool\nnewmtl lamp\n{lines}\n")).unwrap();
        Scene::from_file(&obj)
    };
    for (lines, at, field) in [
        ("Kd 0.5 0.5 0.5\nKe inf 1 1", "room.mtl:4:4", "Ke"),
        ("Ke 1e10 1 1", "room.mtl:3:4", "Ke"),
        ("Ke 1 -1 1", "room.mtl:3:6", "Ke"),
        ("Ke 1 1 1\nKd 0.5 NaN 0.5", "room.mtl:4:8", "Kd"),
        ("Ke 1 1 1\nKs 0.1 0.1 -0.1", "room.mtl:4:12", "Ks"),
        ("Ke 1 1 1\nNs inf", "room.mtl:4:4", "Ns"),
        // One number: tobj 4.0.5 panicked (`parse_float3` unwraps).
        ("Ke 1 1 1\n  Kd 0.5", "room.mtl:4:3", "Kd"),
    ] {
        let e = with(lines).unwrap_err();
        let text = e.to_string();
        assert!(!e.unreadable && text.contains(at) && text.contains(&format!("material `lamp`.{field}")), "{text}");
    }
    // A reflectance above 1 (exporters write colour × intensity): clamped
    // to 1 and said, naming the line.
    let s = with("Ke 1 1 1\nKd 2 0.5 0.5").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.materials[0].model, ReflectanceModel::Diffuse { reflectance: [1.0, 0.5, 0.5] });
    assert!(s.notes.iter().any(|n| n.contains("room.mtl:4:4") && n.contains("clamped to 1")), "{:?}", s.notes);
    // At the bounds: read as written.
    let s = with("Ke 1e9 0 0\nKd 1 1 1\nNs 1e6").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.surfaces[0].emission, [1e9, 0.0, 0.0]);
    // `illumnet build`: exit 3.
    with("Ke inf 1 1").unwrap_err();
    let (code, err) = build_exit(&obj);
    assert_eq!(code, Some(3), "{err}");
    assert!(err.contains("room.mtl:3:4") && err.contains("material `lamp`.Ke"), "{err}");
}
