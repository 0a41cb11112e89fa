//! `brdfpack models`: lists every model; `--json` is machine-readable; bad names exit 2.

use assert_cmd::Command;
use brdfpack::model::Model;

#[test]
fn lists_every_model_with_parameters() {
    let out = Command::cargo_bin("brdfpack")
        .unwrap()
        .arg("models")
        .assert()
        .success();
    let text = String::from_utf8(out.get_output().stdout.clone()).unwrap();
    for d in Model::catalog() {
        assert!(text.contains(d.name), "{} missing", d.name);
        for p in d.params {
            assert!(text.contains(p.name), "{}: {} missing", d.name, p.name);
        }
    }
    assert!(text.contains("[1e-6, 10]") && text.contains("tabulable: no"));
}

#[test]
fn json_listing_parses() {
    let out = Command::cargo_bin("brdfpack")
        .unwrap()
        .args(["models", "--json"])
        .assert()
        .success();
    let v: serde_json::Value = serde_json::from_slice(&out.get_output().stdout).unwrap();
    let models = v["models"].as_array().unwrap();
    assert_eq!(models.len(), Model::catalog().len());
    let mf = models.iter().find(|m| m["name"] == "microfacet").unwrap();
    let alpha = mf["params"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == "alpha")
        .unwrap();
    assert_eq!(alpha["min"], 1e-6);
    assert_eq!(alpha["max"], 10.0);
    assert_eq!(mf["isotropic"], "when alpha_x = alpha_y");
    assert_eq!(v["metals"].as_array().unwrap().len(), 4);
}

#[test]
fn one_model_by_alias_and_unknown_name() {
    let out = Command::cargo_bin("brdfpack")
        .unwrap()
        .args(["models", "ggx"])
        .assert()
        .success();
    let text = String::from_utf8(out.get_output().stdout.clone()).unwrap();
    assert!(text.starts_with("microfacet"), "{text}");
    assert!(!text.contains("lambert"));
    Command::cargo_bin("brdfpack")
        .unwrap()
        .args(["models", "glossy"])
        .assert()
        .code(2)
        .stderr(predicates::str::contains(
            "brdfpack: unknown model \"glossy\"",
        ));
}
