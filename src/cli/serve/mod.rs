//! `illumnet serve ARCHIVE`: interactive relighting in the browser. The
//! page (served from the binary: `assets/serve/`) draws the patches
//! coloured by their radiance and sends changes of the light; one solver
//! thread (`solver`) re-solves warm-started from the last solution and
//! every page connected gets the new radiance (binary WebSocket frames)
//! and the energy balance. The archive is never written; the light is
//! saved only on request, as `--set` values `render --set-file` reads.
//!
//! The HTTP and WebSocket server is axum on tokio; `protocol` decodes and
//! checks what pages send, `mesh` the patches as triangles.

mod mesh;
mod protocol;
mod solver;

use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::sync::{Arc, Condvar, Mutex};

use anyhow::{Context, Result};
use axum::extract::State;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::http::header;
use axum::response::IntoResponse;
use axum::routing::get;
use clap::Args;
use illumnet::archive::Archive;
use tokio::sync::watch;

use super::common::opened;
use protocol::{Request, Sets};
use solver::{Desk, Solved, Wanted};

/// `illumnet serve`'s arguments.
#[derive(Args)]
pub struct ServeCommand {
    /// Archive written by `illumnet build` (never written to).
    archive: PathBuf,
    /// Port to listen on (0: any free one; the URL printed says which).
    #[arg(long, default_value_t = 7878)]
    port: u16,
    /// Address to listen on. Loopback by default: there is no
    /// authentication, so another address lets anyone who reaches it
    /// change the light (a warning says so).
    #[arg(long, default_value = "127.0.0.1")]
    bind: IpAddr,
    /// Where the page's "render" button writes its images (default: a
    /// temporary directory, removed when the server stops).
    #[arg(long, value_name = "DIR")]
    render_dir: Option<PathBuf>,
    #[command(flatten)]
    budget: super::common::BudgetArgs,
}

/// What every connection shares.
struct Shared {
    archive: Arc<Archive>,
    desk: Arc<Desk>,
    solved: watch::Receiver<Option<Arc<Solved>>>,
    scene: String,
    mesh: Vec<u8>,
    /// The archive's path, as given.
    path: PathBuf,
    /// Where renders go, and how many were made.
    renders: PathBuf,
    rendered: std::sync::atomic::AtomicU64,
    /// `--memory-budget`, in bytes, given to the render button's renders
    /// too.
    budget: Option<u64>,
}

/// Runs `illumnet serve` until interrupted.
pub fn run(command: ServeCommand) -> Result<()> {
    let archive = Arc::new(open_within_budget(&command.archive, command.budget.memory_budget)?);
    let v = archive.view();
    let desk =
        Arc::new(Desk { wanted: Mutex::new(Wanted { version: 1, ..Default::default() }), changed: Condvar::new() });
    let (tx, rx) = watch::channel(None);
    let temporary = match &command.render_dir {
        Some(_) => None,
        None => Some(tempfile::Builder::new().prefix("illumnet-serve-").tempdir()?),
    };
    let renders = match (&command.render_dir, &temporary) {
        (Some(d), _) => {
            std::fs::create_dir_all(d).with_context(|| format!("--render-dir {}", d.display()))?;
            d.clone()
        }
        (None, Some(t)) => t.path().to_path_buf(),
        (None, None) => unreachable!("a temporary directory is made when none is given"),
    };
    println!("renders go to {}{}", renders.display(), if temporary.is_some() { " (removed at exit)" } else { "" });
    let shared = Arc::new(Shared {
        archive: archive.clone(),
        desk: desk.clone(),
        solved: rx,
        scene: scene_message(&archive),
        mesh: mesh::mesh_bytes(&v),
        path: command.archive.clone(),
        renders,
        rendered: Default::default(),
        budget: command.budget.memory_budget,
    });
    let solver = {
        let (archive, desk) = (archive.clone(), desk.clone());
        std::thread::Builder::new().name("solver".into()).spawn(move || {
            solver::run(&archive, &desk, |s| tx.send(Some(Arc::new(s))).is_ok());
        })?
    };
    let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?;
    // Interrupted or terminated: the temporary renders go with it.
    // (The handlers are in place before the URL is printed.)
    let cleanup = temporary.as_ref().map(|t| t.path().to_path_buf());
    let (mut interrupt, mut terminate) = {
        use tokio::signal::unix::{SignalKind, signal};
        let _in_runtime = runtime.enter();
        (signal(SignalKind::interrupt())?, signal(SignalKind::terminate())?)
    };
    runtime.spawn(async move {
        tokio::select! {
            _ = interrupt.recv() => {}
            _ = terminate.recv() => {}
        }
        if let Some(dir) = &cleanup {
            let _ = std::fs::remove_dir_all(dir);
        }
        std::process::exit(130);
    });
    let result = runtime.block_on(serve(command.bind, command.port, shared));
    drop(solver); // detached: it ends with the process
    drop(temporary);
    result
}

/// The archive opened as a render of its camera's view would be within
/// `budget` (the link ends mapped, or streamed when they do not fit: each
/// solve is then slower, and says so in its time); refused before work
/// when even that cannot fit.
fn open_within_budget(path: &std::path::Path, budget: Option<u64>) -> Result<Archive> {
    use illumnet::render::plan;
    let summary = opened(path, Archive::summary(path))?;
    let job = plan::RenderJob {
        width: summary.camera.width,
        height: summary.camera.height,
        samples_per_axis: 1,
        frames: 1,
        keep_images: false,
        anderson_depth: illumnet::distribute::DistributeOptions::default().anderson_depth as u32,
        buckets: true,
        threads: rayon::current_num_threads() as u32,
        keeps_solving: true,
    };
    let budget = super::common::memory_budget(budget);
    let memory = plan::plan(&summary, &job, budget)?;
    let archive = match memory.access {
        plan::LinkAccess::Mapped => opened(path, Archive::open(path))?,
        plan::LinkAccess::Streamed { window_ends, in_flight } => {
            let a = opened(path, Archive::open_streamed(path, window_ends))?;
            if let Some(stream) = a.link_stream() {
                stream.limit_windows_in_flight(in_flight);
            }
            a
        }
    };
    println!("memory: {memory}");
    Ok(archive)
}

/// Listens and answers until interrupted.
async fn serve(bind: IpAddr, port: u16, shared: Arc<Shared>) -> Result<()> {
    let app = axum::Router::new()
        .route("/", get(|| async { ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], PAGE) }))
        .route("/app.js", get(|| async { ([(header::CONTENT_TYPE, "text/javascript; charset=utf-8")], SCRIPT) }))
        .route("/mesh.bin", get(mesh_bin))
        .route("/patch-surfaces.bin", get(patch_surfaces))
        .route("/renders/{name}", get(render_file))
        .route("/ws", get(upgrade))
        .with_state(shared);
    let address = SocketAddr::new(bind, port);
    let listener =
        tokio::net::TcpListener::bind(address).await.with_context(|| format!("cannot listen on {address}"))?;
    let local = listener.local_addr()?;
    if !bind.is_loopback() {
        eprintln!(
            "illumnet: warning: listening on {local}, not loopback: there is no authentication, anyone who reaches \
             this address can change the light (the archive is never written)"
        );
    }
    println!("serving on http://{local}/ (Ctrl-C to stop)");
    axum::serve(listener, app).await.context("the server stopped")
}

/// The page and its script, from the binary.
const PAGE: &str = include_str!("../../../assets/serve/index.html");
const SCRIPT: &str = include_str!("../../../assets/serve/app.js");

async fn mesh_bin(State(shared): State<Arc<Shared>>) -> impl IntoResponse {
    ([(header::CONTENT_TYPE, "application/octet-stream")], shared.mesh.clone())
}

/// Each patch's surface (`u32`, little-endian), for a page or a test that
/// picks patches by surface.
async fn patch_surfaces(State(shared): State<Arc<Shared>>) -> impl IntoResponse {
    let v = shared.archive.view();
    let bytes: Vec<u8> =
        v.patch_primitive.iter().flat_map(|&p| v.primitives[p as usize].surface.to_le_bytes()).collect();
    ([(header::CONTENT_TYPE, "application/octet-stream")], bytes)
}

/// An image the "render" button made (`render-N.png` only).
async fn render_file(
    axum::extract::Path(name): axum::extract::Path<String>,
    State(shared): State<Arc<Shared>>,
) -> axum::response::Response {
    let valid = name
        .strip_prefix("render-")
        .and_then(|n| n.strip_suffix(".png"))
        .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()));
    match valid.then(|| std::fs::read(shared.renders.join(&name))) {
        Some(Ok(bytes)) => ([(header::CONTENT_TYPE, "image/png")], bytes).into_response(),
        _ => (axum::http::StatusCode::NOT_FOUND, "no such render").into_response(),
    }
}

/// Renders `view` with the light and frame of `wanted` by running the
/// `render` command itself (its image is then the command line's, bit
/// for bit); the answer names the image and the command.
fn render_view(shared: &Shared, view: protocol::View, wanted: &Wanted) -> String {
    let n = shared.rendered.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
    let name = format!("render-{n}.png");
    let out = shared.renders.join(&name);
    let point = |p: [f32; 3]| format!("{},{},{}", p[0], p[1], p[2]);
    let mut args: Vec<String> = vec!["render".into(), shared.path.display().to_string(), "-o".into()];
    args.push(out.display().to_string());
    for (flag, value) in [
        ("--camera-position", point(view.position)),
        ("--look-at", point(view.look_at)),
        ("--up", point(view.up)),
        ("--fov", view.fov_y_deg.to_string()),
        ("--size", format!("{}x{}", view.width, view.height)),
    ] {
        args.extend([flag.to_string(), value]);
    }
    if shared.archive.view().sequence.is_some() {
        args.extend(["--frames".to_string(), wanted.frame.to_string()]);
    }
    for s in wanted.sets.args() {
        args.extend(["--set".to_string(), s]);
    }
    if let Some(b) = shared.budget {
        args.extend(["--memory-budget".to_string(), b.to_string()]);
    }
    let started = std::time::Instant::now();
    let command = std::iter::once("illumnet".to_string())
        .chain(args.iter().map(|a| if a.contains(' ') { format!("'{a}'") } else { a.clone() }))
        .collect::<Vec<_>>()
        .join(" ");
    match super::run_render(&args) {
        Ok(()) => serde_json::json!({
            "type": "rendered",
            "url": format!("/renders/{name}"),
            "args": args,
            "command": command,
            "seconds": started.elapsed().as_secs_f64(),
        })
        .to_string(),
        Err(e) => error(format!("render: {e:#}")),
    }
}

async fn upgrade(ws: WebSocketUpgrade, State(shared): State<Arc<Shared>>) -> impl IntoResponse {
    ws.max_message_size(protocol::MAX_MESSAGE).on_upgrade(move |socket| connection(socket, shared))
}

/// One page: the scene first, then every solution as it comes, and an
/// answer to each request.
async fn connection(mut socket: WebSocket, shared: Arc<Shared>) {
    let mut solved = shared.solved.clone();
    if socket.send(Message::Text(shared.scene.clone().into())).await.is_err() {
        return;
    }
    // The latest solution, if any, at once.
    let current = solved.borrow_and_update().clone();
    if let Some(s) = current
        && send_solved(&mut socket, &s).await.is_err()
    {
        return;
    }
    loop {
        tokio::select! {
            changed = solved.changed() => {
                if changed.is_err() { return; }
                let current = solved.borrow_and_update().clone();
                if let Some(s) = current && send_solved(&mut socket, &s).await.is_err() { return; }
            }
            incoming = socket.recv() => {
                let reply = match incoming {
                    Some(Ok(Message::Text(text))) => match protocol::decode(&text) {
                        Ok(Request::Render(view)) => {
                            // On a thread of its own: this page waits, the others do not.
                            let (shared, wanted) = (shared.clone(), shared.desk.wanted.lock().unwrap_or_else(std::sync::PoisonError::into_inner).clone());
                            tokio::task::spawn_blocking(move || render_view(&shared, view, &wanted)).await.ok()
                        }
                        _ => answer(&shared, &text),
                    },
                    Some(Ok(Message::Binary(_))) => Some(error("binary messages are not requests")),
                    Some(Ok(_)) => None, // pings, pongs
                    Some(Err(_)) | None => return,
                };
                if let Some(r) = reply && socket.send(Message::Text(r.into())).await.is_err() {
                    return;
                }
            }
        }
    }
}

async fn send_solved(socket: &mut WebSocket, s: &Solved) -> Result<(), axum::Error> {
    socket.send(Message::Text(s.status.clone().into())).await?;
    if !s.radiance.is_empty() {
        socket.send(Message::Binary(s.radiance.clone().into())).await?;
    }
    Ok(())
}

fn error(message: impl std::fmt::Display) -> String {
    serde_json::json!({ "type": "error", "message": message.to_string() }).to_string()
}

/// Applies one request; the answer to send (changes are answered by the
/// solution every page receives).
fn answer(shared: &Shared, text: &str) -> Option<String> {
    let request = match protocol::decode(text) {
        Ok(r) => r,
        Err(e) => return Some(error(e)),
    };
    let mut wanted = shared.desk.wanted.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let frames = shared.archive.view().sequence.map_or(1, |s| s.frames());
    match request {
        Request::Save => {
            return Some(serde_json::json!({ "type": "saved", "toml": wanted.sets.toml() }).to_string());
        }
        Request::Set { target, value } => {
            let sets = wanted.sets.with(&target, value);
            if let Err(e) = solver::lighting(&shared.archive, &sets) {
                return Some(error(format!("{e:#}")));
            }
            wanted.sets = sets;
        }
        Request::Frame(f) if f >= frames => {
            return Some(error(format!("frame {f}: the archive has {frames} frame(s)")));
        }
        Request::Frame(f) => wanted.frame = f,
        Request::Reset => wanted.sets = Sets::default(),
        Request::Render(_) => return Some(error("render: answered by the connection")),
    }
    wanted.version += 1;
    shared.desk.changed.notify_one();
    None
}

/// The scene as the page needs it: surfaces (names, light, reflectance),
/// frames, patches, the camera.
fn scene_message(archive: &Archive) -> String {
    let v = archive.view();
    let meta = archive.meta();
    let lighting = illumnet::distribute::Lighting::from_view(&v);
    let surfaces: Vec<_> = meta
        .surface_names
        .iter()
        .enumerate()
        .map(|(s, name)| {
            serde_json::json!({
                "name": name,
                "material": meta.material_names[v.surfaces[s].material as usize],
                "emission": lighting.emission[s],
                "reflectance": lighting.reflectance[s],
                "specular": lighting.specular[s],
            })
        })
        .collect();
    let c = v.camera;
    serde_json::json!({
        "type": "scene",
        "surfaces": surfaces,
        "frames": v.sequence.map_or(1, |s| s.frames()),
        "patches": v.patch_count(),
        "camera": { "position": c.position, "look_at": c.look_at, "up": c.up, "fov_y_deg": c.fov_y_deg,
                    "width": c.width, "height": c.height },
    })
    .to_string()
}
