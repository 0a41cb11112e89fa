//! What a scene needs from a material (`--scene FILE` and the matching flags): the θ range
//! of light and view, the channels (`rgb`, `luminance`, a subset of named channels, a band of
//! wavelengths), isotropy and the error budget. The tool then stores only that domain (the
//! grid's `theta-max`, so cells outside are invalid, checks sample inside and `eval` refuses
//! outside) and those channels (the source seen through [`SceneSource`]), and reports what
//! was dropped.

use crate::brdf::{Brdf, Channels};
use crate::geometry::Vec3;
use crate::grid::Grid;
use crate::reads::ReadSet;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Rec. 709 / sRGB luminance weights (ITU-R BT.709-6, item 3.2).
pub const LUMINANCE_WEIGHTS: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// A scene's needs, as written in a scene file (TOML or JSON) or given by flags.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Largest angle of the light direction from the normal, in degrees (θi ≤ this).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_i_max: Option<f64>,
    /// Largest angle of the view direction from the normal, in degrees (θo ≤ this).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_o_max: Option<f64>,
    /// `rgb`, `luminance`, channel names separated by `/` (`R/G`), or a band `400-700nm`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channels: Option<String>,
    /// The scene only needs an isotropic material (an anisotropic source may be sampled on
    /// an isotropic grid, at φ = 0; recorded in the file).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub isotropic: Option<bool>,
    /// Error budget (`log_rmse=0.01,p99_rel_core=0.2`) when the command is given none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_error: Option<String>,
}

/// What a scene left out, for reports.
#[derive(Clone, Debug, Serialize)]
pub struct SceneReport {
    /// The stored domain, e.g. `θi ≤ 60°, θo ≤ 60°` (`full hemisphere` when unrestricted).
    pub domain: String,
    pub channels_in: Vec<String>,
    pub channels_kept: Vec<String>,
    /// Grid cells outside the domain (stored as invalid, no values) and in all.
    pub cells_dropped: usize,
    pub cells: usize,
    /// Stored values kept / values of the full table (all cells, all source channels).
    pub values_kept_fraction: f64,
}

impl Scene {
    /// Reads a scene file: JSON when it starts with `{`, TOML otherwise. Records it in `reads`.
    pub fn load(path: &Path, reads: &mut ReadSet) -> Result<Scene> {
        let bytes = crate::io::atomic::read_input(path)?;
        reads.record(path);
        let text = std::str::from_utf8(&bytes)
            .map_err(|_| Error::invalid_file(path, "a scene file must be UTF-8 text"))?;
        Scene::parse(text, &path.display().to_string())
    }

    /// Parses scene text (JSON or TOML); `name` is for messages.
    pub fn parse(text: &str, name: &str) -> Result<Scene> {
        let scene: Scene = if text.trim_start().starts_with('{') {
            crate::text::reject_duplicate_json_keys(text.as_bytes())
                .map_err(|e| Error::input(format!("scene {name}: {e}")))?;
            serde_json::from_str(text).map_err(|e| Error::input(format!("scene {name}: {e}")))?
        } else {
            toml::from_str(text)
                .map_err(|e| Error::input(format!("scene {name}: {}", e.to_string().trim_end())))?
        };
        scene.validate(name)?;
        Ok(scene)
    }

    /// Flags override the file's fields.
    pub fn overridden_by(mut self, flags: &Scene) -> Scene {
        if flags.theta_i_max.is_some() {
            self.theta_i_max = flags.theta_i_max;
        }
        if flags.theta_o_max.is_some() {
            self.theta_o_max = flags.theta_o_max;
        }
        if flags.channels.is_some() {
            self.channels = flags.channels.clone();
        }
        if flags.isotropic.is_some() {
            self.isotropic = flags.isotropic;
        }
        if flags.max_error.is_some() {
            self.max_error = flags.max_error.clone();
        }
        self
    }

    pub fn validate(&self, name: &str) -> Result<()> {
        for (field, v) in [
            ("theta_i_max", self.theta_i_max),
            ("theta_o_max", self.theta_o_max),
        ] {
            if let Some(d) = v
                && !(d > 0.0 && d <= 90.0)
            {
                return Err(Error::input(format!(
                    "scene {name}: {field} = {d} is out of range (0, 90] degrees"
                )));
            }
        }
        if let Some(b) = &self.max_error {
            crate::plan::budget::Budget::parse(b)
                .map_err(|e| Error::input(format!("scene {name}: max_error: {e}")))?;
        }
        Ok(())
    }

    pub fn is_empty(&self) -> bool {
        *self == Scene::default()
    }

    /// The stored θ limit: the grid keeps one limit for both directions, so the larger of
    /// the two (the smaller one is met inside it; checks then cover the stored domain).
    pub fn theta_max_deg(&self) -> Option<f64> {
        match (self.theta_i_max, self.theta_o_max) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (Some(_), None) | (None, Some(_)) => Some(90.0),
            (None, None) => None,
        }
        .filter(|&d| d < 90.0)
    }

    /// `grid` restricted to the scene's θ range (a grid's own tighter limit is kept).
    pub fn restrict_grid(&self, grid: &Grid) -> Result<Grid> {
        let Some(t) = self.theta_max_deg() else {
            return Ok(grid.clone());
        };
        let mut d = grid.desc();
        d.theta_max_deg = Some(d.theta_max_deg.map_or(t, |g| g.min(t)));
        Grid::from_desc(&d)
    }

    /// `src` seen with the scene's channels only, holding values only inside the scene's θ
    /// range (so checks and estimates that respect a source's domain sample only there);
    /// unchanged when the scene restricts neither.
    pub fn restrict_source(&self, src: Box<dyn Brdf>) -> Result<Box<dyn Brdf>> {
        let mix = match self.channels.as_deref() {
            Some(spec) => channel_weights(spec, src.channels())?,
            None => None,
        };
        let theta_max_deg = self.theta_max_deg();
        if mix.is_none() && theta_max_deg.is_none() {
            return Ok(src);
        }
        let mut note = String::new();
        if let Some(t) = theta_max_deg {
            note.push_str(&format!("scene domain θi, θo ≤ {t}°"));
        }
        if let (Some(spec), Some((channels, _))) = (self.channels.as_deref(), &mix) {
            if !note.is_empty() {
                note.push_str("; ");
            }
            note.push_str(&format!(
                "scene channels {spec}: {}",
                channels.names().join(", ")
            ));
        }
        Ok(Box::new(SceneSource {
            cos_theta_max: theta_max_deg.map(|t| t.to_radians().cos() - 1e-12),
            theta_max_deg,
            mix,
            inner: src,
            note,
        }))
    }

    /// What the scene dropped from `full_channels` on `grid` (with its `valid` cells).
    pub fn report(
        &self,
        full_channels: &Channels,
        kept: &Channels,
        grid: &Grid,
        valid: usize,
    ) -> SceneReport {
        let domain = match (self.theta_i_max, self.theta_o_max, grid.theta_max_deg()) {
            (None, None, None) => "full hemisphere".to_string(),
            (a, b, stored) => format!(
                "θi ≤ {}°, θo ≤ {}° (stored: θi, θo ≤ {}°)",
                a.unwrap_or(90.0),
                b.unwrap_or(90.0),
                stored.unwrap_or(90.0)
            ),
        };
        let cells = grid.cells();
        SceneReport {
            domain,
            channels_in: full_channels.names().to_vec(),
            channels_kept: kept.names().to_vec(),
            cells_dropped: cells - valid.min(cells),
            cells,
            values_kept_fraction: (valid * kept.len()) as f64
                / (cells * full_channels.len()).max(1) as f64,
        }
    }
}

/// The kept channels and, per kept channel, its weights over the source's channels; `None`
/// when the spec keeps every channel unchanged.
fn channel_weights(spec: &str, src: &Channels) -> Result<Option<(Channels, Vec<Vec<f64>>)>> {
    let names = src.names();
    let n = names.len();
    let unit = |i: usize| {
        let mut w = vec![0.0; n];
        w[i] = 1.0;
        w
    };
    let spec = spec.trim();
    match spec {
        "all" => return Ok(None),
        "rgb" => {
            return if n == 3 && crate::spectral::require_rgb(src, "").is_ok() {
                Ok(None)
            } else {
                Err(Error::input(format!(
                    "scene channels = rgb: the source's channels are {} (use --to-rgb for \
                     spectral sources)",
                    names.join(", ")
                )))
            };
        }
        "luminance" | "Y" => {
            if n == 1 {
                return Ok(None);
            }
            if n != 3 || crate::spectral::is_spectral(src) {
                return Err(Error::input(format!(
                    "scene channels = luminance needs an RGB source; this one has {}",
                    names.join(", ")
                )));
            }
            return Ok(Some((
                Channels::default_for(1),
                vec![LUMINANCE_WEIGHTS.to_vec()],
            )));
        }
        _ => {}
    }
    if let Some(band) = spec.strip_suffix("nm") {
        let Some(w) = src.wavelengths_nm() else {
            return Err(Error::input(format!(
                "scene channels = {spec}: a band of wavelengths needs a spectral source"
            )));
        };
        let bad = || {
            Error::input(format!(
                "scene channels = {spec}: expected a band LO-HInm, e.g. 400-700nm"
            ))
        };
        let (lo, hi) = band.split_once('-').ok_or_else(bad)?;
        let lo: f64 = lo.trim().parse().map_err(|_| bad())?;
        let hi: f64 = hi.trim().parse().map_err(|_| bad())?;
        let keep: Vec<usize> = (0..n).filter(|&i| w[i] >= lo && w[i] <= hi).collect();
        if keep.is_empty() {
            return Err(Error::input(format!(
                "scene channels = {spec}: no channel of the source lies in the band"
            )));
        }
        let channels = Channels::named(
            keep.iter().map(|&i| names[i].clone()).collect(),
            Some(keep.iter().map(|&i| w[i]).collect()),
        )?;
        return Ok(Some((channels, keep.into_iter().map(unit).collect())));
    }
    let mut keep = Vec::new();
    for name in spec.split('/') {
        let Some(i) = names.iter().position(|n| n == name.trim()) else {
            return Err(Error::input(format!(
                "scene channels = {spec}: the source has no channel {name:?} (it has {}; or \
                 rgb, luminance, LO-HInm)",
                names.join(", ")
            )));
        };
        keep.push(i);
    }
    if keep.len() == n && keep.iter().enumerate().all(|(k, &i)| k == i) {
        return Ok(None);
    }
    let channels = Channels::named(
        keep.iter().map(|&i| names[i].clone()).collect(),
        src.wavelengths_nm()
            .map(|w| keep.iter().map(|&i| w[i]).collect()),
    )?;
    Ok(Some((channels, keep.into_iter().map(unit).collect())))
}

/// A source seen through a scene: each kept channel a weighted sum of the source's, and
/// values only inside the scene's θ range.
pub struct SceneSource {
    inner: Box<dyn Brdf>,
    /// The kept channels and their weights over the source's (None: all, unchanged).
    mix: Option<(Channels, Vec<Vec<f64>>)>,
    theta_max_deg: Option<f64>,
    cos_theta_max: Option<f64>,
    note: String,
}

impl SceneSource {
    fn mix(&self, full: &[f64], out: &mut [f64]) {
        match &self.mix {
            Some((_, weights)) => {
                for (o, w) in out.iter_mut().zip(weights) {
                    *o = w.iter().zip(full).map(|(a, b)| a * b).sum();
                }
            }
            None => out.copy_from_slice(full),
        }
    }
}

impl Brdf for SceneSource {
    fn is_sampled(&self) -> bool {
        self.inner.is_sampled()
    }

    fn channels(&self) -> &Channels {
        match &self.mix {
            Some((c, _)) => c,
            None => self.inner.channels(),
        }
    }
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        let mut full = vec![0.0; self.inner.channels().len()];
        self.inner.eval(wi, wo, &mut full);
        self.mix(&full, out);
    }
    fn is_isotropic(&self) -> bool {
        self.inner.is_isotropic()
    }
    fn is_reciprocal(&self) -> bool {
        self.inner.is_reciprocal()
    }
    fn describe(&self) -> String {
        format!("{} ({})", self.inner.describe(), self.note)
    }
    fn provenance_notes(&self) -> Vec<String> {
        let mut notes = self.inner.provenance_notes();
        notes.push(self.note.clone());
        notes
    }
    fn specular_coefficient(&self, wi: Vec3) -> Option<Vec<f64>> {
        let full = self.inner.specular_coefficient(wi)?;
        let mut out = vec![0.0; self.channels().len()];
        self.mix(&full, &mut out);
        Some(out)
    }
    fn series_terms_max(&self) -> Option<usize> {
        self.inner.series_terms_max()
    }
    fn in_domain(&self, wi: Vec3, wo: Vec3) -> bool {
        let inside = match self.cos_theta_max {
            Some(c) => wi.z >= c && wo.z >= c,
            None => true,
        };
        inside && self.inner.in_domain(wi, wo)
    }
    fn theta_max_deg(&self) -> Option<f64> {
        match (self.theta_max_deg, self.inner.theta_max_deg()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
    /// The model's structured fast paths when the channels are the model's own (the grid
    /// carries the θ limit there).
    fn as_any(&self) -> Option<&dyn std::any::Any> {
        if self.mix.is_none() {
            self.inner.as_any()
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Model;

    #[test]
    fn toml_and_json_scenes_parse_alike() {
        let t = Scene::parse(
            "theta_i_max = 60\ntheta_o_max = 45\nchannels = \"luminance\"\n",
            "t",
        )
        .unwrap();
        let j = Scene::parse(
            r#"{"theta_i_max": 60, "theta_o_max": 45, "channels": "luminance"}"#,
            "j",
        )
        .unwrap();
        assert_eq!(t, j);
        assert_eq!(t.theta_max_deg(), Some(60.0));
        assert!(Scene::parse("theta_i_max = 100\n", "x").is_err());
        assert!(Scene::parse("colour = 1\n", "x").is_err());
    }

    #[test]
    fn luminance_is_the_rec709_sum() {
        let src: Box<dyn Brdf> = Box::new(Model::parse("lambert:albedo=0.8/0.5/0.2").unwrap());
        let scene = Scene {
            channels: Some("luminance".into()),
            ..Scene::default()
        };
        let s = scene.restrict_source(src).unwrap();
        let mut out = [0.0];
        s.eval(Vec3::Z, Vec3::Z, &mut out);
        let want = (0.2126 * 0.8 + 0.7152 * 0.5 + 0.0722 * 0.2) / std::f64::consts::PI;
        assert!((out[0] - want).abs() < 1e-15, "{} vs {want}", out[0]);
        assert_eq!(s.channels().names(), ["Y"]);
    }

    #[test]
    fn a_subset_keeps_named_channels() {
        let src: Box<dyn Brdf> = Box::new(Model::parse("lambert:albedo=0.8/0.5/0.2").unwrap());
        let scene = Scene {
            channels: Some("B/R".into()),
            ..Scene::default()
        };
        let s = scene.restrict_source(src).unwrap();
        let mut out = [0.0; 2];
        s.eval(Vec3::Z, Vec3::Z, &mut out);
        let pi = std::f64::consts::PI;
        assert_eq!(out, [0.2 / pi, 0.8 / pi]);
        assert!(
            Scene {
                channels: Some("Q".into()),
                ..Scene::default()
            }
            .restrict_source(Box::new(Model::parse("lambert:albedo=0.5").unwrap()))
            .is_err()
        );
    }
}
