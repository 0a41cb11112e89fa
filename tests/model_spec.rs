//! Model specs: the compact and JSON forms agree, canonical JSON round-trips, and every class
//! of bad input is an `Error::Input` naming the parameter and the value.

use brdfpack::Error;
use brdfpack::brdf::Brdf;
use brdfpack::geometry::Vec3;
use brdfpack::model::{Model, listing};
use serde_json::{Value, json};

fn eval(m: &Model, wi: Vec3, wo: Vec3) -> Vec<f64> {
    let mut out = vec![0.0; m.channels().len()];
    m.eval(wi, wo, &mut out);
    out
}

const PAIRS: [(Vec3, Vec3); 3] = [
    (Vec3::new(0.0, 0.0, 1.0), Vec3::new(0.6, 0.0, 0.8)),
    (Vec3::new(0.36, 0.48, 0.8), Vec3::new(-0.48, -0.6, 0.64)),
    (Vec3::new(0.8, 0.0, 0.6), Vec3::new(0.0, 0.6, 0.8)),
];

/// Compact specs and the canonical JSON each must mean.
fn pairs() -> Vec<(&'static str, Value)> {
    vec![
        ("lambert", json!({"model": "lambert", "albedo": 0.5})),
        (
            "lambert:albedo=0.8/0.5/0.2",
            json!({"model": "lambert", "albedo": [0.8, 0.5, 0.2]}),
        ),
        (
            "mirror:albedo=0.9",
            json!({"model": "mirror", "albedo": 0.9}),
        ),
        (
            "phong:albedo=0.9,exponent=1e+3,norm=none",
            json!({"model": "phong", "albedo": 0.9, "exponent": 1000.0, "norm": "none"}),
        ),
        (
            "blinn-phong:exponent=40",
            json!({"model": "blinn-phong", "albedo": 0.5, "exponent": 40.0}),
        ),
        (
            "torrance-sparrow:m=0.2,scale=0.9/0.7/0.5",
            json!({"model": "torrance-sparrow", "m": 0.2,
                   "fresnel": {"type": "dielectric", "ior": 1.5}, "scale": [0.9, 0.7, 0.5]}),
        ),
        (
            "ggx:alpha=0.2,fresnel=au",
            json!({"model": "microfacet", "distribution": "ggx", "alpha": 0.2,
                   "shadowing": "smith-correlated", "g1": "exact",
                   "fresnel": {"type": "conductor", "eta": [0.143, 0.374, 1.442],
                               "k": [3.983, 2.385, 1.603]},
                   "scale": [1.0, 1.0, 1.0]}),
        ),
        (
            "beckmann:alpha_x=0.5,alpha_y=0.25,g1=rational,fresnel=dielectric,ior=1.5",
            json!({"model": "microfacet", "distribution": "beckmann", "alpha_x": 0.5,
                   "alpha_y": 0.25, "shadowing": "smith-correlated", "g1": "rational",
                   "fresnel": {"type": "dielectric", "ior": 1.5}, "scale": 1.0}),
        ),
        (
            "microfacet:distribution=ggx,shadowing=v-cavity,fresnel=schlick,f0=0.04/0.5/0.9",
            json!({"model": "microfacet", "distribution": "ggx", "alpha": 0.2,
                   "shadowing": "v-cavity", "g1": "exact",
                   "fresnel": {"type": "schlick", "f0": [0.04, 0.5, 0.9]},
                   "scale": [1.0, 1.0, 1.0]}),
        ),
        (
            "ggx:fresnel=conductor,eta=1.2,k=3.5",
            json!({"model": "microfacet", "distribution": "ggx", "alpha": 0.2,
                   "shadowing": "smith-correlated", "g1": "exact",
                   "fresnel": {"type": "conductor", "eta": 1.2, "k": 3.5}, "scale": 1.0}),
        ),
        (
            "ward:variant=duer,rho_s=0.5/0.4/0.3,alpha_x=0.1,alpha_y=0.3",
            json!({"model": "ward", "variant": "duer", "rho_s": [0.5, 0.4, 0.3],
                   "rho_d": [0.0, 0.0, 0.0], "alpha_x": 0.1, "alpha_y": 0.3}),
        ),
        (
            "oren-nayar:sigma=0.4",
            json!({"model": "oren-nayar", "albedo": 0.5, "sigma": 0.4}),
        ),
        (
            "ashikhmin-shirley:rs=0.9/0.6/0.3,nu=10,nv=1000",
            json!({"model": "ashikhmin-shirley", "rs": [0.9, 0.6, 0.3], "rd": [0.0, 0.0, 0.0],
                   "nu": 10.0, "nv": 1000.0}),
        ),
        (
            "lafortune:diffuse=0.2,norm=ngan,lobe=-1:-1:0.95:20,lobe=0.5:0.5:0.3:3/4/5:0.2",
            json!({"model": "lafortune", "diffuse": [0.2, 0.2, 0.2], "norm": "ngan", "lobes": [
                {"cx": [-1.0, -1.0, -1.0], "cy": [-1.0, -1.0, -1.0], "cz": [0.95, 0.95, 0.95],
                 "n": [20.0, 20.0, 20.0], "albedo": [1.0, 1.0, 1.0]},
                {"cx": [0.5, 0.5, 0.5], "cy": [0.5, 0.5, 0.5], "cz": [0.3, 0.3, 0.3],
                 "n": [3.0, 4.0, 5.0], "albedo": [0.2, 0.2, 0.2]}]}),
        ),
        (
            "lambert:albedo=0.1 + ggx:alpha=0.3,fresnel=au",
            json!({"model": "sum", "terms": [
                {"model": "lambert", "albedo": 0.1},
                {"model": "microfacet", "distribution": "ggx", "alpha": 0.3,
                 "shadowing": "smith-correlated", "g1": "exact",
                 "fresnel": {"type": "conductor", "eta": [0.143, 0.374, 1.442],
                             "k": [3.983, 2.385, 1.603]},
                 "scale": [1.0, 1.0, 1.0]}]}),
        ),
    ]
}

#[test]
fn compact_and_json_forms_agree_and_round_trip() {
    for (compact, canonical) in pairs() {
        let a = Model::parse(compact).unwrap_or_else(|e| panic!("{compact}: {e}"));
        let b = Model::from_json(&canonical).unwrap_or_else(|e| panic!("{canonical}: {e}"));
        let c = Model::parse(&canonical.to_string()).unwrap();
        assert_eq!(a.to_json(), canonical, "{compact}: canonical JSON");
        assert_eq!(b.to_json(), canonical, "{compact}: JSON form");
        assert_eq!(c.to_json(), canonical, "{compact}: inline JSON");
        // Round trip through the canonical form.
        let d = Model::from_json(&a.to_json()).unwrap();
        assert_eq!(d.to_json(), canonical);
        assert_eq!(a.describe(), canonical.to_string());
        if a.check_tabulable().is_ok() {
            for (wi, wo) in PAIRS {
                assert_eq!(eval(&a, wi, wo), eval(&b, wi, wo), "{compact}");
            }
        }
    }
}

#[test]
fn spec_file_form_reads_json() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.json");
    std::fs::write(&path, r#"{"model": "ggx", "alpha": 0.3}"#).unwrap();
    let m = Model::parse(&format!("@{}", path.display())).unwrap();
    assert_eq!(m.to_json()["distribution"], "ggx");
    assert_eq!(m.to_json()["alpha"], 0.3);
    let missing = Model::parse("@/nonexistent/model.json").unwrap_err();
    assert!(matches!(missing, Error::Io { .. }), "{missing}");
    assert_eq!(missing.exit_code(), 2);
    std::fs::write(&path, "{not json").unwrap();
    let bad = Model::parse(&format!("@{}", path.display())).unwrap_err();
    assert!(matches!(bad, Error::InvalidFile { .. }), "{bad}");
}

/// Each bad input, and the substrings its message must contain.
const BAD: &[(&str, &[&str])] = &[
    ("", &["empty model spec"]),
    (
        "glossy:alpha=0.2",
        &["unknown model", "\"glossy\"", "lambert", "ggx"],
    ),
    (r#"{"albedo": 0.5}"#, &["\"model\"", "missing"]),
    (
        "lambert:colour=0.5",
        &["lambert", "unknown parameter", "colour", "albedo"],
    ),
    (
        "ggx:alpha=-1",
        &["microfacet: alpha = -1 is out of range [1e-6, 10]"],
    ),
    ("ggx:alpha=11", &["alpha = 11", "[1e-6, 10]"]),
    ("phong:exponent=2e6", &["exponent = 2e6", "[0, 1e6]"]),
    (
        "lambert:albedo=nan",
        &["albedo = nan", "not a finite number"],
    ),
    (
        "lambert:albedo=0.5/inf/0.2",
        &["albedo = inf", "not a finite number"],
    ),
    ("ggx:alpha=abc", &["alpha = \"abc\"", "not a number"]),
    ("lambert:albedo=0.5/0.5", &[]), // two channels are fine on their own
    (
        "ggx:fresnel=au,scale=1/2",
        &["scale has 2 values", "fresnel = au (RGB) has 3"],
    ),
    (
        "ward:rho_s=0.1/0.2/0.3,rho_d=0.1/0.2",
        &["rho_d has 2 values but rho_s has 3"],
    ),
    (
        "lambert:albedo=0.1/0.2 + ggx:fresnel=au",
        &["terms[1] has 3 channels but terms[0] has 2"],
    ),
    ("ggx:fresnel=schlick", &["fresnel.f0 is required", "[0, 1]"]),
    ("ggx:fresnel=dielectric", &["fresnel.ior is required"]),
    ("ggx:fresnel=conductor,eta=1", &["fresnel.k is required"]),
    (
        "ggx:fresnel=dielectric,ior=0",
        &["fresnel.ior = 0 is out of range [1e-6, 1e6]"],
    ),
    (
        "ggx:fresnel=schlick,f0=1.5",
        &["fresnel.f0 = 1.5 is out of range [0, 1]"],
    ),
    ("ggx:ior=1.5", &["ior = 1.5 needs fresnel=dielectric"]),
    ("ggx:fresnel=au,k=3", &["fresnel.k", "au"]),
    ("ggx:fresnel=gold", &["fresnel.type = \"gold\"", "au"]),
    (
        "ggx:fresnel=dielectric,ior=1.5,f0=0.2",
        &["unknown parameter \"fresnel.f0\"", "accepted: ior"],
    ),
    (
        "ggx:alpha=0.2,alpha_x=0.3,alpha_y=0.3",
        &["alpha = 0.2", "alpha_x = 0.3", "both"],
    ),
    ("ggx:alpha_x=0.3", &["alpha_x = 0.3", "without alpha_y"]),
    ("ggx:g1=rational", &["g1 = \"rational\"", "beckmann"]),
    (
        "ggx:distribution=beckmann",
        &["distribution = \"beckmann\"", "ggx"],
    ),
    (
        "microfacet:shadowing=smith",
        &["shadowing = \"smith\"", "smith-correlated"],
    ),
    (
        "ward:variant=dur",
        &["variant = \"dur\"", "ward | duer | balanced"],
    ),
    ("lafortune:diffuse=0.2", &["lobes is required"]),
    ("lafortune:lobe=1:1:1", &["lobe = \"1:1:1\"", "cx:cy:cz:n"]),
    (
        "lafortune:lobe=1:1:1:-2",
        &["lobes[0].n = -2 is out of range [0, 1e6]"],
    ),
    (
        r#"{"model": "lafortune", "lobes": [{"cx": 1, "cy": 1, "cz": 1}]}"#,
        &["lobes[0].n is required"],
    ),
    (
        "lafortune:norm=ngan,lobe=0.5:0.6:1:10",
        &["lobes[0].cx = 0.5", "lobes[0].cy = 0.6", "ngan"],
    ),
    (
        "phong:exponent=10,exponent=20",
        &["exponent is given twice"],
    ),
    ("phong:exponent", &["\"exponent\" is not key=value"]),
    ("lambert + ", &["empty term"]),
    (
        r#"{"model": "lambert", "albedo": "bright"}"#,
        &["albedo = \"bright\"", "not a number"],
    ),
    (
        r#"{"model": "lambert", "albedo": []}"#,
        &["albedo = [] is empty"],
    ),
    (r#"{"model": "sum", "terms": []}"#, &["terms = []"]),
    (r#"{"model": "sum"}"#, &["terms is required"]),
    (r#"{"model": "lambert", "albedo": 1e999}"#, &["model JSON"]),
];

#[test]
fn channel_count_is_capped() {
    let many = vec![0.5; 5000];
    let e = Model::from_json(&json!({"model": "lambert", "albedo": many})).unwrap_err();
    assert!(
        e.to_string()
            .contains("albedo has 5000 values; at most 4096"),
        "{e}"
    );
}

#[test]
fn bad_input_is_an_input_error_naming_parameter_and_value() {
    for (spec, needles) in BAD {
        match Model::parse(spec) {
            Ok(m) => assert!(needles.is_empty(), "{spec:?} parsed: {}", m.to_json()),
            Err(e) => {
                assert!(!needles.is_empty(), "{spec:?}: unexpected error {e}");
                assert!(
                    matches!(e, Error::Input(_)),
                    "{spec:?}: {e:?} is not Error::Input"
                );
                assert_eq!(e.exit_code(), 2);
                let msg = e.to_string();
                for n in *needles {
                    assert!(msg.contains(n), "{spec:?}: message {msg:?} lacks {n:?}");
                }
            }
        }
    }
}

#[test]
fn mirror_parses_but_refuses_evaluation_and_reports_albedo() {
    let m = Model::parse("mirror:albedo=0.9/0.8/0.7").unwrap();
    let e = m.check_tabulable().unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("Dirac delta") && msg.contains("ggx:alpha=0.001"),
        "{msg}"
    );
    assert_eq!(m.delta_albedo(), Some(vec![0.9, 0.8, 0.7]));
    let s = Model::parse("lambert:albedo=0.1 + mirror:albedo=0.5").unwrap();
    assert!(
        s.check_tabulable()
            .unwrap_err()
            .to_string()
            .contains("terms[1]")
    );
    assert_eq!(s.delta_albedo(), Some(vec![0.5]));
    assert_eq!(Model::parse("lambert").unwrap().delta_albedo(), None);
    assert!(
        Model::parse("ggx:alpha=0.001")
            .unwrap()
            .check_tabulable()
            .is_ok()
    );
}

#[test]
fn default_material_is_ggx_gold() {
    let m = Model::default_material();
    let j = m.to_json();
    assert_eq!(j["model"], "microfacet");
    assert_eq!(j["distribution"], "ggx");
    assert_eq!(j["alpha"], 0.2);
    assert_eq!(j["shadowing"], "smith-correlated");
    assert_eq!(j["fresnel"]["eta"], json!([0.143, 0.374, 1.442]));
    assert_eq!(m.channels().len(), 3);
    assert!(m.is_isotropic());
}

#[test]
fn anisotropy_flags() {
    for (spec, iso) in [
        ("ggx:alpha_x=0.1,alpha_y=0.2", false),
        ("ggx:alpha_x=0.2,alpha_y=0.2", true),
        ("ward:alpha_x=0.1,alpha_y=0.2", false),
        ("ashikhmin-shirley:nu=10,nv=100", false),
        ("lafortune:lobe=-1:-0.9:1:10", false),
        ("lafortune:lobe=-1:-1:1:10", true),
        ("lambert + ward:alpha_x=0.1,alpha_y=0.2", false),
    ] {
        assert_eq!(Model::parse(spec).unwrap().is_isotropic(), iso, "{spec}");
    }
}

#[test]
fn every_catalog_model_builds_from_its_defaults() {
    for d in Model::catalog() {
        let spec = match d.name {
            "lafortune" => "lafortune:lobe=-1:-1:1:10".to_string(),
            "sum" => "lambert + phong".to_string(),
            n => n.to_string(),
        };
        let m = Model::parse(&spec).unwrap_or_else(|e| panic!("{spec}: {e}"));
        assert_eq!(m.name(), d.name);
        assert_eq!(m.check_tabulable().is_ok(), d.tabulable, "{}", d.name);
        // Defaults match the declarations: every declared numeric default is what to_json shows.
        let j = m.to_json();
        for p in d.params {
            if let brdfpack::model::ParamDefault::Number(x) = p.default
                && let Some(v) = j.get(p.name)
            {
                assert_eq!(v.as_f64(), Some(x), "{}: {}", d.name, p.name);
            }
        }
    }
}

#[test]
fn docs_list_the_declared_parameters() {
    let docs = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/models.md"))
        .expect("docs/models.md");
    let generated = listing::catalog_markdown(Model::catalog());
    assert!(
        docs.contains(&generated),
        "docs/models.md is out of date with the parameter declarations: regenerate its tables \
         with `brdfpack models --markdown`"
    );
}
