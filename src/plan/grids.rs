//! The default grid of a source: the grid `pack` starts from when the user gives none
//! ([`super::pack`] refines it from there when the budget asks for more).

use crate::brdf::Brdf;

/// The default grid of a source: its symmetries at about MERL's resolution — `halfdiff4:64`
/// for anisotropic sources, `spherical3:90x90x180` for isotropic non-reciprocal ones (measured
/// data), `merl` otherwise.
pub fn default_grid_spec(src: &dyn Brdf) -> &'static str {
    if !src.is_isotropic() {
        "halfdiff4:64"
    } else if !src.is_reciprocal() {
        "spherical3:90x90x180"
    } else {
        "merl"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::parse_grid_spec;
    use crate::model::Model;

    #[test]
    fn default_grids_follow_the_source_symmetries() {
        for (m, want) in [
            ("ggx:alpha=0.2", "merl"),
            ("lambert", "merl"),
            ("ward:alpha_x=0.1,alpha_y=0.3", "halfdiff4:64"),
        ] {
            let model = Model::parse(m).unwrap();
            let spec = default_grid_spec(&model);
            assert_eq!(spec, want, "{m}");
            parse_grid_spec(spec).unwrap();
        }
    }
}
