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
