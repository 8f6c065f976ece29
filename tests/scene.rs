//! Scene files from disk: OBJ meshes relative to the scene, transforms, errors.

use illumnet::scene::Scene;

const HEAD: &str = "[camera]\nposition = [0, 0, -3]\nlook_at = [0, 0, 0]\nfov_y_deg = 40\nwidth = 8\nheight = 8\n\
[[material]]\nname = 'w'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n";

#[test]
fn obj_mesh_loads_relative_to_the_scene_and_is_transformed() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("meshes")).unwrap();
    // A unit square in z = 0 as two triangles facing +z, and a quad face (triangulated).
    std::fs::write(dir.path().join("meshes/square.obj"), "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n")
        .unwrap();
    let scene_path = dir.path().join("s.toml");
    std::fs::write(
        &scene_path,
        format!(
            "{HEAD}[[surface]]\nname = 'm'\nmaterial = 'w'\nmesh = 'meshes/square.obj'\n\
             transform = {{ scale = [2, 2, 2], rotate_deg = [0, 90, 0], translate = [0, 1, 0] }}\n"
        ),
    )
    .unwrap();
    let scene = Scene::from_file(&scene_path).unwrap();
    let prims = &scene.surfaces[0].primitives;
    assert_eq!(prims.len(), 2);
    let area: f32 = prims.iter().map(|p| p.area()).sum();
    assert!((area - 4.0).abs() < 1e-5, "scaled by 2: area {area}");
    // +z rotated 90° about y becomes +x.
    for p in prims {
        assert!((p.normal() - glam::Vec3::X).length() < 1e-5, "{:?}", p.normal());
    }
    let (lo, hi) = scene.bounds();
    assert!((lo.y - 1.0).abs() < 1e-6 && (hi.y - 3.0).abs() < 1e-6, "{lo} {hi}");

    // A missing mesh names the scene line and the OBJ path.
    std::fs::write(&scene_path, format!("{HEAD}[[surface]]\nname = 'm'\nmaterial = 'w'\nmesh = 'nope.obj'\n")).unwrap();
    let e = Scene::from_file(&scene_path).unwrap_err();
    assert_eq!((e.line, e.field.as_str()), (14, "surface[0].mesh"), "{e}");
    assert!(e.message.contains("nope.obj") && e.unreadable, "{e}");
}

#[test]
fn mirroring_transforms_keep_box_faces_outward() {
    let s = format!(
        "{HEAD}[[surface]]\nname = 'b'\nmaterial = 'w'\nbox = {{ min = [0, 0, 0], max = [1, 1, 1] }}\n\
         transform = {{ scale = [-1, 1, 1] }}\n"
    );
    let scene = Scene::from_toml(&s, std::path::Path::new("m.toml"), std::path::Path::new(".")).unwrap();
    let centre = glam::Vec3::new(-0.5, 0.5, 0.5);
    for p in &scene.surfaces[0].primitives {
        let mid = (p.p[0] + p.p[2]) / 2.0;
        assert!(p.normal().dot(mid - centre) > 0.0);
    }
}

#[test]
fn missing_file_is_an_error_naming_it() {
    let e = Scene::from_file(std::path::Path::new("/nonexistent/scene.toml")).unwrap_err();
    assert!(e.to_string().starts_with("/nonexistent/scene.toml: cannot read") && e.unreadable, "{e}");
    // Bytes that are not UTF-8 were read: bad input, not an I/O failure.
    let dir = tempfile::tempdir().unwrap();
    let latin1 = dir.path().join("latin1.toml");
    std::fs::write(&latin1, b"[camera]\n# caf\xe9\n").unwrap();
    let e = Scene::from_file(&latin1).unwrap_err();
    assert!(e.message.contains("not UTF-8") && !e.unreadable, "{e}");
    // A glTF file that is not there: named at the field that names it.
    let e = Scene::from_toml("[gltf]\nfile = 'gone.gltf'\n", &dir.path().join("g.toml"), dir.path()).unwrap_err();
    assert!(e.field == "gltf.file" && e.line == 2 && e.unreadable && e.message.contains("gone.gltf"), "{e}");
    // An OBJ path that names a directory says so: an I/O error (exit 5),
    // as for every special file (tests/special_files.rs).
    std::fs::create_dir(dir.path().join("meshes")).unwrap();
    let text = format!("{HEAD}[[surface]]\nname = 's'\nmaterial = 'w'\nmesh = 'meshes'\n");
    let e = Scene::from_toml(&text, &dir.path().join("s.toml"), dir.path()).unwrap_err();
    assert_eq!((e.line, e.field.as_str()), (14, "surface[0].mesh"), "{e}");
    assert!(e.message.contains("is a directory, not a regular file") && e.unreadable, "{e}");
    // Found by fuzzing: a normal index whose ×3 overflows inside tobj.
    let obj = std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tobj_normal_index_overflow.obj"),
    )
    .unwrap();
    std::fs::write(dir.path().join("bad.obj"), obj).unwrap();
    let text = format!("{HEAD}[[surface]]\nname = 's'\nmaterial = 'w'\nmesh = 'bad.obj'\n");
    let e = Scene::from_toml(&text, &dir.path().join("s.toml"), dir.path()).unwrap_err();
    assert!(e.field == "surface[0].mesh" && e.message.contains("index out of bounds"), "{e}");
}

#[test]
fn glossy_materials_parse_and_bad_keys_name_their_field() {
    use illumnet::scene::ReflectanceModel;
    let quad = "[[surface]]\nname = 's'\nmaterial = 'g'\nquad = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]\ngrain = [0, 1, 0]\n";
    let parse = |material: &str| {
        Scene::from_toml(
            &format!("{HEAD}[[material]]\nname = 'g'\n{material}\n{quad}"),
            std::path::Path::new("g.toml"),
            std::path::Path::new("."),
        )
    };
    let ok = parse("type = 'broad_specular'\nreflectance = [0.4, 0.3, 0.2]\nspecular = [0.5, 0.5, 0.5]\nalpha = 0.2")
        .unwrap();
    match ok.materials[1].model {
        ReflectanceModel::BroadSpecular { lobe, .. } => {
            assert_eq!((lobe.alpha_u, lobe.alpha_v, lobe.ior), (0.2, 0.2, None))
        }
        m => panic!("{m:?}"),
    }
    assert_eq!(ok.surfaces[0].grain, Some(glam::Vec3::Y));
    let metal =
        parse("type = 'rough_conductor'\nspecular = [1, 1, 1]\nalpha_u = 0.1\nalpha_v = 0.3\nior = [1.5, 1.6, 1.7]")
            .unwrap();
    let (_, lobe) = metal.materials[1].model.lobe().unwrap();
    assert_eq!((lobe.bands(), lobe.alpha_v), (3, 0.3));
    for (material, field, says) in [
        (
            "type = 'broad_specular'\nreflectance = [0.6, 0.3, 0.2]\nspecular = [0.5, 0.5, 0.5]\nalpha = 0.2",
            "specular",
            "exceed 1",
        ),
        ("type = 'rough_conductor'\nspecular = [1, 1, 1]", "alpha", "alpha"),
        ("type = 'rough_conductor'\nspecular = [1, 1, 1]\nalpha = 0.001", "alpha", "[0.01, 1]"),
        ("type = 'rough_conductor'\nspecular = [1, 1, 1]\nalpha = 0.2\nalpha_u = 0.3", "alpha", "not both"),
        ("type = 'rough_conductor'\nspecular = [1, 1, 1]\nalpha = 0.2\nior = -1", "ior", "positive"),
        (
            "type = 'rough_conductor'\nreflectance = [0.5, 0.5, 0.5]\nspecular = [1, 1, 1]\nalpha = 0.2",
            "reflectance",
            "has no",
        ),
        ("type = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\nalpha = 0.2", "alpha", "has no"),
        ("type = 'mirror'", "type", "rough_conductor"),
    ] {
        let e = parse(material).unwrap_err();
        assert_eq!(e.field, format!("material[1].{field}"), "{e}");
        assert!(e.message.contains(says), "{e}");
        assert!(e.line >= 12, "{e}");
    }
    // A zero grain is an error on the surface.
    let e = Scene::from_toml(
        &format!(
            "{HEAD}[[material]]\nname = 'g'\ntype = 'rough_conductor'\nspecular = [1, 1, 1]\nalpha = 0.2\n{}",
            quad.replace("grain = [0, 1, 0]", "grain = [0, 0, 0]")
        ),
        std::path::Path::new("g.toml"),
        std::path::Path::new("."),
    )
    .unwrap_err();
    assert_eq!(e.field, "surface[0].grain", "{e}");
}

#[test]
fn parser_errors_name_the_field_in_plain_words() {
    // HEAD's camera in dotted keys.
    const DOTTED: &str = "camera.position = [0, 0, -3]\ncamera.look_at = [0, 0, 0]\ncamera.fov_y_deg = 40\n\
        camera.width = 8\ncamera.height = 8\n[[material]]\nname = 'w'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n";
    let parse =
        |text: &str| Scene::from_toml(text, std::path::Path::new("s.toml"), std::path::Path::new(".")).unwrap_err();
    let surface = "[[surface]]\nname = 's'\nmaterial = 'w'\n";
    for (text, line, field, says) in [
        (
            HEAD.replace("position = [0, 0, -3]", "position = [0, 0]"),
            2,
            "camera.position",
            "expected a list of 3 numbers",
        ),
        (HEAD.replace("width = 8", "width = 200.0"), 5, "camera.width", "expected a whole number, got 200.0"),
        (
            HEAD.replace("width = 8", "width = -5"),
            5,
            "camera.width",
            "expected a whole number, not a negative one, got -5",
        ),
        (HEAD.replace("width = 8", "width = 18446744073709551615"), 5, "camera.width", "18446744073709551615"),
        (format!("{HEAD}[camera]\n"), 11, "camera", "camera"),
        (HEAD.replace("height = 8", "height = 8\nwidth = 9"), 7, "camera.width", "`width` is given twice"),
        (
            HEAD.replace("reflectance = [0.5, 0.5, 0.5]", "reflectance = 'grey'"),
            10,
            "material[0].reflectance",
            "got \"grey\"",
        ),
        (
            format!("{HEAD}{surface}box = {{ min = [0, 0], max = [1, 1, 1] }}\n"),
            14,
            "surface[0].box.min",
            "got 2 values",
        ),
        (
            format!("{HEAD}[[material]]\nname = 'v'\ntype = 'diffuse'\nreflectance = [0.5,\n  0.5]\n"),
            14,
            "material[1].reflectance",
            "got 2 values",
        ),
        // A list of lists over several lines (the style of
        // scenes/cornell_box.toml): the lines inside are not table headers.
        (
            format!(
                "{HEAD}{surface}quads = [\n  [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]],\n  [[0, 0, 1], [1, 0, 1], [1, 1], [0, 1, 1]],\n]\n"
            ),
            16,
            "surface[0].quads",
            "got 2 values",
        ),
        (
            format!("{HEAD}{surface}emission = [1e10, 0, 0]\nquad = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]\n"),
            14,
            "surface[0].emission",
            "[0, 1e9]",
        ),
        // A misspelt key in an inline table of a list: the element named.
        (
            format!(
                "{HEAD}{surface}quad = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]\nkeyframes = [{{ frame = 0, translate = [0, 0, 0] }}, {{ frame = 1, rotate_dg = [0, 0, 0] }}]\n"
            ),
            15,
            "surface[0].keyframes[1].rotate_dg",
            "rotate_dg",
        ),
        // The same over several lines.
        (
            format!(
                "{HEAD}{surface}quad = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]\nkeyframes = [\n  {{ frame = 0 }}, # first\n  {{ frame = 1, translate = [0, 0, 0] }},\n  {{ frame = 2, rotate_dg = [0, 0, 0] }},\n]\n"
            ),
            18,
            "surface[0].keyframes[2].rotate_dg",
            "rotate_dg",
        ),
        // A field an element of the list lacks: the element named.
        (
            format!(
                "{HEAD}{surface}quad = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]\nkeyframes = [{{ frame = 0 }}, {{ rotate_deg = [0, 0, 0] }}]\n"
            ),
            15,
            "surface[0].keyframes[1]",
            "frame",
        ),
        // A string with an escaped quote and a bracket does not open a
        // bracket: the next table is still found.
        (
            format!("{HEAD}[[material]]\nname = \"v\\\"[\"\ntype = 'diffuse'\nreflectance = [0.5, 2]\n"),
            14,
            "material[1].reflectance",
            "got 2 values",
        ),
        // Too long: serde's fixed arrays would take the first values.
        (
            HEAD.replace("position = [0, 0, -3]", "position = [0, 0, -3, 0]"),
            2,
            "camera.position",
            "expected a list of 3 numbers, like [1, 2, 3], got 4 values",
        ),
        (
            format!("{HEAD}{surface}quad = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0.5, 0]]\n"),
            14,
            "surface[0].quad",
            "expected a list of 4 corners, got 5 values",
        ),
        (
            HEAD.replace("reflectance = [0.5, 0.5, 0.5]", "reflectance = [0.5, 0.5, 0.5, 0.5]"),
            10,
            "material[0].reflectance",
            "got 4 values",
        ),
        // Dotted keys keep their prefix: at the top level, with spaces
        // around the dot, misspelt, and inside a table.
        (DOTTED.replace("camera.width = 8", "camera.width = -5"), 4, "camera.width", "not a negative one"),
        (DOTTED.replace("camera.width = 8", "camera . width = 200.0"), 4, "camera.width", "got 200.0"),
        (DOTTED.replace("camera.fov_y_deg", "camera.fovv"), 3, "camera.fovv", "unknown field `fovv`"),
        (format!("{DOTTED}{surface}box.min = [0, 0]\nbox.max = [1, 1, 1]\n"), 13, "surface[0].box.min", "got 2 values"),
    ] {
        let e = parse(&text);
        assert_eq!((e.line, e.field.as_str()), (line, field), "{e}");
        assert!(!e.to_string().is_empty());
        assert!(e.message.contains(says), "{e}");
        assert!(!e.message.contains("u32") && !e.message.contains("invalid length"), "{e}");
    }
}

/// `render --camera-from/--camera-path` read a file's camera alone: a
/// scene file's `[camera]` (the rest ignored), or a path of keyframes over
/// `[animation] frames`; errors name the file, line and field.
#[test]
fn camera_files_read_the_camera_alone() {
    use illumnet::scene::CameraPath;
    let dir = tempfile::tempdir().unwrap();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene = Scene::from_file(&root.join("scenes/fan_room.toml")).unwrap();
    let cam = CameraPath::from_file(&root.join("scenes/fan_room.toml")).unwrap();
    assert_eq!(cam.frames, scene.frame_count());
    for f in [0, 7, 59] {
        assert_eq!(cam.at(f), scene.camera_at(f), "frame {f}");
    }
    let walk = dir.path().join("walk.toml");
    std::fs::write(
        &walk,
        "[animation]\nframes = 5\n[camera]\nposition = [0, 0, -2]\nlook_at = [0, 0, 0]\nfov_y_deg = 40\n\
         width = 8\nheight = 8\nkeyframes = [{ frame = 0, position = [0, 0, -2], look_at = [0, 0, 0] },\n\
         { frame = 4, position = [2, 0, 0], look_at = [0, 0, 0] }]\n",
    )
    .unwrap();
    let path = CameraPath::from_file(&walk).unwrap();
    assert_eq!(path.frames, 5);
    assert!((path.at(2).position - glam::Vec3::new(1.0, 0.0, -1.0)).length() < 1e-6);
    assert_eq!(path.at(9).position, glam::Vec3::new(2.0, 0.0, 0.0), "held after the last key");
    // A key that looks along `up`, on line 8: named.
    std::fs::write(
        &walk,
        "[animation]\nframes = 5\n[camera]\nposition = [0, 0, -2]\nlook_at = [0, 0, 0]\nfov_y_deg = 40\n\
         width = 8\nkeyframes = [{ frame = 0, position = [0, -1, 0], look_at = [0, 0, 0] }]\nheight = 8\n",
    )
    .unwrap();
    let e = CameraPath::from_file(&walk).unwrap_err();
    assert_eq!((e.line, e.field.as_str()), (8, "camera.keyframes"), "{e}");
}
