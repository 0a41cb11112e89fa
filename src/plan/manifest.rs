//! The manifest of `brdfpack build` (docs/build.md): TOML, or JSON when the text starts with
//! `{`. A list of materials, each with a source, optional grid, budget, codec and scene, and
//! its outputs (any table format, by extension). Relative paths are relative to the working
//! directory, as on the command line (the directory Make or Ninja runs in).

use super::scene::Scene;
use crate::reads::ReadSet;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// A whole manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Values a material takes when it does not set them.
    #[serde(default)]
    pub defaults: Defaults,
    #[serde(rename = "material")]
    pub materials: Vec<Material>,
}

/// Manifest-wide defaults of the optional material fields.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Defaults {
    pub grid: Option<String>,
    pub codec: Option<String>,
    pub max_error: Option<String>,
    pub effort: Option<String>,
    pub scene: Option<SceneRef>,
}

/// A scene: a file (TOML or JSON) or written inline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum SceneRef {
    File(PathBuf),
    Inline(Scene),
}

/// One material.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// Unique name: the summary's key and the cache entry's.
    pub name: String,
    /// A model spec (`ggx:alpha=0.2`, `@spec.json`) or a table / measured file.
    pub source: String,
    /// Grid spec (default: the source's default grid, as `pack` chooses it).
    pub grid: Option<String>,
    /// Native codec (`lossless`, `dct:step=0.05`...); exclusive with `max_error`.
    pub codec: Option<String>,
    /// Error budget of the native file against the source (the smallest file meeting it).
    pub max_error: Option<String>,
    /// Planner effort with `max_error`: fast, default or max.
    pub effort: Option<String>,
    pub scene: Option<SceneRef>,
    /// Files to write; the format from the extension (.bpk, .exr, .binary, .mbsdf).
    pub outputs: Vec<PathBuf>,
    /// Sample an anisotropic source on an isotropic grid (as `--allow-anisotropic`).
    #[serde(default)]
    pub allow_anisotropic: bool,
    /// Sample a non-reciprocal source on halfdiff3 (as `--allow-nonreciprocal`).
    #[serde(default)]
    pub allow_nonreciprocal: bool,
    /// Clamp a measured source's negative values to 0 (as `--clamp-negative`).
    #[serde(default)]
    pub clamp_negative: bool,
}

impl Manifest {
    /// Reads and checks a manifest file, recording it in `reads`.
    pub fn load(path: &Path, reads: &mut ReadSet) -> Result<Manifest> {
        let bytes = crate::io::atomic::read_input(path)?;
        reads.record(path);
        let text = std::str::from_utf8(&bytes)
            .map_err(|_| Error::invalid_file(path, "a manifest must be UTF-8 text"))?;
        Manifest::parse(text, &path.display().to_string())
    }

    /// Parses manifest text (TOML, or JSON when it starts with `{`); `name` is for messages.
    pub fn parse(text: &str, name: &str) -> Result<Manifest> {
        let mut m: Manifest = if text.trim_start().starts_with('{') {
            crate::text::reject_duplicate_json_keys(text.as_bytes())
                .map_err(|e| Error::input(format!("manifest {name}: {e}")))?;
            serde_json::from_str(text).map_err(|e| Error::input(format!("manifest {name}: {e}")))?
        } else {
            toml::from_str(text).map_err(|e| {
                Error::input(format!("manifest {name}: {}", e.to_string().trim_end()))
            })?
        };
        m.apply_defaults();
        m.validate(name)?;
        Ok(m)
    }

    fn apply_defaults(&mut self) {
        let d = self.defaults.clone();
        for m in &mut self.materials {
            if m.codec.is_none() && m.max_error.is_none() {
                m.codec = d.codec.clone();
                m.max_error = d.max_error.clone();
            }
            m.grid = m.grid.take().or(d.grid.clone());
            m.effort = m.effort.take().or(d.effort.clone());
            m.scene = m.scene.take().or(d.scene.clone());
        }
    }

    fn validate(&self, name: &str) -> Result<()> {
        if self.materials.is_empty() {
            return Err(Error::input(format!(
                "manifest {name}: no [[material]] (each needs name, source and outputs)"
            )));
        }
        let mut outputs: Vec<&Path> = Vec::new();
        for (i, m) in self.materials.iter().enumerate() {
            let at = format!("manifest {name}: material {:?}", m.name);
            if m.name.is_empty() || m.name.contains(['/', '\\']) || m.name.starts_with('.') {
                return Err(Error::input(format!(
                    "{at}: name must be non-empty, without / or \\ and not start with ."
                )));
            }
            if self.materials[..i].iter().any(|o| o.name == m.name) {
                return Err(Error::input(format!("{at}: the name is used twice")));
            }
            if m.codec.is_some() && m.max_error.is_some() {
                return Err(Error::input(format!(
                    "{at}: codec and max_error are both given; a budget chooses the codec"
                )));
            }
            if m.outputs.is_empty() {
                return Err(Error::input(format!("{at}: outputs is empty")));
            }
            for o in &m.outputs {
                match crate::io::FormatName::from_path(o) {
                    Some(crate::io::FormatName::Rgl) | None => {
                        return Err(Error::input(format!(
                            "{at}: output {}: use .bpk, .exr, .binary or .mbsdf",
                            o.display()
                        )));
                    }
                    Some(_) => {}
                }
                if outputs.contains(&o.as_path()) {
                    return Err(Error::input(format!(
                        "{at}: output {} is written by two materials",
                        o.display()
                    )));
                }
                outputs.push(o);
            }
            if let Some(SceneRef::Inline(s)) = &m.scene {
                s.validate(&at)?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOML: &str = r#"
[defaults]
max_error = "log_rmse=0.01,p99_rel_core=0.2"

[[material]]
name = "gold"
source = "ggx:alpha=0.2,fresnel=au"
outputs = ["gold.bpk", "gold.exr"]

[[material]]
name = "white"
source = "lambert:albedo=0.8"
codec = "lossless"
scene = { theta_i_max = 60, theta_o_max = 60, channels = "luminance" }
outputs = ["white.bpk"]
"#;

    #[test]
    fn toml_and_json_manifests_agree() {
        let t = Manifest::parse(TOML, "t").unwrap();
        assert_eq!(t.materials.len(), 2);
        // The default budget applies where no codec is set.
        assert_eq!(
            t.materials[0].max_error.as_deref(),
            Some("log_rmse=0.01,p99_rel_core=0.2")
        );
        assert_eq!(t.materials[1].max_error, None);
        let json = serde_json::to_string(&t).unwrap();
        assert_eq!(Manifest::parse(&json, "j").unwrap(), t);
    }

    #[test]
    fn refuses_bad_manifests() {
        let dup = TOML.replace("name = \"white\"", "name = \"gold\"");
        assert!(
            Manifest::parse(&dup, "d")
                .unwrap_err()
                .to_string()
                .contains("twice")
        );
        let bad = TOML.replace("white.bpk", "white.png");
        assert!(Manifest::parse(&bad, "b").is_err());
        let unknown = TOML.replace("codec = \"lossless\"", "codek = \"lossless\"");
        assert!(Manifest::parse(&unknown, "u").is_err());
        assert!(Manifest::parse("", "e").is_err());
    }
}
