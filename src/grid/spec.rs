//! The grid spec grammar of the CLI (documented in docs/parameterizations.md):
//!
//! ```text
//! merl[,theta-max=DEG][,horizon=cut|extend]
//! KIND:DIMS[,warp=W[/W...]][,at=center|edge[/...]][,theta-max=DEG][,weight=none|cosine]
//!       [,space=linear|log:S][,horizon=cut|extend]
//! KIND  = spherical4 | spherical3 | halfdiff3 | halfdiff4
//! DIMS  = N | NxNx...            (one N applies to every axis)
//! W     = linear | sqrt | grazing (one value applies to every axis)
//! ```

use super::{Grid, GridKind, Horizon, InterpSpace, InterpWeight, Placement, Warp};
use crate::{Error, Result};

/// Parses a grid spec such as `merl` or `halfdiff4:64,warp=sqrt/linear/linear/linear`.
pub fn parse_grid_spec(spec: &str) -> Result<Grid> {
    let spec = spec.trim();
    if spec == "merl" {
        return Ok(Grid::merl());
    }
    // `merl,theta-max=DEG`: the MERL grid stored up to θmax.
    if let Some(opts) = spec.strip_prefix("merl,") {
        let mut d = Grid::merl().desc();
        for opt in opts.split(',') {
            match opt.split_once('=') {
                Some(("theta-max", v)) => {
                    d.theta_max_deg = Some(v.trim().parse::<f64>().map_err(|_| {
                        Error::input(format!(
                            "grid {spec:?}: theta-max {v:?} is not a number of degrees"
                        ))
                    })?)
                }
                Some(("horizon", "cut")) => d.horizon = Horizon::Cut,
                Some(("horizon", "extend")) => d.horizon = Horizon::Extend,
                _ => {
                    return Err(Error::input(format!(
                        "grid {spec:?}: option {opt:?}: `merl` takes only theta-max=DEG and \
                         horizon=cut|extend (spell the grid out as halfdiff3:90x90x180,... to \
                         change more)"
                    )));
                }
            }
        }
        return Grid::from_desc(&d);
    }
    let (kind_s, rest) = spec.split_once(':').ok_or_else(|| {
        Error::input(format!(
            "grid {spec:?}: expected `merl` or KIND:DIMS (e.g. halfdiff3:90x90x180), KIND one of spherical4, spherical3, halfdiff3, halfdiff4"
        ))
    })?;
    let kind = match kind_s {
        "spherical4" => GridKind::Spherical4,
        "spherical3" => GridKind::Spherical3,
        "halfdiff3" => GridKind::Halfdiff3,
        "halfdiff4" => GridKind::Halfdiff4,
        _ => {
            return Err(Error::input(format!(
                "grid {spec:?}: unknown kind {kind_s:?} (expected spherical4, spherical3, halfdiff3, halfdiff4 or merl)"
            )));
        }
    };
    let d = kind.quantities().len();
    let mut parts = rest.split(',');
    let dims_s = parts.next().unwrap_or("");
    let dims: Vec<usize> = broadcast(dims_s, 'x', d, "resolution", spec)?
        .iter()
        .map(|s| {
            s.parse::<usize>().map_err(|_| {
                Error::input(format!(
                    "grid {spec:?}: resolution {s:?} is not a positive whole number"
                ))
            })
        })
        .collect::<Result<_>>()?;
    let mut warps = vec![Warp::Linear; d];
    let mut placements = vec![Placement::Center; d];
    let mut theta_max = None;
    let mut weight = InterpWeight::None;
    let mut space = InterpSpace::Linear;
    let mut horizon = Horizon::Cut;
    for opt in parts {
        let (k, v) = opt.split_once('=').ok_or_else(|| {
            Error::input(format!("grid {spec:?}: option {opt:?} is not key=value"))
        })?;
        match k {
            "warp" => {
                warps = broadcast(v, '/', d, "warp", spec)?
                    .iter()
                    .map(|w| match *w {
                        "linear" => Ok(Warp::Linear),
                        "sqrt" => Ok(Warp::Sqrt),
                        "grazing" => Ok(Warp::Grazing),
                        _ => Err(Error::input(format!(
                            "grid {spec:?}: warp {w:?} is not linear, sqrt or grazing"
                        ))),
                    })
                    .collect::<Result<_>>()?
            }
            "at" => {
                placements = broadcast(v, '/', d, "at", spec)?
                    .iter()
                    .map(|w| match *w {
                        "center" | "centre" => Ok(Placement::Center),
                        "edge" | "lower-edge" => Ok(Placement::LowerEdge),
                        _ => Err(Error::input(format!(
                            "grid {spec:?}: at={w:?} is not center or edge"
                        ))),
                    })
                    .collect::<Result<_>>()?
            }
            "theta-max" => {
                theta_max = Some(v.parse::<f64>().map_err(|_| {
                    Error::input(format!(
                        "grid {spec:?}: theta-max {v:?} is not a number of degrees"
                    ))
                })?)
            }
            "weight" => {
                weight = match v {
                    "none" => InterpWeight::None,
                    "cosine" => InterpWeight::Cosine,
                    _ => {
                        return Err(Error::input(format!(
                            "grid {spec:?}: weight {v:?} is not none or cosine"
                        )));
                    }
                }
            }
            "space" => space = match v.split_once(':') {
                None if v == "linear" => InterpSpace::Linear,
                Some(("log", s)) => s
                    .parse::<f64>()
                    .ok()
                    .and_then(|s| InterpSpace::log(s).ok())
                    .ok_or_else(|| {
                        Error::input(format!(
                            "grid {spec:?}: space log scale {s:?} is not a finite positive number"
                        ))
                    })?,
                _ => {
                    return Err(Error::input(format!(
                        "grid {spec:?}: space {v:?} is not linear or log:SCALE (e.g. log:0.001)"
                    )));
                }
            },
            "horizon" => {
                horizon = match v {
                    "cut" => Horizon::Cut,
                    "extend" => Horizon::Extend,
                    _ => {
                        return Err(Error::input(format!(
                            "grid {spec:?}: horizon {v:?} is not cut or extend"
                        )));
                    }
                }
            }
            _ => {
                return Err(Error::input(format!(
                    "grid {spec:?}: unknown option {k:?} (expected warp, at, theta-max, weight, \
                     space, horizon)"
                )));
            }
        }
    }
    let axes: Vec<_> = (0..d).map(|k| (dims[k], warps[k], placements[k])).collect();
    Grid::new(kind, &axes, theta_max)?
        .with_weight(weight)
        .with_space(space)
        .with_horizon(horizon)
}

#[cfg(test)]
mod merl_tests {
    use super::*;

    #[test]
    fn merl_takes_theta_max() {
        let g = parse_grid_spec("merl,theta-max=60").unwrap();
        assert_eq!(g.theta_max_deg(), Some(60.0));
        assert_eq!(g.cells(), Grid::merl().cells());
        assert!(parse_grid_spec("merl,warp=linear").is_err());
        assert!(parse_grid_spec("merl,theta-max=abc").is_err());
    }
}

/// Splits `s` on `sep` and broadcasts a single value to `d` axes.
fn broadcast<'a>(s: &'a str, sep: char, d: usize, what: &str, spec: &str) -> Result<Vec<&'a str>> {
    let v: Vec<&str> = s.split(sep).collect();
    match v.len() {
        1 => Ok(vec![v[0]; d]),
        n if n == d => Ok(v),
        n => Err(Error::input(format!(
            "grid {spec:?}: {n} {what} values given, expected 1 or {d}"
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_documented_forms() {
        let g = parse_grid_spec("halfdiff3:90x90x180,warp=sqrt/linear/linear,at=edge").unwrap();
        assert_eq!(g, Grid::merl());
        let g = parse_grid_spec("halfdiff4:32").unwrap();
        assert_eq!(g.shape(), vec![32; 4]);
        let g = parse_grid_spec("spherical4:8x16x8x16,theta-max=80").unwrap();
        assert!((g.theta_max().unwrap() - 80f64.to_radians()).abs() < 1e-15);
    }

    #[test]
    fn the_log_space_parses_prints_and_survives_the_header() {
        let g = parse_grid_spec("halfdiff3:8x8x16,space=log:0.0025").unwrap();
        assert_eq!(g.space(), InterpSpace::Log { scale: 0.0025 });
        assert!(
            g.describe().ends_with("; space log:2.500e-3"),
            "{}",
            g.describe()
        );
        let json = serde_json::to_string(&g.desc()).unwrap();
        assert!(
            json.contains(r#""interp_space":{"log":{"scale":0.0025}}"#),
            "{json}"
        );
        let back: super::super::GridDesc = serde_json::from_str(&json).unwrap();
        assert_eq!(Grid::from_desc(&back).unwrap(), g);
        // A linear grid's header has no field (files written before the space are unchanged).
        let plain = serde_json::to_string(&parse_grid_spec("halfdiff3:8").unwrap().desc()).unwrap();
        assert!(!plain.contains("interp_space"), "{plain}");
        for bad in [
            "log",
            "log:0",
            "log:-1",
            "log:inf",
            "log:nan",
            "cubic",
            "log:1e-400",
        ] {
            let e = parse_grid_spec(&format!("halfdiff3:8,space={bad}")).unwrap_err();
            assert!(e.to_string().contains("space"), "{bad}: {e}");
        }
        // A header cannot smuggle in a scale the parser refuses.
        let mut d = g.desc();
        d.interp_space = InterpSpace::Log { scale: -1.0 };
        assert!(Grid::from_desc(&d).is_err());
    }

    #[test]
    fn theta_max_survives_the_header_description() {
        // 0.21° → rad → deg gives 0.21000000000000002°, whose radians are an ulp off.
        let g = parse_grid_spec("spherical3:4,theta-max=0.21").unwrap();
        assert_eq!(g.desc().theta_max_deg, Some(0.21));
        assert_eq!(Grid::from_desc(&g.desc()).unwrap(), g);
        assert!(
            g.describe().ends_with("theta-max 0.21°"),
            "{}",
            g.describe()
        );
    }

    #[test]
    fn errors_name_the_problem() {
        for (spec, needle) in [
            ("cube:4", "unknown kind"),
            ("halfdiff3:4x4", "2 resolution values"),
            ("halfdiff3:4xAx4", "\"A\""),
            ("halfdiff3:4,warp=log", "\"log\""),
            ("halfdiff3:4,theta-max=100", "theta-max = 100"),
            ("halfdiff3:4,foo=1", "unknown option"),
            ("halfdiff3", "expected `merl`"),
        ] {
            let e = parse_grid_spec(spec).unwrap_err().to_string();
            assert!(e.contains(needle), "{spec}: {e}");
        }
    }
}
