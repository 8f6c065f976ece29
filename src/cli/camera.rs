//! Render-time cameras: any view from one archive. The I-net holds no
//! camera of its own (the archive's is where the build was told to look),
//! so `render` may look from anywhere: a camera read from a file
//! (`--camera-from`), a walkthrough along a path (`--camera-path`), and any
//! of its fields set on the command line.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use illumnet::archive::layout::CameraRecord;
use illumnet::scene::CameraPath;

use super::exit::BadInput;

/// `render`'s camera options.
#[derive(Args, Debug, Clone, Default)]
pub struct CameraArgs {
    /// Look through the camera of FILE instead of the archive's: a scene
    /// file's `[camera]` (its keyframes, if any, followed over the frames
    /// rendered; over `[gltf]`, completed from the glTF file's camera), a
    /// file of a `[camera]` table alone, or a glTF file's first camera.
    #[arg(long, value_name = "FILE", conflicts_with = "camera_path")]
    camera_from: Option<PathBuf>,
    /// A walkthrough: render the frames of the camera path in FILE (a
    /// `[camera]` with `keyframes` and `[animation] frames`, as in a scene
    /// file). Over a still archive the light is solved once and every
    /// frame reuses it; over a sequence, path frame k shows frame k.
    #[arg(long, value_name = "FILE")]
    camera_path: Option<PathBuf>,
    /// Camera position, e.g. `0.5,0.3,-1` (replaces the camera's).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_point, allow_hyphen_values = true)]
    camera_position: Option<[f32; 3]>,
    /// Point the camera looks at.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_point, allow_hyphen_values = true)]
    look_at: Option<[f32; 3]>,
    /// Camera up vector.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_point, allow_hyphen_values = true)]
    up: Option<[f32; 3]>,
    /// Vertical field of view, degrees in (0, 180).
    #[arg(long, value_name = "DEG")]
    fov: Option<f32>,
    /// Image size in pixels, e.g. `640x480` (each side 1..=16384).
    #[arg(long, value_name = "WxH", value_parser = parse_image_size)]
    size: Option<(u32, u32)>,
}

fn parse_point(s: &str) -> Result<[f32; 3], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let numbers: Vec<f32> = parts
        .iter()
        .map(|p| p.parse::<f32>().map_err(|_| format!("`{p}` is not a number (expected X,Y,Z, like 0.5,1,-2)")))
        .collect::<Result<_, _>>()?;
    match numbers[..] {
        [x, y, z] if numbers.iter().all(|v| v.is_finite()) => Ok([x, y, z]),
        [_, _, _] => Err("coordinates must be finite".into()),
        _ => Err(format!("expected three numbers X,Y,Z, got {}", numbers.len())),
    }
}

fn parse_image_size(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("expected WIDTHxHEIGHT in pixels, like 640x480, got `{s}`");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    // (The sides' range is checked with the other cameras' values, in
    // `RenderCameras::new`: a value of the right form out of its range
    // is bad input, exit 3, not a usage error.)
    Ok((w.trim().parse::<u32>().map_err(|_| bad())?, h.trim().parse::<u32>().map_err(|_| bad())?))
}

/// The cameras a render looks through, resolved from [`CameraArgs`].
#[derive(Debug, Clone, Default)]
pub struct RenderCameras {
    path: Option<CameraPath>,
    walkthrough: bool,
    args: CameraArgs,
}

impl RenderCameras {
    /// Reads the camera files the options name (errors name the file,
    /// line and field).
    pub fn new(args: &CameraArgs) -> Result<Self> {
        let read = |p: &Path| CameraPath::from_file(p).map_err(anyhow::Error::new);
        let (path, walkthrough) = match (&args.camera_from, &args.camera_path) {
            (Some(f), _) => (Some(read(f)?), false),
            (None, Some(f)) => (Some(read(f)?), true),
            (None, None) => (None, false),
        };
        if let Some(fov) = args.fov
            && !(fov > 0.0 && fov < 180.0)
        {
            return Err(anyhow::Error::new(BadInput(format!("--fov must be in (0, 180) degrees, got {fov}"))));
        }
        if let Some((w, h)) = args.size
            && !((1..=16384).contains(&w) && (1..=16384).contains(&h))
        {
            return Err(anyhow::Error::new(BadInput(format!(
                "--size: each side must be 1..=16384 pixels, got {w}x{h}"
            ))));
        }
        Ok(Self { path, walkthrough, args: args.clone() })
    }

    /// Whether any camera option was given (else the archive's cameras).
    pub fn given(&self) -> bool {
        let a = &self.args;
        self.path.is_some()
            || a.camera_position.is_some()
            || a.look_at.is_some()
            || a.up.is_some()
            || a.fov.is_some()
            || a.size.is_some()
    }

    /// Frames of a walkthrough (`--camera-path`): what `render` renders
    /// when `--frames` does not say.
    pub fn walkthrough_frames(&self) -> Option<u32> {
        self.path.as_ref().filter(|_| self.walkthrough).map(|p| p.frames)
    }

    /// The camera of output frame `frame`, given the archive's camera for
    /// it: the file's (at that frame), then each field given on the
    /// command line; refused when it cannot make rays.
    pub fn at(&self, archive: CameraRecord, frame: u32) -> Result<CameraRecord> {
        let mut c = archive;
        if let Some(p) = &self.path {
            let k = p.at(frame);
            c = CameraRecord {
                position: k.position.to_array(),
                look_at: k.look_at.to_array(),
                up: k.up.to_array(),
                fov_y_deg: k.fov_y_deg,
                width: k.width,
                height: k.height,
            };
        }
        let a = &self.args;
        c.position = a.camera_position.unwrap_or(c.position);
        c.look_at = a.look_at.unwrap_or(c.look_at);
        c.up = a.up.unwrap_or(c.up);
        c.fov_y_deg = a.fov.unwrap_or(c.fov_y_deg);
        if let Some((w, h)) = a.size {
            (c.width, c.height) = (w, h);
        }
        if !illumnet::limits::camera_is_usable(c.position, c.look_at, c.up) {
            return Err(anyhow::Error::new(BadInput(format!(
                "the camera of frame {frame} (position {:?}, look_at {:?}, up {:?}) can make no rays: look_at must \
                 differ from the position, up must not lie along the view, and coordinates must be within ±1e9 m",
                c.position, c.look_at, c.up
            ))));
        }
        Ok(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_and_sizes_parse_or_say_why_not() {
        assert_eq!(parse_point("0.5, 1,-2").unwrap(), [0.5, 1.0, -2.0]);
        assert!(parse_point("1,2").unwrap_err().contains("three numbers"));
        assert!(parse_point("1,x,2").unwrap_err().contains("`x` is not a number"));
        assert!(parse_point("1,inf,2").unwrap_err().contains("finite"));
        assert_eq!(parse_image_size("640x480").unwrap(), (640, 480));
        assert!(parse_image_size("640").unwrap_err().contains("WIDTHxHEIGHT"));
        assert_eq!(parse_image_size("0x10").unwrap(), (0, 10));
    }

    #[test]
    fn fields_given_replace_the_archives() {
        let archive = CameraRecord {
            position: [0.0, 0.0, -1.0],
            look_at: [0.0; 3],
            up: [0.0, 1.0, 0.0],
            fov_y_deg: 40.0,
            width: 8,
            height: 8,
        };
        let none = RenderCameras::new(&CameraArgs::default()).unwrap();
        assert!(!none.given());
        assert_eq!(none.at(archive, 3).unwrap(), archive);
        let args = CameraArgs { look_at: Some([1.0, 0.0, 0.0]), size: Some((32, 16)), ..Default::default() };
        let c = RenderCameras::new(&args).unwrap().at(archive, 0).unwrap();
        assert_eq!((c.look_at, c.width, c.height, c.position), ([1.0, 0.0, 0.0], 32, 16, archive.position));
        // Looking along up: refused.
        let args = CameraArgs { look_at: Some([0.0, 5.0, -1.0]), ..Default::default() };
        assert!(RenderCameras::new(&args).unwrap().at(archive, 0).is_err());
        assert!(RenderCameras::new(&CameraArgs { fov: Some(180.0), ..Default::default() }).is_err());
    }
}
