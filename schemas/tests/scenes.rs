//! Every scene file shipped under `scenes/` loads and validates.

use std::path::{Path, PathBuf};

use schemas::{Method, Scene};

fn toml_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            toml_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "toml") && !is_campaign(&path) {
            out.push(path);
        }
    }
}

/// Campaign files (`coupler campaign`) live beside their scenes:
/// `campaign.toml` or `<name>.campaign.toml`.
fn is_campaign(path: &Path) -> bool {
    path.file_name().is_some_and(|n| n.to_string_lossy().ends_with("campaign.toml"))
}

#[test]
fn every_scene_loads() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    let mut files = Vec::new();
    toml_files(&root, &mut files);
    files.sort();
    assert!(files.len() >= 30, "found only {} scenes under {}", files.len(), root.display());
    let mut failures = Vec::new();
    for f in &files {
        if let Err(e) = Scene::load(f, &[]) {
            failures.push(format!("{}:\n{e}", f.display()));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

/// The MPM scenes are MPM, name the method explicitly, and their names are unique.
#[test]
fn mpm_scenes_are_mpm() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    let mut files = Vec::new();
    toml_files(&root.join("ceccato2020"), &mut files);
    toml_files(&root.join("mpm_drag_study"), &mut files);
    let mut names = std::collections::BTreeSet::new();
    let mut mpm = 0;
    for f in &files {
        let s = Scene::load(f, &[]).unwrap();
        assert!(names.insert(s.spec.scene.name.clone()), "{}: scene name used twice", f.display());
        let stem = f.file_stem().unwrap().to_string_lossy();
        if stem.starts_with("mpm_") || stem.starts_with("drag_") {
            mpm += 1;
            assert_eq!(s.method(), Method::Mpm, "{}", f.display());
            assert_eq!(s.spec.scene.name, stem, "{}: scene.name should be the file name", f.display());
            assert!(s.spec.mpm.is_some(), "{}: write the [mpm] table out", f.display());
        }
    }
    assert_eq!(mpm, 14);
}
