//! What the page may ask of `illumnet serve`, decoded and checked before
//! anything changes: a message is one of a few JSON objects, and a change
//! of the light is a `render --set` value (`NAME.FIELD=R,G,B`), checked by
//! the very code `render --set` runs (`relight`), so that whatever the page
//! can set, the command line can reproduce. A message that is not one of
//! these, or asks for what `render --set` would refuse, is answered with an
//! error and changes nothing.

use serde::Deserialize;

/// The largest message accepted, in bytes (a `set` is under 200).
pub const MAX_MESSAGE: usize = 16 * 1024;

/// A request from the page.
#[derive(Debug, Clone, PartialEq)]
pub enum Request {
    /// Set `target` (`SURFACE.emission`, `NAME.reflectance`,
    /// `NAME.specular`) to an RGB value.
    Set { target: String, value: [f32; 3] },
    /// Show frame `frame` of a sequence.
    Frame(u32),
    /// Back to the archive's own light (every `set` undone).
    Reset,
    /// The `--set` values of the current light, as a file `render
    /// --set-file` reads.
    Save,
    /// A full-quality image of this view (the `render` command's, with
    /// the current light and frame).
    Render(View),
}

/// A camera as the page sends it (checked: finite, a field of view in
/// (0, 180) degrees, 1 to 4096 pixels a side, eye away from the target).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct View {
    pub position: [f32; 3],
    pub look_at: [f32; 3],
    pub up: [f32; 3],
    pub fov_y_deg: f32,
    pub width: u32,
    pub height: u32,
}

/// The JSON shape of a request (`op` says which).
#[derive(Deserialize)]
#[serde(tag = "op", rename_all = "lowercase", deny_unknown_fields)]
enum Wire {
    Set { target: String, value: Vec<f64> },
    Frame { frame: u64 },
    Reset,
    Save,
    Render { camera: View },
}

/// Decodes one text message (the page sends no binary ones).
pub fn decode(text: &str) -> Result<Request, String> {
    if text.len() > MAX_MESSAGE {
        return Err(format!("message of {} bytes: at most {MAX_MESSAGE}", text.len()));
    }
    let wire: Wire = serde_json::from_str(text).map_err(|e| format!("not a request: {e}"))?;
    Ok(match wire {
        Wire::Set { target, value } => {
            if target.len() > 256 || !target.contains('.') || target.contains('=') {
                return Err(format!("set: `{}` is not NAME.FIELD", clip(&target)));
            }
            let rgb: [f64; 3] = value.try_into().map_err(|v: Vec<f64>| format!("set: {} values, not 3", v.len()))?;
            // f32 is what the distribution holds; a value beyond it is no
            // radiance and no reflectance.
            if rgb.iter().any(|x| !x.is_finite() || x.abs() > f32::MAX as f64) {
                return Err("set: the values must be finite numbers".into());
            }
            Request::Set { target, value: rgb.map(|x| x as f32) }
        }
        Wire::Frame { frame } => Request::Frame(u32::try_from(frame).map_err(|_| format!("frame {frame}: too large"))?),
        Wire::Reset => Request::Reset,
        Wire::Save => Request::Save,
        Wire::Render { camera: c } => {
            let numbers = c.position.iter().chain(&c.look_at).chain(&c.up).chain([&c.fov_y_deg]);
            if !numbers.into_iter().all(|x| x.is_finite()) {
                return Err("render: the camera's numbers must be finite".into());
            }
            if !(c.fov_y_deg > 0.0 && c.fov_y_deg < 180.0) {
                return Err(format!("render: field of view {} degrees, not in (0, 180)", c.fov_y_deg));
            }
            if !(1..=4096).contains(&c.width) || !(1..=4096).contains(&c.height) {
                return Err(format!("render: {}x{} pixels: each side 1 to 4096", c.width, c.height));
            }
            let d: f32 = (0..3).map(|k| (c.position[k] - c.look_at[k]).powi(2)).sum();
            if d.sqrt() < 1e-6 * (1.0 + c.position.iter().map(|x| x.abs()).fold(0.0, f32::max)) {
                return Err("render: the camera looks at its own position".into());
            }
            Request::Render(c)
        }
    })
}

/// At most 40 characters of `s`, for messages that quote it.
fn clip(s: &str) -> String {
    s.chars().take(40).collect()
}

/// The light as `--set` values: one per target, in the order first set,
/// a later value replacing an earlier one's.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Sets(pub Vec<(String, [f32; 3])>);

impl Sets {
    /// These values with `target` set to `value`.
    pub fn with(&self, target: &str, value: [f32; 3]) -> Self {
        let mut out = self.clone();
        match out.0.iter_mut().find(|(t, _)| t == target) {
            Some(slot) => slot.1 = value,
            None => out.0.push((target.to_string(), value)),
        }
        out
    }

    /// As `render --set` arguments (`NAME.FIELD=R,G,B`; Rust's shortest
    /// round-trip formatting, so that the values read back are these).
    pub fn args(&self) -> Vec<String> {
        self.0.iter().map(|(t, v)| format!("{t}={},{},{}", v[0], v[1], v[2])).collect()
    }

    /// As a file `render --set-file` reads: `set = ["NAME.FIELD=R,G,B", …]`.
    pub fn toml(&self) -> String {
        let list: Vec<String> = self.args().iter().map(|a| format!("  {a:?},")).collect();
        format!(
            "# `illumnet render ARCHIVE --set-file THIS` relights as `illumnet serve` showed it.\nset = [\n{}\n]\n",
            list.join("\n")
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn requests_decode() {
        assert_eq!(
            decode(r#"{"op":"set","target":"light.emission","value":[20,15.5,5]}"#),
            Ok(Request::Set { target: "light.emission".into(), value: [20.0, 15.5, 5.0] })
        );
        assert_eq!(decode(r#"{"op":"frame","frame":30}"#), Ok(Request::Frame(30)));
        assert_eq!(decode(r#"{"op":"reset"}"#), Ok(Request::Reset));
        assert_eq!(decode(r#"{"op":"save"}"#), Ok(Request::Save));
        let view = r#"{"op":"render","camera":{"position":[0,1,2],"look_at":[0,1,0],"up":[0,1,0],"fov_y_deg":40,"width":64,"height":48}}"#;
        assert!(matches!(decode(view), Ok(Request::Render(View { width: 64, height: 48, .. }))));
        for (bad, says) in [
            (view.replace("40", "180"), "field of view"),
            (view.replace("64", "0"), "each side"),
            (view.replace("[0,1,2]", "[0,1,0]"), "own position"),
            (view.replace(",\"height\":48", ""), "not a request"),
        ] {
            assert!(decode(&bad).unwrap_err().contains(says), "{bad}");
        }
    }

    #[test]
    fn wrong_requests_are_errors_that_say_why() {
        for (text, says) in [
            ("", "not a request"),
            ("[1,2]", "not a request"),
            (r#"{"op":"set","target":"light.emission","value":[1,2]}"#, "2 values"),
            (r#"{"op":"set","target":"light.emission","value":[1,2,"x"]}"#, "not a request"),
            (r#"{"op":"set","target":"light.emission","value":[1,2,1e300]}"#, "finite"),
            (r#"{"op":"set","target":"light","value":[1,2,3]}"#, "NAME.FIELD"),
            (r#"{"op":"set","target":"a.b=c","value":[1,2,3]}"#, "NAME.FIELD"),
            (r#"{"op":"frame","frame":-1}"#, "not a request"),
            (r#"{"op":"frame","frame":99999999999}"#, "too large"),
            (r#"{"op":"frame","frame":1,"extra":2}"#, "not a request"),
            (r#"{"op":"launch"}"#, "not a request"),
        ] {
            let e = decode(text).expect_err(text);
            assert!(e.contains(says), "{text}: {e}");
        }
        assert!(decode(&" ".repeat(MAX_MESSAGE + 1)).unwrap_err().contains("at most"));
    }

    #[test]
    fn sets_replace_their_target_and_print_what_render_reads() {
        let s = Sets::default().with("light.emission", [1.0, 2.0, 3.0]).with("red.reflectance", [0.5, 0.0, 0.0]);
        let s = s.with("light.emission", [2.0, 4.0, 6.0]);
        assert_eq!(s.args(), vec!["light.emission=2,4,6", "red.reflectance=0.5,0,0"]);
        let parsed: toml::Value = toml::from_str(&s.toml()).unwrap();
        let list: Vec<&str> = parsed["set"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
        assert_eq!(list, s.args());
    }

    proptest! {
        /// Random text never panics the decoder, and what it accepts is
        /// bounded.
        #[test]
        fn any_text_decodes_or_is_refused(text in ".{0,200}") {
            if let Ok(Request::Set { value, .. }) = decode(&text) {
                prop_assert!(value.iter().all(|x| x.is_finite()));
            }
        }

        /// JSON of the right shape with any numbers.
        #[test]
        fn any_numbers_decode_or_are_refused(a in any::<f64>(), b in any::<f64>(), f in any::<i64>()) {
            let text = format!(r#"{{"op":"set","target":"x.emission","value":[{a},{b},1]}}"#);
            if let Ok(Request::Set { value, .. }) = decode(&text) {
                prop_assert!(value.iter().all(|x| x.is_finite()));
            }
            let _ = decode(&format!(r#"{{"op":"frame","frame":{f}}}"#));
        }
    }
}
