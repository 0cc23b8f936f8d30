//! The dry and the saturated column of one H0 start from the same grains
//! (issue 19): everything the deposition reads is the same in both scenes,
//! so they share one packing key and cache file.

use std::path::PathBuf;

use dem_proc::packing::{cache_path, packing_key};
use schemas::scene::Scene;

fn scene(name: &str) -> Scene {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/ceccato2020").join(name);
    Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn dry_and_saturated_columns_deposit_the_same_packing() {
    for h in ["030", "040", "050", "060", "070"] {
        let dry = scene(&format!("dry_h{h}.toml"));
        let saturated = scene(&format!("sat_h{h}.toml"));
        assert_eq!(packing_key(&dry), packing_key(&saturated), "H0 = 0.{h} m: the two scenes deposit differently");
        assert_eq!(cache_path(&dry), cache_path(&saturated));
    }
    // The key does see what the deposition reads.
    let looser = Scene::load(
        &PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/ceccato2020/dry_h060.toml"),
        &["deposition.friction=0.1".to_string()],
    )
    .expect("valid override");
    assert_ne!(packing_key(&looser), packing_key(&scene("sat_h060.toml")));
}

/// `domain.collapse_gravity` acts from the run's start only: the grains
/// settle under `domain.gravity`, so a pushed run starts from the unpushed
/// run's packing (one key, one cache file) and only the run's world feels
/// the push.
#[test]
fn a_pushed_run_deposits_the_unpushed_packing() {
    use dem_proc::setup::DemSetup;
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/ceccato2020/dry_h060.toml");
    let plain = scene("dry_h060.toml");
    let pushed =
        Scene::load(&path, &["domain.collapse_gravity=[1.962, 0.0, -9.81]".to_string()]).expect("valid override");
    assert_eq!(packing_key(&plain), packing_key(&pushed));
    assert_eq!(cache_path(&plain), cache_path(&pushed));
    let setup = DemSetup::from_scene(&pushed);
    assert_eq!(setup.gravity, [1.962, 0.0, -9.81], "the run feels the push");
    assert_eq!(setup.for_deposition(&pushed).gravity, [0.0, 0.0, -9.81], "the grains settle under domain.gravity");
    assert_eq!(DemSetup::from_scene(&plain).gravity, [0.0, 0.0, -9.81], "no push unless asked");
}
