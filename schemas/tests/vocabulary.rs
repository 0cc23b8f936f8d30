//! The vocabulary crate stays a vocabulary: plain data and pure functions,
//! no transport, recorder, threads or process handling (those are the
//! `runtime` crate). A dependency creeping back fails here, by name.

#[test]
fn schemas_depends_on_serialisation_crates_only() {
    let manifest = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/Cargo.toml")).expect("manifest");
    let table: toml::Table = manifest.parse().expect("manifest is TOML");
    let deps: Vec<&str> = table
        .get("dependencies")
        .and_then(|d| d.as_table())
        .map(|t| t.keys().map(String::as_str).collect())
        .unwrap_or_default();
    let allowed = ["serde", "serde_json", "serde_path_to_error", "toml", "thiserror"];
    let extra: Vec<_> = deps.iter().filter(|d| !allowed.contains(d)).collect();
    assert!(
        extra.is_empty(),
        "schemas depends on {extra:?}: move the code that needs it to the `runtime` crate (or to its solver)"
    );
}
