//! Generates `include/brdfpack.h` from the crate's `extern "C"` items with cbindgen
//! (configuration in cbindgen.toml). The header is committed so that C users need no Rust
//! build to read it; it is rewritten only when its text changes.

fn main() {
    let dir = std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
    let dir = std::path::Path::new(&dir);
    println!("cargo:rerun-if-changed=src/lib.rs");
    println!("cargo:rerun-if-changed=cbindgen.toml");
    let config = cbindgen::Config::from_file(dir.join("cbindgen.toml"))
        .expect("bindings/c/cbindgen.toml is readable and valid");
    let header = dir.join("include/brdfpack.h");
    match cbindgen::Builder::new()
        .with_crate(dir)
        .with_config(config)
        .generate()
    {
        // `write_to_file` leaves the file alone when the text is unchanged.
        Ok(bindings) => {
            bindings.write_to_file(&header);
        }
        Err(e) => panic!("cbindgen: {e}"),
    }
}
