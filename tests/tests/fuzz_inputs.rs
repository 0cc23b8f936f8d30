//! Bad input, fuzzed (issue 23, part 5): whatever a user writes in a scene
//! or a `--set`, and whatever bytes a recording or a peer hands over, the
//! loaders and decoders answer with a value or an error, never a panic.
//!
//! Quick form here (proptest's 256 cases per property, a few seconds); the
//! long form is the same with more cases:
//! `PROPTEST_CASES=100000 cargo test --release -p integration-tests --test fuzz_inputs`.
//! Failing cases proptest finds are kept in `tests/proptest-regressions/`.

use std::path::Path;

use proptest::prelude::*;
use schemas::messages::{
    decode_loads, decode_states, encode_loads, encode_states, ExchangeHeader, HydroLoad, ParticleState,
};
use schemas::Scene;

const DRY: &str = include_str!("../../scenes/validation/minimal_dry_column.toml");
const SATURATED: &str = include_str!("../../scenes/validation/minimal_saturated_column.toml");
const MPM: &str = include_str!("../../scenes/validation/mpm_lab_column_defaults.toml");

/// Loads `text` with `set`; any outcome but a panic is fine, and an error
/// must say something.
fn load(text: &str, set: &[String]) {
    if let Err(e) = Scene::from_toml_str(text, Path::new("."), set) {
        assert!(!e.to_string().trim().is_empty(), "an error without words");
    }
}

/// Keys a user could plausibly aim at, right or wrong.
fn key() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("output.end_time".to_string()),
        Just("dem.friction".to_string()),
        Just("particles[0].density".to_string()),
        Just("particles[0].packing.region.max".to_string()),
        Just("fluids[0].region".to_string()),
        Just("lbm.spacing".to_string()),
        Just("mpm.points_per_element".to_string()),
        Just("coupling.ratio".to_string()),
        Just("domain.walls".to_string()),
        Just("gates[0].normal".to_string()),
        "[a-z_]{1,8}(\\[[0-9]{1,2}\\])?(\\.[a-z_]{1,8}){0,3}",
        ".{0,24}",
    ]
}

/// Values of every TOML shape and some that are not TOML.
fn value() -> impl Strategy<Value = String> {
    prop_oneof![
        any::<f64>().prop_map(|x| format!("{x:?}")),
        any::<i64>().prop_map(|x| x.to_string()),
        Just("true".to_string()),
        Just("\"text\"".to_string()),
        Just("[1.0, 2.0]".to_string()),
        Just("[]".to_string()),
        Just("{ min = [0.0, 0.0, 0.0], max = [1e300, -1.0, 0.0] }".to_string()),
        Just("nan".to_string()),
        Just("-inf".to_string()),
        Just("1e-320".to_string()),
        ".{0,24}",
    ]
}

/// One edit of a text: delete a span, insert characters, or repeat a line.
fn edit(text: &str, at: usize, len: usize, insert: &str, op: u8) -> String {
    let chars: Vec<char> = text.chars().collect();
    let at = at % (chars.len() + 1);
    let end = (at + len).min(chars.len());
    match op % 3 {
        0 => chars[..at].iter().chain(&chars[end..]).collect(),
        1 => chars[..at].iter().collect::<String>() + insert + &chars[at..].iter().collect::<String>(),
        _ => {
            let lines: Vec<&str> = text.lines().collect();
            let k = at % lines.len().max(1);
            let mut out: Vec<&str> = lines.clone();
            if let Some(&line) = lines.get(k) {
                out.insert(k, line);
            }
            out.join("\n")
        }
    }
}

fn states(n: usize) -> Vec<ParticleState> {
    (0..n)
        .map(|i| ParticleState { id: i as u32, position: [i as f64, 0.5, -1.0], radius: 1e-3, ..Default::default() })
        .collect()
}

fn loads(n: usize) -> Vec<HydroLoad> {
    (0..n).map(|i| HydroLoad { id: i as u32, force: [0.0, 0.0, -(i as f64)], ..Default::default() }).collect()
}

proptest! {
    /// Any `--set KEY=VALUE` (or a malformed one) on the three kinds of scene.
    #[test]
    fn overrides_never_panic(k in key(), v in value(), raw in ".{0,30}", which in 0u8..3) {
        let base = [DRY, SATURATED, MPM][which as usize];
        load(base, &[format!("{k}={v}")]);
        load(base, &[raw]);
    }

    /// A scene file with a span deleted, characters inserted, or a line repeated.
    #[test]
    fn edited_scenes_never_panic(at in 0usize..4000, len in 0usize..60, insert in ".{0,12}", op in 0u8..3, which in 0u8..3) {
        let base = [DRY, SATURATED, MPM][which as usize];
        load(&edit(base, at, len, &insert, op), &[]);
    }

    /// A recorded exchange message (`/dem/received_loads`, `/lbm/received_states`),
    /// cut short, with bytes flipped, or made of anything.
    #[test]
    fn exchange_messages_never_panic(n in 0usize..5, cut in 0usize..400, flip in 0usize..400, bits in any::<u8>(), junk in proptest::collection::vec(any::<u8>(), 0..200)) {
        let header = ExchangeHeader::new(3, 0.25);
        for mut bytes in [
            { let mut b = Vec::new(); encode_states(&header, &states(n), &mut b); b },
            { let mut b = Vec::new(); encode_loads(&header, &loads(n), &mut b); b },
        ] {
            let whole = bytes.clone();
            prop_assert!(decode_states(&whole).is_ok() || decode_loads(&whole).is_ok());
            if !bytes.is_empty() {
                let k = flip % bytes.len();
                bytes[k] ^= bits;
            }
            bytes.truncate(cut.min(bytes.len()));
            let _ = decode_states(&bytes);
            let _ = decode_loads(&bytes);
        }
        let _ = decode_states(&junk);
        let _ = decode_loads(&junk);
    }

    /// A recorded full state (`/dem/state`, `/lbm/state`, `/mpm/state`) of
    /// random bytes, or starting with a valid version: an error, not a panic
    /// or an allocation of what a corrupt length claims.
    #[test]
    fn recorded_states_never_panic(junk in proptest::collection::vec(any::<u8>(), 0..300)) {
        for prefix in [&[][..], &[2u8][..], &[1u8][..]] {
            let bytes: Vec<u8> = prefix.iter().chain(&junk).copied().collect();
            let _ = dem_proc::run::DemState::decode(&bytes);
            let _ = lbm_proc::run::LbmState::decode(&bytes);
            let _ = mpm_proc::run::MpmStateRecord::decode(&bytes);
        }
    }

    /// A checkpoint cut anywhere or with any one bit flipped is refused
    /// with a reason (every byte is under the lengths or the hash), never
    /// read as another state; junk of any length is refused too.
    #[test]
    fn damaged_checkpoints_are_refused(cut in 0usize..2000, flip in 0usize..2000, bit in 0u8..8, junk in proptest::collection::vec(any::<u8>(), 0..300)) {
        let valid = checkpoint_bytes();
        let cut = cut % valid.len();
        prop_assert!(runtime::checkpoint::decode(valid[..cut].to_vec()).is_err());
        let mut flipped = valid.clone();
        flipped[flip % valid.len()] ^= 1 << bit;
        prop_assert!(runtime::checkpoint::decode(flipped).is_err());
        let _ = runtime::checkpoint::decode(junk);
        prop_assert!(runtime::checkpoint::decode(valid).is_ok());
    }
}

/// The bytes of a small valid checkpoint (written once, as the driver writes them).
fn checkpoint_bytes() -> Vec<u8> {
    static BYTES: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    BYTES
        .get_or_init(|| {
            let dir = integration_tests::scratch_dir("fuzz_checkpoint");
            let scene = Scene::from_toml_str(DRY, Path::new("."), &[]).expect("the dry scene loads");
            let mut w = runtime::checkpoint::CheckpointWriter::new(&dir, "dem_proc", &scene).expect("writer");
            let driver = runtime::checkpoint::DriverState {
                steps: 7,
                time: 7e-6,
                last_recorded: 0,
                last_state: Some(0),
                frames_at_rest: 0,
                has_moved: false,
            };
            let path = w.write(driver, None, |o| o.write_all(&[42u8; 600])).expect("written");
            std::fs::read(path).expect("read back")
        })
        .clone()
}
