//! What every BRDF source (analytic model, stored table, measured file) offers the pipeline.

use crate::geometry::Vec3;

/// Names (and, for spectral data, wavelengths) of a BRDF's output channels.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Channels {
    names: Vec<String>,
    /// Wavelength of each channel in nanometres, when the channels are spectral samples.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    wavelengths_nm: Option<Vec<f64>>,
}

impl Channels {
    /// The conventional names for `n` channels: `Y` for one, `R G B` for three,
    /// `c0 c1 ...` otherwise.
    pub fn default_for(n: usize) -> Channels {
        let names = match n {
            1 => vec!["Y".to_string()],
            3 => vec!["R".into(), "G".into(), "B".into()],
            _ => (0..n).map(|i| format!("c{i}")).collect(),
        };
        Channels {
            names,
            wavelengths_nm: None,
        }
    }

    /// Spectral channels named by wavelength (`550nm`).
    pub fn spectral(wavelengths_nm: Vec<f64>) -> Channels {
        let names = wavelengths_nm.iter().map(|w| format!("{w}nm")).collect();
        Channels {
            names,
            wavelengths_nm: Some(wavelengths_nm),
        }
    }

    /// Channels with explicit names; errors when names repeat or are empty.
    pub fn named(names: Vec<String>, wavelengths_nm: Option<Vec<f64>>) -> crate::Result<Channels> {
        if names.is_empty() {
            return Err(crate::Error::input("a table needs at least one channel"));
        }
        // A set, not a scan of the earlier names: a file's header may declare millions of
        // channels, and n² comparisons of them took hours (issue 20 fuzzing).
        let mut seen = std::collections::HashSet::with_capacity(names.len());
        for n in &names {
            if n.is_empty() || !seen.insert(n.as_str()) {
                return Err(crate::Error::input(format!(
                    "channel name {n:?} is empty or repeated"
                )));
            }
        }
        if let Some(w) = &wavelengths_nm {
            if w.len() != names.len() {
                return Err(crate::Error::input(format!(
                    "{} wavelengths given for {} channels",
                    w.len(),
                    names.len()
                )));
            }
            // A file's header may say anything: a wavelength that is no length is refused
            // where the file is read (its reader names the file), not at a later conversion.
            if let Some((i, x)) = w
                .iter()
                .enumerate()
                .find(|(_, x)| !(x.is_finite() && **x > 0.0))
            {
                return Err(crate::Error::input(format!(
                    "wavelength[{i}] = {x:?} nm (channel {:?}); expected a finite value > 0",
                    names[i]
                )));
            }
        }
        Ok(Channels {
            names,
            wavelengths_nm,
        })
    }

    pub fn len(&self) -> usize {
        self.names.len()
    }
    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }
    pub fn names(&self) -> &[String] {
        &self.names
    }
    pub fn wavelengths_nm(&self) -> Option<&[f64]> {
        self.wavelengths_nm.as_deref()
    }
}

/// A BRDF f_r(wi, wo) in 1/sr without the cosine factor, in the local frame
/// (z = normal), both directions pointing away from the surface.
pub trait Brdf: Send + Sync {
    /// The output channels; `eval` writes exactly `channels().len()` values.
    fn channels(&self) -> &Channels;

    /// Evaluates f_r for unit directions `wi`, `wo`, writing one value per channel into
    /// `out`. Implementations return 0 in every channel when `wi.z <= 0` or `wo.z <= 0`
    /// (one-sided; the horizon counts as below) and never write NaN or Inf for finite
    /// unit inputs.
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]);

    /// [`Brdf::eval`] at many pairs: `out[p·C + c]` for pair `p` and channel `c`, the same
    /// bits as one `eval` per pair. Sampled sources override it with their batched lookups
    /// (the albedo quadrature of `check` evaluates a million pairs of a table this way).
    /// Runs on the calling thread: callers are parallel over their own chunks.
    fn eval_pairs(&self, pairs: &[(Vec3, Vec3)], out: &mut [f64]) {
        let c = self.channels().len();
        for (&(wi, wo), f) in pairs.iter().zip(out.chunks_exact_mut(c.max(1))) {
            self.eval(wi, wo, f);
        }
    }

    /// True when f depends on the azimuths only through their difference.
    fn is_isotropic(&self) -> bool;

    /// True when f(wi, wo) = f(wo, wi) is promised (measured data usually is not).
    fn is_reciprocal(&self) -> bool {
        true
    }

    /// A one-line description of the source for provenance and reports.
    fn describe(&self) -> String;

    /// Notes that a table of this source must carry in its provenance: what the source has
    /// that a table cannot hold (e.g. HTSG's specular delta). None by default.
    fn provenance_notes(&self) -> Vec<String> {
        Vec::new()
    }

    /// The coefficient per channel of a Dirac-delta (specular) part for light from `wi`, which
    /// `eval` and tables never include (e.g. HTSG's ρ_s(wi)); None when there is none.
    fn specular_coefficient(&self, _wi: Vec3) -> Option<Vec<f64>> {
        None
    }

    /// For sources evaluated by a series (HTSG): the largest number of series terms summed
    /// over a fixed set of direction pairs; None otherwise.
    fn series_terms_max(&self) -> Option<usize> {
        None
    }

    /// True when the pair lies inside the domain where the source holds values: a table
    /// stored up to θmax has none beyond it (tabulation marks such cells invalid; checks
    /// sample only inside). Models and measured files cover the whole hemisphere.
    fn in_domain(&self, _wi: Vec3, _wo: Vec3) -> bool {
        true
    }

    /// True for a source that is itself samples on a grid (a table, a measured file): it
    /// has values at its own samples only, so re-sampling it on another grid adds the
    /// interpolation of one grid to the other's (planners keep its layout). False for models.
    fn is_sampled(&self) -> bool {
        false
    }

    /// The stored θ limit of the source in degrees (a table's θmax), when it has one.
    fn theta_max_deg(&self) -> Option<f64> {
        None
    }

    /// The concrete source behind this one when a layer above may exploit its structure, to
    /// be downcast there (tabulation's structured microfacet path looks for a
    /// `model::Model`); None by default. The trait stays ignorant of its implementors.
    fn as_any(&self) -> Option<&dyn std::any::Any> {
        None
    }
}
