//! `illumnet serve`, talked to as its page does (WebSocket, JSON requests,
//! binary radiance frames): the light is linear in emission, two pages see
//! one state, hostile requests change nothing and are each answered with
//! an error, and the light saved reads back as `render --set-file` input.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use tokio_tungstenite::tungstenite::Message;

type Socket = tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// The server, killed (by its PID, through `Child`) when dropped.
struct Server {
    child: Child,
    url: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn build_cornell_box(dir: &Path) -> std::path::PathBuf {
    build(dir, "cornell_box")
}

fn build(dir: &Path, name: &str) -> std::path::PathBuf {
    let archive = dir.join(format!("{name}.inet"));
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/{name}.toml"));
    let out = Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["build", "-q", "--quality", "draft"])
        .arg(&scene)
        .arg("-o")
        .arg(&archive)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    archive
}

fn serve(archive: &Path, renders: &Path) -> Server {
    serve_with(archive, renders, &[]).0
}

/// The server, and what it printed before its URL.
fn serve_with(archive: &Path, renders: &Path, extra: &[&str]) -> (Server, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["serve", "--port", "0", "--render-dir"])
        .arg(renders)
        .args(extra)
        .arg(archive)
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    let mut before = String::new();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    while !line.starts_with("serving on ") {
        before.push_str(&line);
        line.clear();
        assert!(out.read_line(&mut line).unwrap() > 0, "the server stopped: {before}");
    }
    // Keep reading what it prints (a render's summary): a closed pipe
    // would end it.
    std::thread::spawn(move || std::io::copy(&mut out, &mut std::io::sink()));
    let address = line.split("http://").nth(1).and_then(|r| r.split('/').next()).unwrap_or_else(|| panic!("{line}"));
    (Server { child, url: format!("ws://{address}/ws") }, before)
}

/// The next text message, as JSON.
async fn next_json(ws: &mut Socket) -> serde_json::Value {
    loop {
        let m = tokio::time::timeout(Duration::from_secs(60), ws.next()).await.expect("an answer").unwrap().unwrap();
        if let Message::Text(t) = m {
            return serde_json::from_str(&t).unwrap();
        }
    }
}

/// The next solution: its status and per-patch radiance.
async fn next_solution(ws: &mut Socket) -> (serde_json::Value, Vec<[f32; 3]>) {
    let status = loop {
        let j = next_json(ws).await;
        if j["type"] == "solved" {
            break j;
        }
        assert_ne!(j["type"], "error", "{j}");
    };
    let m = tokio::time::timeout(Duration::from_secs(60), ws.next()).await.unwrap().unwrap().unwrap();
    let Message::Binary(b) = m else { panic!("expected the radiance after the status, got {m:?}") };
    assert_eq!(&b[..4], b"INRD");
    let n = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
    assert_eq!(b.len(), 16 + 12 * n);
    let radiance = b[16..]
        .chunks_exact(12)
        .map(|c| [0, 1, 2].map(|k| f32::from_le_bytes(c[4 * k..4 * k + 4].try_into().unwrap())))
        .collect();
    (status, radiance)
}

async fn send(ws: &mut Socket, text: &str) {
    ws.send(Message::Text(text.into())).await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_page_relights_the_cornell_box() {
    let dir = tempfile::tempdir().unwrap();
    let archive = build_cornell_box(dir.path());
    let server = serve(&archive, &dir.path().join("renders"));
    let (mut a, _) = tokio_tungstenite::connect_async(&server.url).await.unwrap();
    let scene = next_json(&mut a).await;
    assert_eq!(scene["type"], "scene");
    let light: Vec<f64> =
        scene["surfaces"].as_array().unwrap().iter().find(|s| s["name"] == "light").unwrap()["emission"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
    let (first, one) = next_solution(&mut a).await;
    assert_eq!(first["sets"].as_array().unwrap().len(), 0);

    // Twice the lamp: everything is linear in emission.
    let doubled = format!(
        r#"{{"op":"set","target":"light.emission","value":[{},{},{}]}}"#,
        2.0 * light[0],
        2.0 * light[1],
        2.0 * light[2]
    );
    send(&mut a, &doubled).await;
    let (status, two) = next_solution(&mut a).await;
    assert!(status["version"].as_u64() > first["version"].as_u64());
    let peak = one.iter().flatten().fold(0.0f32, |m, &x| m.max(x));
    let (mut diff, mut total) = (0.0f64, 0.0f64);
    for (p, (x, y)) in one.iter().zip(&two).enumerate() {
        for c in 0..3 {
            // The solver's tolerance: 1e-4 of the emitted power unshot.
            assert!((y[c] - 2.0 * x[c]).abs() <= 2e-3 * peak + 1e-2 * x[c], "patch {p}: {} then {}", x[c], y[c]);
            diff += (y[c] - 2.0 * x[c]).abs() as f64;
            total += 2.0 * x[c] as f64;
        }
    }
    assert!(diff / total < 1e-3, "radiance doubled to {:.2e} (relative L1)", diff / total);

    // A second page sees the same state, at once.
    let (mut b, _) = tokio_tungstenite::connect_async(&server.url).await.unwrap();
    assert_eq!(next_json(&mut b).await["type"], "scene");
    let (seen, radiance_b) = next_solution(&mut b).await;
    assert_eq!(seen["version"], status["version"]);
    assert!(radiance_b == two, "the second page sees other light");

    // Hostile requests: each answered with an error, nothing changes.
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng
    };
    let shapes = [
        r#"{"op":"set","target":"nothing.emission","value":[1,1,1]}"#.to_string(),
        r#"{"op":"set","target":"light.emission","value":[-1,1,1]}"#.to_string(),
        r#"{"op":"set","target":"light.emission","value":[1e39,1,1]}"#.to_string(),
        r#"{"op":"set","target":"red_wall.reflectance","value":[2,0,0]}"#.to_string(),
        r#"{"op":"set","target":"light.alpha","value":[1,1,1]}"#.to_string(),
        r#"{"op":"set","target":"light.emission","value":"red"}"#.to_string(),
        r#"{"op":"frame","frame":5}"#.to_string(),
        r#"{"op":"frame","frame":1e20}"#.to_string(),
        r#"{"op":"delete"}"#.to_string(),
        "{".to_string(),
    ];
    for i in 0..1000 {
        let text = match i % 3 {
            0 => shapes[next() as usize % shapes.len()].clone(),
            1 => (0..next() % 64).map(|_| char::from(32 + (next() % 95) as u8)).collect(),
            _ => format!(
                r#"{{"op":"set","target":"light.emission","value":[{},{},{}]}}"#,
                -((next() % 1000) as f64 + 1.0),
                1,
                1
            ),
        };
        send(&mut a, &text).await;
        let answer = next_json(&mut a).await;
        assert_eq!(answer["type"], "error", "{text} → {answer}");
    }
    // Binary requests are not requests either.
    a.send(Message::Binary(vec![0u8; 64].into())).await.unwrap();
    assert_eq!(next_json(&mut a).await["type"], "error");
    send(&mut a, r#"{"op":"save"}"#).await;
    let saved = next_json(&mut a).await;
    assert_eq!(saved["type"], "saved", "{saved}");
    let toml_text = saved["toml"].as_str().unwrap();
    let parsed: toml::Value = toml::from_str(toml_text).unwrap();
    assert_eq!(parsed["set"].as_array().unwrap().len(), 1, "only the lamp was set: {toml_text}");
    // `render --set-file` reads it: the same image as the `--set` it holds.
    let file = dir.path().join("light.toml");
    std::fs::write(&file, toml_text).unwrap();
    let set = parsed["set"][0].as_str().unwrap().to_string();
    let render = |extra: &[&str], png: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_illumnet"))
            .arg("render")
            .arg(&archive)
            .args(["-q", "--shading", "inet", "--samples", "1", "--size", "32x32", "-o"])
            .arg(dir.path().join(png))
            .args(extra)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        image::open(dir.path().join(png)).unwrap().to_rgb8().into_raw()
    };
    let from_file = render(&["--set-file", file.to_str().unwrap()], "file.png");
    assert!(from_file == render(&["--set", &set], "set.png"), "--set-file differs from --set {set}");
    assert!(from_file != render(&[], "plain.png"), "the saved light is the archive's");

    // Half the red wall's reflectance: its patches lose more than half
    // their light (less comes back to them too).
    let names: Vec<String> =
        scene["surfaces"].as_array().unwrap().iter().map(|s| s["name"].as_str().unwrap().to_string()).collect();
    let red = names.iter().position(|n| n == "red_wall").unwrap();
    let red_rho: Vec<f64> =
        scene["surfaces"][red]["reflectance"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    send(
        &mut a,
        &format!(
            r#"{{"op":"set","target":"red_wall.reflectance","value":[{},{},{}]}}"#,
            red_rho[0] / 2.0,
            red_rho[1] / 2.0,
            red_rho[2] / 2.0
        ),
    )
    .await;
    let (after, halved) = next_solution(&mut a).await;
    assert_eq!(
        after["version"].as_u64(),
        Some(status["version"].as_u64().unwrap() + 1),
        "hostile requests changed the state"
    );
    let opened = illumnet::archive::Archive::open(&archive).unwrap();
    let v = opened.view();
    let surface_of: Vec<usize> = v.patch_primitive.iter().map(|&p| v.primitives[p as usize].surface as usize).collect();
    let on = |name: &str, r: &[[f32; 3]], c: usize| -> f64 {
        let s = names.iter().position(|n| n == name).unwrap();
        r.iter().zip(&surface_of).filter(|(_, k)| **k == s).map(|(x, _)| x[c] as f64).sum()
    };
    let (before_red, after_red) = (on("red_wall", &two, 0), on("red_wall", &halved, 0));
    assert!(after_red < 0.5 * before_red, "the red wall's red: {before_red:.3} → {after_red:.3}");
    for wall in ["back_wall", "floor", "ceiling"] {
        let (x, y) = (on(wall, &two, 0), on(wall, &halved, 0));
        assert!(y < x, "{wall}'s red: {x:.4} → {y:.4}: the red wall reflects less onto it");
    }

    // "render": the view asked for, with the light set, is the render
    // command's image byte for byte.
    let c = &scene["camera"];
    let view = serde_json::json!({ "op": "render", "camera": {
        "position": [c["position"][0].as_f64().unwrap() + 0.1, c["position"][1], c["position"][2]],
        "look_at": c["look_at"], "up": c["up"], "fov_y_deg": 35.5, "width": 48, "height": 40 } });
    send(&mut a, &view.to_string()).await;
    let rendered = loop {
        let j = next_json(&mut a).await;
        if j["type"] == "rendered" {
            break j;
        }
        assert_ne!(j["type"], "error", "{j}");
    };
    let name = rendered["url"].as_str().unwrap().rsplit('/').next().unwrap().to_string();
    let served = std::fs::read(dir.path().join("renders").join(&name)).unwrap();
    let mut args: Vec<String> =
        rendered["args"].as_array().unwrap().iter().map(|a| a.as_str().unwrap().to_string()).collect();
    let o = args.iter().position(|a| a == "-o").unwrap();
    args[o + 1] = dir.path().join("cli.png").display().to_string();
    assert!(args.iter().filter(|a| *a == "--set").count() == 2, "{args:?}");
    let out = Command::new(env!("CARGO_BIN_EXE_illumnet")).args(&args).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let cli = std::fs::read(dir.path().join("cli.png")).unwrap();
    assert!(served == cli, "the page's render differs from `{}`", rendered["command"]);
    let image = image::load_from_memory(&served).unwrap();
    assert_eq!((image.width(), image.height()), (48, 40));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_page_scrubs_the_fan_room_to_the_light_render_solves() {
    let dir = tempfile::tempdir().unwrap();
    let archive = build(dir.path(), "fan_room");
    let server = serve(&archive, &dir.path().join("renders"));
    let (mut a, _) = tokio_tungstenite::connect_async(&server.url).await.unwrap();
    assert_eq!(next_json(&mut a).await["frames"], 60);
    let (first, zero) = next_solution(&mut a).await;
    send(&mut a, r#"{"op":"frame","frame":30}"#).await;
    let (status, page) = next_solution(&mut a).await;
    assert_eq!(status["frame"], 30);
    assert!(status["version"].as_u64() > first["version"].as_u64());
    // What `render --frames 30` solves: frame 30 alone, cold. The page's
    // came warm from frame 0's: the same light to the solver's tolerance.
    let opened = illumnet::archive::Archive::open(&archive).unwrap();
    let want = illumnet::distribute::distribute_frame(
        &opened.view(),
        30,
        &illumnet::distribute::DistributeOptions::default(),
        &illumnet::progress::NoProgress,
    )
    .unwrap();
    // `render --patch-radiance` writes that solution.
    let bin = dir.path().join("r30.bin");
    let run = |frames: &str| {
        Command::new(env!("CARGO_BIN_EXE_illumnet"))
            .args(["render", "-q", "--frames", frames, "--shading", "inet", "--samples", "1", "--size", "8x6"])
            .arg(&archive)
            .arg("-o")
            .arg(dir.path().join("x_%02d.png"))
            .arg("--patch-radiance")
            .arg(&bin)
            .output()
            .unwrap()
    };
    assert!(run("30").status.success());
    let written: Vec<f32> =
        std::fs::read(&bin).unwrap().chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
    assert!(written == want.radiance.iter().flatten().copied().collect::<Vec<_>>(), "--patch-radiance");
    assert_eq!(run("29..31").status.code(), Some(3), "--patch-radiance of two frames is refused");
    let present = illumnet::archive::InetView::primitive_spans(&opened.view());
    let v = opened.view();
    let peak = want.radiance.iter().flatten().fold(0.0f32, |m, &x| m.max(x));
    let (mut diff, mut total, mut absent) = (0.0f64, 0.0f64, 0);
    for (p, (got, want)) in page.iter().zip(&want.radiance).enumerate() {
        if !present[v.patch_primitive[p] as usize].contains(30) {
            assert_eq!(*got, [-1.0; 3], "patch {p} is absent from frame 30: the page hides it");
            absent += 1;
            continue;
        }
        for c in 0..3 {
            assert!(
                (got[c] - want[c]).abs() <= 2e-3 * peak + 1e-2 * want[c],
                "patch {p}: {} against {}",
                got[c],
                want[c]
            );
            diff += (got[c] - want[c]).abs() as f64;
            total += want[c] as f64;
        }
    }
    assert!(diff / total < 1e-3, "frame 30 against render's: relative L1 {:.2e}", diff / total);
    assert!(absent > 0, "the fan room's frame 30 hides the blades of other frames");
    assert!(page != zero, "frame 30's light is frame 0's");

    // A scrub: five frames asked at once. The solves they supersede are
    // cancelled or never started; the last one asked is the one shown.
    for f in 40..45 {
        send(&mut a, &format!(r#"{{"op":"frame","frame":{f}}}"#)).await;
    }
    let last = status["version"].as_u64().unwrap() + 5;
    let mut shown = Vec::new();
    loop {
        let (s, _) = next_solution(&mut a).await;
        shown.push(s["frame"].as_u64().unwrap());
        if s["version"].as_u64() == Some(last) {
            assert_eq!(s["frame"], 44);
            break;
        }
    }
    assert!(shown.len() <= 2, "frames solved and shown for one scrub: {shown:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn under_a_small_budget_the_page_gets_the_same_light_streamed() {
    let dir = tempfile::tempdir().unwrap();
    let archive = build_cornell_box(dir.path());
    let (mapped, said) = serve_with(&archive, &dir.path().join("r1"), &[]);
    assert!(!said.contains("streamed"), "{said}");
    let (streamed, said) = serve_with(&archive, &dir.path().join("r2"), &["--memory-budget", "16M"]);
    assert!(said.contains("streamed"), "under 16M the link ends are streamed: {said}");
    let mut light = Vec::new();
    for server in [&mapped, &streamed] {
        let (mut ws, _) = tokio_tungstenite::connect_async(&server.url).await.unwrap();
        assert_eq!(next_json(&mut ws).await["type"], "scene");
        light.push(next_solution(&mut ws).await.1);
    }
    assert!(light[0] == light[1], "streamed link ends give other light");
    // Below what any plan needs: refused before work, exit 6.
    let out = Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["serve", "--port", "0", "--memory-budget", "1M"])
        .arg(&archive)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(6), "{}", String::from_utf8_lossy(&out.stderr));
}

#[test]
fn stopped_by_a_signal_the_server_removes_its_temporary_renders() {
    let dir = tempfile::tempdir().unwrap();
    let archive = build_cornell_box(dir.path());
    let mut child = Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["serve", "--port", "0"])
        .arg(&archive)
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let (mut line, mut renders) = (String::new(), None);
    while !line.starts_with("serving on ") {
        line.clear();
        assert!(out.read_line(&mut line).unwrap() > 0);
        if let Some(rest) = line.strip_prefix("renders go to ") {
            renders = Some(std::path::PathBuf::from(rest.trim_end().trim_end_matches(" (removed at exit)")));
        }
    }
    let renders = renders.expect("the server says where renders go");
    assert!(renders.is_dir());
    // SAFETY: kill(2) on our own child's PID.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130));
    assert!(!renders.exists(), "{} left behind", renders.display());
}
