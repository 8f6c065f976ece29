//! `render --set`: relighting without a rebuild. Emission, reflectance
//! and a glossy material's specular colour are inputs of the distribution,
//! not of the links, so they change per render; what shapes the
//! reflectance tables is refused with the advice to rebuild.

use anyhow::Result;
use clap::Args;
use illumnet::archive::{self, Archive};
use illumnet::distribute;
use illumnet::limits::MAX_RADIANCE;

use crate::cli::exit::{InputContext, bail_input};

/// Relighting without a rebuild (repeatable): `SURFACE.emission=R,G,B`,
/// `SURFACE.reflectance=R,G,B` or `MATERIAL.reflectance=R,G,B`.
#[derive(Args, Clone, Default)]
pub struct RelightArgs {
    /// Change a surface's emitted radiance, or a surface's or material's
    /// reflectance (`.reflectance`) or a glossy one's `k_s` (`.specular`,
    /// each in [0, 1]), e.g. `--set light.emission=20,15,5`.
    #[arg(long = "set", value_name = "NAME.FIELD=R,G,B")]
    pub set: Vec<String>,
    /// Read `--set` values from a TOML file, `set = ["NAME.FIELD=R,G,B",
    /// …]` (what `illumnet serve` saves); `--set` values given too are
    /// applied after them.
    #[arg(long, value_name = "FILE.toml")]
    pub set_file: Option<std::path::PathBuf>,
}

impl RelightArgs {
    /// Every `--set` value: the file's, then the command line's.
    pub fn all(&self) -> Result<Vec<String>> {
        let Some(path) = &self.set_file else { return Ok(self.set.clone()) };
        #[derive(serde::Deserialize)]
        #[serde(deny_unknown_fields)]
        struct SetFile {
            set: Vec<String>,
        }
        let text = std::fs::read_to_string(path)
            .map_err(|e| crate::cli::exit::IoFailure(format!("--set-file {}: {e}", path.display())))?;
        let file: SetFile = toml::from_str(&text)
            .map_err(|e| crate::cli::exit::BadInput(format!("--set-file {}: {e}", path.display())))?;
        Ok(file.set.into_iter().chain(self.set.iter().cloned()).collect())
    }
}

/// Applies `--set NAME.FIELD=R,G,B` changes to `lighting`.
pub fn relight(lighting: &mut distribute::Lighting, archive: &Archive, sets: &[String]) -> Result<()> {
    let meta = archive.meta();
    let materials = archive.view().surfaces.iter().map(|s| s.material as usize).collect::<Vec<_>>();
    for set in sets {
        let (target, value) = set.split_once('=').input(|| format!("--set `{set}`: expected NAME.FIELD=R,G,B"))?;
        let (name, field) = target.rsplit_once('.').input(|| format!("--set `{set}`: expected NAME.FIELD=R,G,B"))?;
        // Fields fixed at build time, or not fields at all: say so before
        // judging the value.
        match field {
            "emission" | "reflectance" | "specular" => {}
            "alpha" | "alpha_u" | "alpha_v" | "ior" | "type" => bail_input!(
                "--set `{set}`: `{field}` shapes the material's reflectance tables, which are built into the \
                 archive: change it in the scene and rebuild (--set changes emission, reflectance and specular)"
            ),
            _ => bail_input!(
                "--set `{set}`: unknown field `{field}`: --set changes SURFACE.emission, SURFACE.reflectance or \
                 MATERIAL.reflectance, and .specular of glossy materials"
            ),
        }
        let v: Vec<f32> = value
            .split(',')
            .map(|x| x.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .ok()
            .filter(|v: &Vec<f32>| v.len() == 3 && v.iter().all(|x| x.is_finite()))
            .input(|| format!("--set `{set}`: the value must be three numbers R,G,B"))?;
        let rgb = [v[0], v[1], v[2]];
        let surface = meta.surface_names.iter().position(|s| s == name);
        let material = meta.material_names.iter().position(|m| m == name);
        match field {
            "emission" => {
                let s = surface.input(|| {
                    format!("--set `{set}`: no surface named `{name}` (surfaces: {})", meta.surface_names.join(", "))
                })?;
                // The scene reader's bound (and the archive's, §7): a larger
                // radiance would be accepted here and blamed on the archive.
                if rgb.iter().any(|&x| !(0.0..=MAX_RADIANCE).contains(&x)) {
                    bail_input!("--set `{set}`: emission must be in [0, {MAX_RADIANCE:e}]");
                }
                lighting.emission[s] = rgb;
                lighting.emission_fixed[s] = true;
            }
            "reflectance" | "specular" => {
                if rgb.iter().any(|&x| !(0.0..=1.0).contains(&x)) {
                    bail_input!("--set `{set}`: {field} components must be in [0, 1]");
                }
                let column = if field == "reflectance" { &mut lighting.reflectance } else { &mut lighting.specular };
                let glossy = |m: usize| archive.view().materials[m].model != archive::layout::model::DIFFUSE;
                if field == "specular"
                    && !surface.map_or_else(|| material.is_some_and(glossy), |s| glossy(materials[s]))
                {
                    bail_input!(
                        "--set `{set}`: `{name}` is diffuse: only rough_conductor and broad_specular materials have a specular colour"
                    );
                }
                match (surface, material) {
                    (Some(s), _) => column[s] = rgb,
                    (None, Some(m)) => {
                        for (s, &sm) in materials.iter().enumerate() {
                            if sm == m {
                                column[s] = rgb;
                            }
                        }
                    }
                    (None, None) => bail_input!(
                        "--set `{set}`: no surface or material named `{name}` (surfaces: {}; materials: {})",
                        meta.surface_names.join(", "),
                        meta.material_names.join(", ")
                    ),
                }
            }
            other => bail_input!("--set `{set}`: unknown field `{other}` (known: emission, reflectance, specular)"),
        }
    }
    for (s, name) in meta.surface_names.iter().enumerate() {
        if !illumnet::limits::conserves_energy(lighting.reflectance[s], lighting.specular[s]) {
            bail_input!(
                "surface `{name}`: reflectance + specular exceeds 1 in some band (the surface would create energy)"
            );
        }
    }
    Ok(())
}
